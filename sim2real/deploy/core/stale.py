"""What a backend's reader says about a stale sensor: the ``stale_context`` hook and its default.

The runtime safe-stops with cause ``stale_sensor`` when a sensor has had no fresh reading for
longer than the robot's ``Robot.stale_limit``. At that stop (and once at the end of a run, for the
report) it asks the backend what its reader saw: :func:`stale_context` calls the backend's own
``stale_context(env)`` (a method of :class:`~sim2real.deploy.core.backend.BackendLifecycle`, which
hardware backends override) or falls back on :func:`default_context` for a backend without one
(a test's stand-in). The answer is a JSON-ready dict, :func:`context`'s keys:

- ``backend``: the backend's name (``unitree``, ``feetech``, ``ros2``, ``sim``, ...);
- ``stream``: the stream it reads, short (``rt/lowstate``, ``joint_states``, ``SYNC READ``,
  ``encoders``), the head of the stop's one-line verdict;
- ``reader``: the stream in full (transport, topic or port, domain, servo IDs);
- ``arrived``: samples that arrived since the last one the reader accepted (the stale window:
  none of them was taken), None where the reader does not count them;
- ``refused``: of those, the ones refused, by kind (``bad_crc``, ``malformed``, ``stale``, ...);
- ``newest_sample_age_s``: s, the newest sample received (taken or not), its source timestamp
  against this computer's clock now; None where there is none or it carries no stamp;
- ``last_accepted_s``: s since the reader last accepted a sample, on this computer's clock;
- ``joints``: joint name -> what the reader knows of that joint alone (a servo ID without a
  reply, a motor's lost packets); only the joints it has something to say about;
- ``other_side``: one phrase of what the other side was doing (``robot silent``, ``12 samples
  arrived, all refused: bad_crc 12``), or None where the reader cannot tell.

Building a context allocates; a backend builds one only when asked (at a stop, at the report),
never in its read.
"""

from __future__ import annotations

import math


def context(
    backend: str,
    stream: str,
    reader: str,
    *,
    arrived: int | None = None,
    refused: dict[str, int] | None = None,
    newest_sample_age_s: float | None = None,
    last_accepted_s: float | None = None,
    joints: dict[str, str] | None = None,
    other_side: str | None = None,
    **extra,
) -> dict:
    """A reader's context (module docstring): the standard keys, then ``extra`` (the backend's
    own figures, JSON-ready; a key ending in ``_s`` is seconds). Seconds are kept to the
    microsecond, non-finite ones become None (JSON has no inf or NaN)."""
    return {
        "backend": backend,
        "stream": stream,
        "reader": reader,
        "arrived": arrived,
        "refused": dict(refused or {}),
        "newest_sample_age_s": _seconds(newest_sample_age_s),
        "last_accepted_s": _seconds(last_accepted_s),
        "joints": dict(joints or {}),
        "other_side": other_side,
        **{k: _seconds(v) if k.endswith("_s") else v for k, v in extra.items()},
    }


def _seconds(value: float | None) -> float | None:
    """``value`` (s) as a float to the microsecond, or None where it is None or not finite."""
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), 6)


def refused_text(refused: dict[str, int]) -> str:
    """``bad_crc 3, stale 1``: the kinds with a count, in order; ``''`` when none."""
    return ", ".join(f"{kind} {n}" for kind, n in refused.items() if n)


def arrivals_phrase(arrived: int | None, refused: dict[str, int], silent: str) -> str | None:
    """The other side's phrase from a reader's counts since its last accepted sample:
    ``silent`` (e.g. ``robot silent``) when nothing arrived, ``N samples arrived, all refused:
    KINDS`` when something did (none of them was taken, by definition of the window); None
    when ``arrived`` is None (not counted)."""
    if arrived is None:
        return None
    if arrived == 0:
        return silent
    kinds = refused_text(refused)
    return f"{arrived} sample{'s' if arrived != 1 else ''} arrived, all refused" + (
        f": {kinds}" if kinds else ""
    )


def default_context(backend, env: int = 0) -> dict:
    """The context of a backend without a ``stale_context`` of its own: its class name and
    ``sensor frame`` as the stream, nothing counted (the runtime's own view of the frame fills
    the verdict)."""
    name = type(backend).__name__
    return context(name, "sensor frame", f"{name}.read() (no reader context)")


def stale_context(backend, env: int = 0) -> dict:
    """``backend.stale_context(env)`` where the backend has one, else :func:`default_context`;
    ``env`` the env (robot) of a batched backend (0 for hardware)."""
    hook = getattr(backend, "stale_context", None)
    return hook(env) if hook is not None else default_context(backend, env)
