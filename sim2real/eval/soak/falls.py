"""What began each fall of a legged robot's soak session (:func:`attribute_falls`).

A fall is counted by :class:`sim2real.deploy.tasks.locomotion.CommandTracker` at the stop that lays
the robot down (its ``fall_log``: time, the stop's cause and, for a hard-limit stop, the joint
whose estimate was past its limit and by how much). Its origin:

- ``runtime_stop``: the runtime stopped a robot that had not fallen (any cause but ``fall``: a
  hard limit, a stale sensor, non-finite actions, an overrun, an over-temperature, a drive
  error). The runtime's response laid it down; the fault it answered, if one was active, is
  named (``during``).
- ``push``: the fall detector's stop (``fall``) within ``ATTRIBUTION_WINDOW`` s of a push (one
  of the training domain's, :mod:`sim2real.eval.world.pushes`, or a ``push`` or ``cable`` fault).
- ``fault``: the fall detector's stop within ``ATTRIBUTION_WINDOW`` s of another injected fault
  (dropout, stale frames, latency, non-finite actions), named (``during``).
- With no stop, push or fault before it, the fall's replays (:mod:`sim2real.eval.soak.
  fall_replay`) decide (:func:`replay_origin`): ``policy`` (its own loop, true state, fell in
  at least ``REPLAY_SHARE`` of its replays), ``runtime`` (the own loop stood in most, the
  runtime with other sensor-noise draws fell in at least that share), ``rare_draw`` (both
  stood in most: the session's own noise draw took it down) or ``undecided`` (no replay ran:
  past ``fall_replay.MAX_FALLS``, or too soon after a stand-up or a resume; or the own loop
  stood and the runtime's were not run). The report says so; it does not guess.

A hard-limit stop that the soak replayed without the stop (:mod:`sim2real.eval.soak.counterfactual`)
carries ``would_fall``. True: the replay fell all the same (its fall detector fired within
``HORIZON`` s), so the stop came on a robot already falling and the fall goes to what began it,
as the fall detector's stop would (push, fault, policy), with ``stopped_while_falling`` True.
False, or not replayed: ``runtime_stop``.
"""

from __future__ import annotations

from sim2real.deploy.backends.sim.fault_kinds import FAULT_KINDS

#: A fall within this long of a push or a fault's end is attributed to it, s. Our choice: 2 s,
#: longer than a walking robot's recovery steps after a shove (a few strides of 0.3-0.4 s).
ATTRIBUTION_WINDOW = 2.0
#: The origins, in the order the report lists them.
ORIGINS = ("runtime_stop", "push", "fault", "policy", "runtime", "rare_draw", "undecided")
#: The share of a fall's replays that must fall for :func:`replay_origin` to name the policy
#: (own loop) or the runtime (other noise draws). Our choice: most of them (3 of 5).
REPLAY_SHARE = 0.5


def push_kinds() -> tuple[str, ...]:
    """The fault kinds that push or pull on the robot (``forces``: push, cable): a fall after one
    has origin ``push``."""
    return tuple(n for n, k in FAULT_KINDS.entries().items() if k.forces)


#: A fall stop is false when the truth at the stop says upright (:func:`false_fall_stops`): its
#: base tilted less than this share of the fall check's tilt limit (our choice: 0.3, 17 deg of
#: the default 57, a walking quadruped's range; the H1s of the push soaks stopped sinking at
#: 26.6-27 deg true were at 14 deg 0.1 s before, falling over) and ...
UPRIGHT_TILT_SHARE = 0.3
#: ... its base at least this share of ``[base] standing_height`` above the floor (the line
#: under which :class:`sim2real.deploy.monitors.estimation.EstimationMonitor` calls the true
#: base fallen, ``TRUE_FALL_HEIGHT``).
UPRIGHT_HEIGHT_SHARE = 0.4
#: ... and not sinking this fast or faster, m/s (a vertical collapse: knees buckling under an
#: upright base is a fall however level the base stays). Our choice: half the fall check's
#: ``FALL_SPEED`` (1 m/s, :mod:`sim2real.deploy.estimation.fall`), past a walking base's vertical
#: velocity (within about 0.3 m/s, the same module's note).
UPRIGHT_SINK_SPEED = 0.5


