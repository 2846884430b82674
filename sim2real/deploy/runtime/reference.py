"""The numpy reference of the runtime's compiled tick: :class:`ReferenceRuntime`, a
:class:`~sim2real.deploy.runtime.loop.Runtime` with the same constructor whose numeric logic runs in numpy:
the guard (:class:`~sim2real.deploy.safety.reference.ReferenceGuard`), the smoother
(:class:`~sim2real.deploy.smoothing.reference.ReferenceSmoother`), the observation
(:func:`~sim2real.deploy.spec.reference.observation_reference`), the supervision and action screen
(:class:`ReferenceSupervision`, a :class:`~sim2real.deploy.runtime.supervision.Supervision` with
:meth:`~ReferenceSupervision.supervise` and :meth:`~ReferenceSupervision.screen`) and the latency
histograms
(:meth:`~sim2real.deploy.core.latency.LatencyHistogram.add_stages`). Both give the same numbers bit
for bit (``tests/test_compiled_tick.py``); the estimator is the compiled one in both.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import (
    FAULT_CAUSES,
    FAULTED,
    HOME_TOLERANCE,
    NAN_ACTION_LIMIT,
    PD_RAMP_REST_SPEED,
    RAMP_IN,
    RUNNING,
    SAFE_STOP,
)
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.observe.long_ticks import record
from sim2real.deploy.runtime.loop import Runtime
from sim2real.deploy.runtime.supervision import Supervision
from sim2real.deploy.safety.reference import ReferenceGuard
from sim2real.deploy.smoothing.reference import ReferenceSmoother
from sim2real.deploy.spec.reference import observation_reference


class ReferenceSupervision(Supervision):
    """A :class:`~sim2real.deploy.runtime.supervision.Supervision` with the numpy references of the
    compiled screen and supervision (:mod:`sim2real.deploy.runtime.supervision_kernel`)."""

    def screen(self, action: np.ndarray) -> np.ndarray:
        """Non-finite output: hold the last valid action and count; too many in a row: safe stop
        (the reference of the compiled screen)."""
        if np.isfinite(action).all():  # the common case
            self.action[:] = action
            self.last_valid_action[:] = action
            self.nan_streak[:] = 0
            return self.action
        bad = ~np.isfinite(action).all(axis=1)
        self.counters.non_finite_actions += bad
        self.nan_streak[bad] += 1
        self.action[:] = np.where(bad[:, None], self.last_valid_action, action)
        self.safe_stop(self.nan_streak >= NAN_ACTION_LIMIT, "non_finite_action")
        self.nan_streak[~bad] = 0
        self.last_valid_action[~bad] = action[~bad]
        return self.action

    def supervise(self, state: RobotState, drive_errors: np.ndarray | None) -> None:
        """The reference of the compiled supervision (the thermal derating and the re-anchoring
        after it are the runtime's): stale sensors, over-temperature, drive errors, overruns; end
        of RAMP_IN and of safe stops."""
        stale = (self.estimator.time_since_fresh > self.robot.stale_limit).any(axis=1)
        self.safe_stop(stale, "stale_sensor")
        hot = (state.winding_temperature > self.temp_max).any(axis=1)
        self.safe_stop(hot, "over_temperature")
        if drive_errors is not None and drive_errors.any():
            self.drive_errors |= drive_errors
            self.safe_stop(drive_errors.any(axis=1), "servo_error")
        if self.clock.realtime and self.overrun_ring.mean() > self.overrun_rate_limit:
            self.safe_stop(np.ones(self.envs, dtype=bool), "overrun")

        mode = self.mode
        if not (mode == RUNNING).all():  # else nothing to end (the common case)
            speed = np.abs(state.dq).max(axis=1)
            at_rest = speed < self.rest_speed
            pose = self.smoother.commanded if self.home_from_command else state.q
            home = ((np.abs(pose - self.home) < HOME_TOLERANCE) | ~self.homed).all(axis=1)
            ramp_rest = PD_RAMP_REST_SPEED if self.home_from_command else self.rest_speed
            took_over = (mode == RAMP_IN) & (speed < ramp_rest) & home
            if took_over.any():
                mode[took_over] = RUNNING
                self.reset_policy(took_over)  # the policy starts from its initial state
            stopping = mode == SAFE_STOP
            ticks = self.stop_ticks
            ticks += stopping
            # at rest, or SAFE_STOP_TIMEOUT after the stop began (counted once, when reached)
            timed_out = stopping & (ticks >= self.stop_timeout)
            stopped = (stopping & at_rest) | timed_out
            if stopped.any():
                self.counters.safe_stop_timeouts += (
                    timed_out & ~at_rest & (ticks == self.stop_timeout)
                )
                thermal = self.cause == FAULT_CAUSES.index("over_temperature")
                cool = (state.winding_temperature < self.temp_start).all(axis=1)
                # a servo whose own protection tripped meanwhile has cut its torque: no resume
                latched = self.drive_errors.any(axis=1)
                resume = stopped & thermal & cool & ~latched
                faulted = stopped & (~thermal | latched)
                mode[faulted] = FAULTED
                ticks[faulted | resume] = 0
                if resume.any():
                    mode[resume] = RAMP_IN
                    self.cause[resume] = -1
                    self.smoother.sync(state.q, self.at_rest, envs=resume)
                    self.reset_policy(resume)


class ReferenceRuntime(Runtime):
    """A :class:`~sim2real.deploy.runtime.loop.Runtime` whose tick runs the numpy references (module
    docstring); the same arguments, attributes and errors. It compiles nothing."""

    supervision_type = ReferenceSupervision

    def _build_stages(self) -> tuple[ReferenceGuard, ReferenceSmoother]:
        """The guard and the smoother (numpy references)."""
        envs, mode = self.envs, self.mode_name
        bounded = self.targets.bounded()  # as Runtime._build_stages
        smoother = ReferenceSmoother(self.robot, envs, mode, bounded=bounded)
        return ReferenceGuard(self.robot, envs, mode, self.kind), smoother

    def _compile(self) -> None:
        """Nothing to compile."""
        return None

    def _supervise(self, state: RobotState, drive_errors: np.ndarray | None) -> None:
        """The guard's ``update_thermal``, :meth:`Supervision.supervise` and :meth:`_reanchor`."""
        self.guard.update_thermal(state.winding_temperature)
        self.supervision.supervise(state, drive_errors)
        self._reanchor(state)

    def _observe(self, state: RobotState) -> np.ndarray:
        """:func:`~sim2real.deploy.spec.reference.observation_reference`."""
        return observation_reference(self.spec, state, self.goal, out=self._obs)

    def _act(self, action: np.ndarray, state: RobotState) -> tuple[np.ndarray, np.ndarray]:
        """The fault injector's filter, :meth:`Supervision.screen`, ``spec.action_to_target``
        and :meth:`Supervision.override`."""
        if self.injector is not None:
            action = self.injector.filter_action(self.time, action)
        action = self.supervision.screen(action)
        target = self.spec.action_to_target(action, state, out=self._target)
        return action, self.supervision.override(target, state)

    def _bind_books(self):
        """:meth:`LatencyHistogram.add_stages` and ``add`` in numpy, then
        :func:`~sim2real.deploy.observe.long_ticks.record` (compiled): ``(tick) -> None``."""
        st, table, period = self._stamps, self.long_ticks.table, self._period

        def books(tick: int) -> None:
            self.latency.add_stages(st)
            self.tick_cost.add(0, st[8] - st[0] - (st[8] - st[7]))  # runtime cost w/o physics
            record(table, st, period, tick)

        return books
