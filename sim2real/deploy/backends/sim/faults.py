"""Fault injection on the simulated robot: the faults the runtime must answer, on a schedule.

A fault is ``KIND[=MAGNITUDE]@START[:DURATION]`` (seconds of simulated time; DURATION defaults to
``DEFAULT_DURATION``), KIND one of the registered fault kinds
(:data:`~sim2real.deploy.backends.sim.fault_kinds.FAULT_KINDS`, where each says what it does):

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

from sim2real.deploy.backends.sim.fault_kinds import (  # noqa: F401 - importable from here too
    CABLE_FORCE,
    FAULT_KINDS,
    KINDS,
    LATENCY_SPIKE_TICKS,
    PUSH_FORCE,
    fault_kind,
)
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

DEFAULT_DURATION = 0.5  # s


@dataclass(frozen=True)
class Fault:
    """One scheduled fault: ``kind`` (a registered fault kind, :data:`FAULT_KINDS`) over
    [start, start + duration) s, on ``envs`` (None: every env), with an optional ``magnitude``
    (push or cable force N / latency ticks) and, for ``cable``, an optional unit ``direction`` of
    the pull (world frame; None: along gravity)."""

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
        names = FAULT_KINDS.names()
        if not sep or kind not in names:
            raise ValueError(f"--inject {text!r}: expected {form} with KIND one of {names}")
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
            spec = fault_kind(kind)
            if spec.magnitude_unit is None:
                sized = [k.name for k in FAULT_KINDS.entries().values() if k.magnitude_unit]
                raise ValueError(
                    f"--inject {text!r}: {kind} takes no MAGNITUDE (only {', '.join(sized)})"
                )
            if not (magnitude > 0 and np.isfinite(magnitude)):
                raise ValueError(f"--inject {text!r}: expected MAGNITUDE > 0")
            if spec.whole_magnitude and magnitude != int(magnitude):
                raise ValueError(
                    f"--inject {text!r}: {kind} MAGNITUDE is whole {spec.magnitude_unit}"
                )
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
        self._kinds = [fault_kind(f.kind) for f in self.faults]
        self._has_push = any(k.forces for k in self._kinds)

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
            kind = self._kinds[i]
            if kind.plant is not None:
                kind.plant(self, f, self._envs(f), push)
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

    @property
    def base_latency(self) -> np.ndarray:
        """(envs,) int64, the backend's encoder latency without faults, control ticks (a view:
        read it, do not write it)."""
        return self._base_latency

    def frozen_frame(self, frame: SensorFrame) -> SensorFrame:
        """A copy of ``frame`` taken at the first call while frame faults are in force, the same
        copy until none is (a ``stale`` fault's old readings)."""
        if self._frozen is None:
            self._frozen = SensorFrame(**{k: v.copy() for k, v in frame.arrays().items()})
        return self._frozen

    def filter_frame(self, t: float, frame: SensorFrame) -> SensorFrame:
        """Apply the frame faults in force (``stale``: the frozen copy's readings on their
        envs); with none in force, the frozen copy is dropped."""
        held = False
        for f, kind in zip(self.faults, self._kinds, strict=True):
            if kind.frame is not None and f.active(t):
                kind.frame(self, f, self._envs(f), frame)
                held = True
        if not held:
            self._frozen = None
        return frame

    def filter_action(self, t: float, action: np.ndarray) -> np.ndarray:
        """Apply the action faults in force (``nan-action``: NaN actions on their envs)."""
        for f, kind in zip(self.faults, self._kinds, strict=True):
            if kind.action is not None and f.active(t):
                kind.action(self, f, self._envs(f), action)
        return action
