"""The runtime's state dict: what a checkpoint of a :class:`~sim2real.deploy.runtime.loop.Runtime` holds,
taken and loaded.

A runtime's state is its own per-env arrays (modes, causes, goals, the screened actions, the last
targets and commands, the counters, the estimated robot state), the arrays its envs share (the
overrun window, the wall-clock histograms), the tick, the time and the clock's counters, then each
stage's own state dict under its name; the conventions are :mod:`sim2real.deploy.core.stateful`'s.

:class:`RuntimeState` is a base class of :class:`~sim2real.deploy.runtime.loop.Runtime`; its methods work
on the runtime's attributes (set in ``Runtime.__init__``). It also gives the state's names (modes,
causes) and read-only views (the last action, target and command).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import FAULT_CAUSES, Mode
from sim2real.deploy.core.stateful import check, load_parts, parts_state_dict, put, scalar, take


class ObservationState:
    """The current policy's observation plan as a stage of the runtime's state dict
    (``observation/``; :meth:`sim2real.deploy.spec.observation_plan.ObservationPlan.state_fields`:
    its gait clocks and frame history), for a batch of ``envs``."""

    def __init__(self, plan, envs: int):
        self.plan, self.envs = plan, envs

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        return take(self.plan.state_fields(self.envs), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Raises StateDictError: a missing field or a shape that differs (another history)."""
        put(self.plan.state_fields(self.envs), state, env)


