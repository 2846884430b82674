"""The runtime's state dict: what a checkpoint of a :class:`~sim2real.deploy.runtime.loop.Runtime` holds,
taken and loaded.

A runtime's state is its own per-env arrays (modes, causes, goals, the screened actions, the last
targets and commands, the counters, the estimated robot state), the arrays its envs share (the
overrun window, the wall-clock histograms), the tick, the time and the clock's counters, then each
stage's own state dict under its name; the conventions are :mod:`sim2real.deploy.core.stateful`'s.

:class:`RuntimeState` is a stage of :class:`~sim2real.deploy.runtime.loop.Runtime`, which delegates
its ``state_dict`` and ``load_state_dict`` to it: it reads the runtime's public arrays and stages
(the policy and its observation plan of the moment: a switch of policy is followed) and hands the
loaded tick and time back to the runtime, which keeps its own clock.
"""

from __future__ import annotations

import numpy as np

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
    """The state dict of ``runtime`` (a :class:`~sim2real.deploy.runtime.loop.Runtime`; module
    docstring)."""

    def __init__(self, runtime):
        self.rt = runtime

    def _state_fields(self) -> dict[str, np.ndarray]:
        """The runtime's own per-env arrays (leading env axis), its state machine's included."""
        rt = self.rt
        c, st, sup = rt.counters, rt.state, rt.supervision
        fields = {
            "mode": rt.mode,
            "cause": rt.cause,
            "goal": rt.goal,
            "drive_errors": rt.drive_errors,
            "action": sup.action,
            "last_valid_action": sup.last_valid_action,
            "nan_streak": sup.nan_streak,
            "stop_ticks": rt.stop_ticks,
            "target": rt.target,
            "command": rt.command,
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
        if st.sensed_orientation is not None:  # the IMU's own attitude, as the base's
            fields["state/sensed_orientation"] = st.sensed_orientation
        return fields

    def _shared_fields(self) -> dict[str, np.ndarray]:
        """Arrays the envs share: the overrun window, the wall-clock histograms."""
        rt = self.rt
        fields = {
            "overrun_ring": rt.supervision.overrun_ring,
            "latency/counts": rt.latency.counts,
            "latency/max_ns": rt.latency.max_ns,
            "tick_cost/counts": rt.tick_cost.counts,
            "tick_cost/max_ns": rt.tick_cost.max_ns,
        }
        jitter = getattr(rt.clock, "jitter", None)
        if jitter is not None:
            fields["clock/jitter/counts"] = jitter.counts
            fields["clock/jitter/max_ns"] = jitter.max_ns
        return fields

    def _parts(self) -> dict:
        """The stages whose state is part of the runtime's: the estimator, guard, smoother and
        the policy's observation (its gait clocks and frame history), an image input's camera
        stage and its plant camera, and the policy, backend and fault injector where they have a
        ``state_dict``."""
        rt = self.rt
        parts = {"estimator": rt.estimator, "guard": rt.guard, "smoother": rt.smoother}
        parts["observation"] = ObservationState(rt.spec.plan, rt.envs)
        parts.update(rt.base_tick.parts())  # a floating base's estimator and fall check
        if rt.height_map is not None:  # a policy with a height scan: its elevation map
            parts["height_map"] = rt.height_map
        if getattr(rt, "cameras", None) is not None:  # a policy with an image input
            parts["camera"] = rt.cameras
            source = rt.cameras.source  # the plant's camera: its frames in flight, its streams
            if source is not None and hasattr(source, "state_dict"):
                parts["camera_source"] = source
        for name, part in (
            ("policy", rt.policy),
            ("backend", rt.backend),
            ("injector", rt.injector),
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
        rt = self.rt
        out: dict = take(self._state_fields(), env)
        out.update({k: np.array(v, copy=True) for k, v in self._shared_fields().items()})
        out["ticks"], out["time"] = int(rt.ticks), float(rt.time)
        clock = rt.clock
        out["clock/overruns"] = int(clock.overruns)
        out["clock/missed_periods"] = int(clock.missed_periods)
        return out | parts_state_dict(self._parts(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> tuple[int, float]:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``; the shared fields
        either way), into a runtime built with the same robot, policy, backend kind and clock;
        returns the ``(ticks, time)`` it holds, for the runtime to set. A started runtime is
        not needed: the state replaces what ``start`` sets (a wall clock's deadlines start anew
        here).

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
        clock = self.rt.clock
        clock.overruns, clock.missed_periods = overruns, missed
        load_parts(self._parts(), state, env)
        clock.start()
        return ticks, now