def attribute_falls(
    fall_log: list[dict], faults: list[dict], push_times: list[float] | None = None
) -> list[dict]:
    """Each fall of ``fall_log`` with its ``origin`` (module docstring) and ``during`` (the
    fault or push it followed, or None).

    Args:
        fall_log: The tracker's records (``t_s`` s, ``cause``, optional ``joint``, ``past_rad``,
            ``would_fall``).
        faults: The session's faults, dicts with ``kind``, ``start_s``, ``duration_s`` (s).
        push_times: The session times of the training domain's pushes, s.
    """
    pushes = sorted(push_times or [])
    out = []
    for fall in fall_log:
        t = float(fall["t_s"])
        recent = [
            f
            for f in faults
            if f["start_s"] <= t <= f["start_s"] + f["duration_s"] + ATTRIBUTION_WINDOW
        ]
        during = recent[-1]["kind"] if recent else None
        falling = fall.get("would_fall") is True
        if fall.get("cause") not in (None, "fall") and not falling:
            origin = "runtime_stop"
        elif any(p <= t <= p + ATTRIBUTION_WINDOW for p in pushes):
            origin, during = "push", "domain push"
        elif any(f["kind"] in (pushing := push_kinds()) for f in recent):
            origin, during = "push", next(f["kind"] for f in recent if f["kind"] in pushing)
        elif recent:
            origin = "fault"
        else:
            origin = replay_origin(fall)
        out.append({**fall, "origin": origin, "during": during, "stopped_while_falling": falling})
    return out


def replay_origin(fall: dict) -> str:
    """The origin of a fall with no stop, push or fault before it, from its replays (module
    docstring): ``policy``, ``runtime``, ``rare_draw`` or ``undecided``. ``fall``: a tracker's
    record with the optional ``own_loop`` and ``redraw`` of
    :class:`~sim2real.eval.soak.fall_replay.FallReplay` (``fall_s``: s, or None where the
    replay stood)."""

    def share(kind: str) -> float | None:
        ends = (fall.get(kind) or {}).get("fall_s") or []
        return sum(t is not None for t in ends) / len(ends) if ends else None

    own, redraw = share("own_loop"), share("redraw")
    if own is not None and own >= REPLAY_SHARE:
        return "policy"
    if own is None or redraw is None:
        return "undecided"
    return "runtime" if redraw >= REPLAY_SHARE else "rare_draw"


def falls_by_origin(falls: list[dict]) -> dict[str, int]:
    """``{origin: falls}`` over ``ORIGINS`` (every origin, zeros included)."""
    return {o: sum(1 for f in falls if f["origin"] == o) for o in ORIGINS}


def stops_while_falling(falls: list[dict]) -> int:
    """How many of ``falls`` (:func:`attribute_falls`'s) began with a runtime stop on a robot
    that its replay showed falling anyway."""
    return sum(1 for f in falls if f.get("stopped_while_falling"))


def fall_replays(falls: list[dict]) -> dict[str, int]:
    """How ``falls`` fared in their replays (:mod:`sim2real.eval.soak.fall_replay`): ``falls``
    replayed; ``own_loop`` replays in the policy's own loop and ``own_loop_fell`` how many of
    those fell; ``redraw`` replays of the runtime with other sensor-noise draws and
    ``redraw_fell`` how many of those fell."""
    out = {"falls": 0, "own_loop": 0, "own_loop_fell": 0, "redraw": 0, "redraw_fell": 0}
    for f in falls:
        kinds = [k for k in ("own_loop", "redraw") if f.get(k) and f[k]["fall_s"]]
        out["falls"] += bool(kinds)
        for k in kinds:
            out[k] += len(f[k]["fall_s"])
            out[f"{k}_fell"] += sum(1 for t in f[k]["fall_s"] if t is not None)
    return out


def upright(
    tilt_rad: float, height_m: float, vz_m_s: float, tilt_limit: float, standing_height: float
) -> bool:
    """Whether a base at a stop was upright, not falling: tilted under ``UPRIGHT_TILT_SHARE``
    of ``tilt_limit`` (rad, the fall check's), at least ``UPRIGHT_HEIGHT_SHARE`` of
    ``standing_height`` (m) high and not sinking at ``UPRIGHT_SINK_SPEED`` or faster
    (``vz_m_s``, m/s world: a base collapsing vertically, level but going down, is a fall). The
    one rule of the soak's :func:`false_fall_stops` and the push benchmark's upright stops."""
    return (
        tilt_rad < UPRIGHT_TILT_SHARE * tilt_limit
        and height_m >= UPRIGHT_HEIGHT_SHARE * standing_height
        and vz_m_s > -UPRIGHT_SINK_SPEED
    )  # fmt: skip


def false_fall_stops(falls: list[dict], standing_height: float, tilt_limit: float) -> int:
    """How many of ``falls`` (the tracker's records) are fall-check stops (cause ``fall``) of
    a robot that was not falling: the simulator's truth at the stop (``true_tilt_deg``,
    ``true_height_m``, ``true_vz_m_s``) :func:`upright`, unless a replay without the stop fell
    anyway (``would_fall``). A record without the truth (hardware) is not counted; one without
    ``true_vz_m_s`` (written before it was recorded) is judged by tilt and height alone."""
    import math

    return sum(
        1
        for f in falls
        if f.get("cause") == "fall"
        and "true_tilt_deg" in f
        and upright(math.radians(f["true_tilt_deg"]), f["true_height_m"],
                    f.get("true_vz_m_s", 0.0), tilt_limit, standing_height)
        and not f.get("would_fall", False)
    )  # fmt: skip