class RuntimeState:
    """The state dict of a :class:`~sim2real.deploy.runtime.loop.Runtime` (module docstring)."""

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        """The runtime's own per-env arrays (leading env axis), its state machine's included."""
        c, st, sup = self.counters, self.state, self.supervision
        fields = {
            "mode": self.mode,
            "cause": self.cause,
            "goal": self.goal,
            "drive_errors": self.drive_errors,
            "action": sup.action,
            "last_valid_action": sup.last_valid_action,
            "nan_streak": sup.nan_streak,
            "stop_ticks": self.stop_ticks,
            "target": self._target,
            "command": self._cmd,
            "counters/non_finite_actions": c.non_finite_actions,
            "counters/safe_stops": c.safe_stops,
            "counters/resyncs": c.resyncs,
            "counters/anchors": c.anchors,
            "counters/safe_stop_timeouts": c.safe_stop_timeouts,
        }
        fields.update({f"counters/faults/{k}": v for k, v in c.faults.items()})
        for name in ("q", "dq", "ee_position", "ee_rotation", "winding_temperature", "last_action"):
            fields[f"state/{name}"] = getattr(st, name)
        if st.base is not None:  # a floating base: its estimate, contacts, command, clock
            for name in ("foot_contact", "command", "clock"):
                fields[f"state/{name}"] = getattr(st, name)
            for name, value in vars(st.base).items():
                fields[f"state/base/{name}"] = value
        return fields

    def _shared_fields(self) -> dict[str, np.ndarray]:
        """Arrays the envs share: the overrun window, the wall-clock histograms."""
        fields = {
            "overrun_ring": self.supervision.overrun_ring,
            "latency/counts": self.latency.counts,
            "latency/max_ns": self.latency.max_ns,
            "tick_cost/counts": self.tick_cost.counts,
            "tick_cost/max_ns": self.tick_cost.max_ns,
        }
        jitter = getattr(self.clock, "jitter", None)
        if jitter is not None:
            fields["clock/jitter/counts"] = jitter.counts
            fields["clock/jitter/max_ns"] = jitter.max_ns
        return fields

    def _parts(self) -> dict:
        """The stages whose state is part of the runtime's: the estimator, guard, smoother and
        the policy's observation (its gait clocks and frame history), and the policy, backend
        and fault injector where they have a ``state_dict``."""
        parts = {"estimator": self.estimator, "guard": self.guard, "smoother": self.smoother}
        parts["observation"] = ObservationState(self.spec.plan, self.envs)
        parts.update(self.base_tick.parts())  # a floating base's estimator and fall check
        if self.height_map is not None:  # a policy with a height scan: its elevation map
            parts["height_map"] = self.height_map
        for name, part in (
            ("policy", self.policy),
            ("backend", self.backend),
            ("injector", self.injector),
        ):
            if part is not None and hasattr(part, "state_dict"):
                parts[name] = part
        return parts

    def state_dict(self, env: int | None = None) -> dict:
        """The state of the loop and of its stages (copies; conventions of
        :mod:`sim2real.deploy.core.stateful`).

        The runtime's own fields, (envs, ...) (length 1 for one env ``env``): ``mode``,
        ``cause`` (int8), ``goal`` (envs, 3) m, ``drive_errors``, the screened ``action`` and
        ``last_valid_action`` (float32), ``nan_streak``, ``stop_ticks`` (int64, ticks since the
        safe stop began), the last ``target`` and ``command`` (the
        units of the mode), ``counters/<name>`` and ``counters/faults/<cause>`` (int64) and the
        estimated ``state/<field>`` (:class:`~sim2real.deploy.core.state.RobotState`). Shared by the batch:
        ``ticks`` (int), ``time`` (float, s), ``overrun_ring`` (window,) int64 missed periods, the
        wall-clock histograms ``latency/*``, ``tick_cost/*`` and ``clock/*`` (measurements, not
        seeded; a wall clock's next deadline is not state: a resumed loop starts its own).
        Then each stage's ``state_dict(env)`` under its name: ``estimator/``, ``guard/``,
        ``smoother/``, ``observation/`` (:class:`ObservationState`), a legged robot's
        ``base_estimator/`` and ``fall_detector/``, a height-scan policy's ``height_map/``, and
        ``policy/``, ``backend/``, ``injector/`` where the policy (a recurrent one), the backend
        (:class:`~sim2real.deploy.backends.sim.plant.SimBackend`) or the fault injector has one.
        """
        out: dict = take(self._state_fields(), env)
        out.update({k: np.array(v, copy=True) for k, v in self._shared_fields().items()})
        out["ticks"], out["time"] = int(self.ticks), float(self.time)
        clock = self.clock
        out["clock/overruns"] = int(clock.overruns)
        out["clock/missed_periods"] = int(clock.missed_periods)
        return out | parts_state_dict(self._parts(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``; the shared fields
        either way), into a runtime built with the same robot, policy, backend kind and clock.
        A started runtime is not needed: the state replaces what :meth:`start` sets (a wall
        clock's deadlines start anew here).

        Raises:
            StateDictError: a missing field or a shape that differs, named with its stage's
                prefix (e.g. ``estimator/covariance``). The runtime's own fields are checked
                before anything is written; a stage's error leaves the stages before it loaded.
        """
        ticks, now = scalar(state, "ticks", int), scalar(state, "time", float)
        overruns = scalar(state, "clock/overruns", int)
        missed = scalar(state, "clock/missed_periods", int)
        shared = self._shared_fields()
        check(shared, state, None)
        put(self._state_fields(), state, env)
        put(shared, state, None)
        self.ticks, self.time = ticks, now
        self.clock.overruns, self.clock.missed_periods = overruns, missed
        load_parts(self._parts(), state, env)
        self.clock.start()

    # ------------------------------------------------------------------ names and read-only views
    def mode_names(self) -> list[str]:
        return [Mode(int(m)).name for m in self.mode]

    def cause_names(self) -> list[str | None]:
        return [FAULT_CAUSES[c] if c >= 0 else None for c in self.cause]

    # ------------------------------------------------------------------ read-only views
    @property
    def action(self) -> np.ndarray:
        """(envs, n) float32: the last tick's screened policy action in [-1, 1] (a view)."""
        return self.supervision.action

    @property
    def target(self) -> np.ndarray:
        """(envs, n): the last tick's guarded target, in the units of the control mode (position
        rad, velocity rad/s, torque N m; a view)."""
        return self._target

    @property
    def command(self) -> np.ndarray:
        """(envs, n): the command the last tick wrote to the backend, in the units of the
        control mode (position rad, velocity rad/s, torque N m; a view)."""
        return self._cmd

    @property
    def damping(self) -> np.ndarray:
        """(envs,) bool: the envs whose command damps the joints instead of holding a pose: a
        legged robot's envs in SAFE_STOP or FAULTED (holding its stance against gravity with a
        low-gain PD heated the thighs past 200 degC in simulation: it lies down instead); all
        False for an arm."""
        return self.base_tick.damping(self.mode)
