"""Fault injection on the simulated robot: the faults the runtime must answer, on a schedule.

A fault is ``KIND@START[:DURATION]`` (seconds of simulated time; DURATION defaults to
``DEFAULT_DURATION``):

- ``dropout``: every encoder reading is lost (the estimator must predict only, then stop safely when
  the data is stale longer than ``Robot.stale_limit``).
- ``stale``: the sensor frame freezes: the same old readings with their old time stamps repeat.
- ``nan-action``: the policy outputs NaN.
- ``latency``: ``LATENCY_SPIKE_TICKS`` extra ticks of encoder latency.
- ``push``: a force of ``PUSH_FORCE`` N along +X pushes the end effector.
- ``cable``: a cable pulls on the end effector: a sustained force of ``CABLE_FORCE`` N (or
  ``magnitude``) along ``direction`` (world frame; default: along gravity, a hanging load), usually
  for tens of seconds (give a DURATION).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.stateful import (
    StateDictError,
    check,
    from_json,
    prefixed,
    put,
    scalar,
    section,
    take,
    to_json,
)

KINDS = ("dropout", "stale", "nan-action", "latency", "push", "cable")
DEFAULT_DURATION = 0.5  # s
LATENCY_SPIKE_TICKS = 10  # control ticks (50 ms at 200 Hz)
PUSH_FORCE = 20.0  # N, a firm shove by hand
CABLE_FORCE = 10.0  # N, a moderate sustained pull (a cable or hose of about 1 kg)
#: The kinds that take a magnitude, and its unit.
MAGNITUDE_UNITS = {"latency": "control ticks", "push": "N", "cable": "N"}


@dataclass(frozen=True)
class Fault:
    """One scheduled fault: ``kind`` from ``KINDS`` over [start, start + duration) s, on ``envs``
    (None: every env), with an optional ``magnitude`` (push or cable force N / latency ticks) and,
    for ``cable``, an optional unit ``direction`` of the pull (world frame; None: along gravity)."""

    kind: str
    start: float
    duration: float = DEFAULT_DURATION
    envs: tuple[int, ...] | None = None
    magnitude: float | None = None
    direction: tuple[float, float, float] | None = None

    @classmethod
    def parse(cls, text: str) -> Fault:
        """Parse ``KIND[=MAGNITUDE]@SECONDS[:DURATION]`` (``latency=1@3:2``: one extra tick of
        encoder latency from 3 s for 2 s; ``push=80@5:0.2``: 80 N for 0.2 s).

        Raises:
            ValueError: naming the bad part and the expected form.
        """
        form = "KIND[=MAGNITUDE]@SECONDS[:DURATION]"
        head, sep, when = text.partition("@")
        kind, eq, size = head.partition("=")
        if not sep or kind not in KINDS:
            raise ValueError(f"--inject {text!r}: expected {form} with KIND one of {KINDS}")
        start, _, duration = when.partition(":")
        try:
            t0 = float(start)
            dt = float(duration) if duration else DEFAULT_DURATION
            magnitude = float(size) if eq else None
        except ValueError:
            raise ValueError(
                f"--inject {text!r}: MAGNITUDE, SECONDS and DURATION must be numbers"
            ) from None
        if t0 < 0 or dt <= 0:
            raise ValueError(f"--inject {text!r}: expected SECONDS >= 0 and DURATION > 0")
        if magnitude is not None:
            if kind not in MAGNITUDE_UNITS:
                raise ValueError(
                    f"--inject {text!r}: {kind} takes no MAGNITUDE (only "
                    f"{', '.join(MAGNITUDE_UNITS)})"
                )
            if not (magnitude > 0 and np.isfinite(magnitude)):
                raise ValueError(f"--inject {text!r}: expected MAGNITUDE > 0")
            if kind == "latency" and magnitude != int(magnitude):
                raise ValueError(f"--inject {text!r}: latency MAGNITUDE is whole control ticks")
        return cls(kind, t0, dt, magnitude=magnitude)

    def active(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration


class FaultInjector:
    """Applies a fault schedule to a :class:`~sim2real.deploy.backends.sim.plant.SimBackend` and to the
    policy
    output, tick by tick. ``log`` records (kind, start, end, envs) of every fault applied."""

    def __init__(self, faults: list[Fault], backend):
        self.faults = sorted(faults, key=lambda f: f.start)
        self.backend = backend
        self._base_dropout = backend.dropout_probability.copy()
        self._base_latency = backend.latency_ticks.copy()
        self._frozen: SensorFrame | None = None
        self._active: set[int] = set()
        self.log: list[dict] = []
        self._has_push = any(f.kind in ("push", "cable") for f in self.faults)

    # ------------------------------------------------------------------ state
    def state_dict(self, env: int | None = None) -> dict:
        """The injector's state (copies; conventions of :mod:`sim2real.deploy.core.stateful`): the backend's
        settings without faults ``base_dropout`` (envs,) and ``base_latency`` (envs,) int64;
        ``frozen`` (bool) and, while a ``stale`` fault holds one, the frozen frame's fields
        ``frozen/<field>`` (:class:`~sim2real.deploy.core.backend.SensorFrame`, env axis first); shared:
        ``active`` (int64, indices into the sorted schedule) and ``log`` (JSON text). The
        schedule itself is configuration: load into an injector built with the same faults.
        """
        out: dict = take(self._base_fields(), env)
        out["frozen"] = self._frozen is not None
        if self._frozen is not None:
            out.update(prefixed("frozen", take(self._frozen.arrays(), env)))
        out["active"] = np.array(sorted(self._active), dtype=np.int64)
        out["log"] = to_json(self.log)
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field, a shape that differs, or an active fault that is
                not in the schedule; nothing is changed.
        """
        fields = self._base_fields()
        check(fields, state, env)
        frozen = scalar(state, "frozen", bool)
        frame = None
        if frozen:
            frame = self._frozen
            if frame is None:  # a frame to load into (NaN: no reading), as wide as the state's
                n = np.shape(state.get("frozen/position", np.empty((0, 0))))[-1]
                frame = SensorFrame.empty(self.backend.envs, n)
            try:
                check(frame.arrays(), section(state, "frozen"), env)
            except StateDictError as exc:
                raise exc.under("frozen") from None
        if "active" not in state:
            raise StateDictError("active", " is missing")
        active = {int(i) for i in np.asarray(state["active"]).reshape(-1)}
        if not active <= set(range(len(self.faults))):
            raise StateDictError(
                "active", f": {sorted(active)} beyond the {len(self.faults)} faults"
            )
        log = from_json(state, "log")
        put(fields, state, env)
        if frame is not None:
            put(frame.arrays(), section(state, "frozen"), env)
        self._frozen = frame
        self._active = active
        self.log = list(log)

    def _base_fields(self) -> dict[str, np.ndarray]:
        return {"base_dropout": self._base_dropout, "base_latency": self._base_latency}

    def _envs(self, f: Fault) -> np.ndarray:
        return np.arange(self.backend.envs) if f.envs is None else np.array(f.envs)

    def before_read(self, t: float) -> None:
        """Switch plant-side faults on or off for time ``t`` (s)."""
        b = self.backend
        b.dropout_probability[:] = self._base_dropout
        b.latency_ticks[:] = self._base_latency
        push = np.zeros((b.envs, 3))
        for i, f in enumerate(self.faults):
            on = f.active(t)
            if on and i not in self._active:
                self._active.add(i)
                self.log.append(
                    {
                        "kind": f.kind,
                        "start": t,
                        "duration": f.duration,
                        "envs": self._envs(f).tolist(),
                    }
                )
            elif not on:
                self._active.discard(i)
            if not on:
                continue
            envs = self._envs(f)
            if f.kind == "dropout":
                b.dropout_probability[envs] = 1.0
            elif f.kind == "latency":
                spike = int(f.magnitude or LATENCY_SPIKE_TICKS)
                b.latency_ticks[envs] = np.minimum(
                    self._base_latency[envs] + spike, b.max_latency_ticks
                )
            elif f.kind == "push":
                push[envs, 0] = f.magnitude or PUSH_FORCE
            elif f.kind == "cable":
                for e in envs:
                    push[e] += (f.magnitude or CABLE_FORCE) * self._cable_direction(f, e)
        if self._has_push:
            for e in range(b.envs):
                b.set_external_force(e, push[e])

    def restore(self) -> None:
        """Undo every fault in force (an episode cut short mid-fault): the backend's dropout and
        latency back to the settings without faults, no force where the schedule pushes or
        pulls, no frozen frame, no fault active."""
        b = self.backend
        b.dropout_probability[:] = self._base_dropout
        b.latency_ticks[:] = self._base_latency
        if self._has_push:
            for e in range(b.envs):
                b.set_external_force(e, np.zeros(3))
        self._frozen = None
        self._active.clear()

    def _cable_direction(self, f: Fault, env: int) -> np.ndarray:
        """Unit vector (3,) of a cable's pull: ``f.direction``, or along the env's gravity."""
        if f.direction is not None:
            d = np.asarray(f.direction, dtype=np.float64)
        else:
            d = np.array(self.backend.models[env].opt.gravity, dtype=np.float64)
        norm = np.linalg.norm(d)
        if not norm > 0.0:
            raise ValueError(f"fault {f}: the cable direction {d.tolist()} has no length")
        return d / norm

    def filter_frame(self, t: float, frame: SensorFrame) -> SensorFrame:
        """Replace the frame with a frozen copy while a ``stale`` fault is active."""
        if any(f.kind == "stale" and f.active(t) for f in self.faults):
            if self._frozen is None:
                self._frozen = SensorFrame(**{k: v.copy() for k, v in frame.arrays().items()})
            frozen = self._frozen
            envs = [
                e for f in self.faults if f.kind == "stale" and f.active(t) for e in self._envs(f)
            ]
            frame.position[envs] = frozen.position[envs]
            frame.position_stamp[envs] = frozen.position_stamp[envs]
            if frame.velocity is not None and frozen.velocity is not None:
                frame.velocity[envs] = frozen.velocity[envs]
            return frame
        self._frozen = None
        return frame

    def filter_action(self, t: float, action: np.ndarray) -> np.ndarray:
        """NaN actions while a ``nan-action`` fault is active."""
        for f in self.faults:
            if f.kind == "nan-action" and f.active(t):
                action[self._envs(f)] = np.nan
        return action
