"""A floating-base robot's part of the tick after its joints' estimate (:class:`LeggedTick`):
the base estimate from the IMU and the legs' kinematics, the feet's contact, the gait clock, the
stale IMU's stop and the fall check's, compiled as two calls bound to the runtime's arrays.

:class:`LeggedTick` is a base class of :class:`~sim2real.deploy.runtime.loop.Runtime`; its methods
work on the runtime's attributes (set in ``Runtime.__init__``).
"""

from __future__ import annotations

import operator

import numpy as np

from sim2real.deploy.core.modes import RAMP_IN, RUNNING
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.kernels.calls import bind, fits


class LeggedTick:
    """The floating-base tick of a :class:`~sim2real.deploy.runtime.loop.Runtime` (module
    docstring)."""

    def _update_base(self, frame, state: RobotState) -> None:
        """A floating-base robot's tick: the base estimate from the IMU and leg kinematics, the
        feet's contact, the gait clock; an IMU silent past ``safety.stale_limit`` makes a safe
        stop (stale_sensor), a fall (:class:`sim2real.deploy.estimation.fall.FallDetector`) a damped one
        (fall); so does an elevation map older than the stale limit (a policy with a height scan,
        :mod:`sim2real.deploy.runtime.height_map`)."""
        if self.height_map is not None:
            self.supervision.safe_stop(self.height_map.update(frame), "stale_sensor")
        self.base_estimator.update(frame, state.q, state.dq, out=state.base)
        calls = self._base_screens(state) if self.compiled_base_screens else None
        if calls is not None:  # the same, compiled (estimation.fall's stale_screen, fall_screen)
            stale_call, fall_call, stale, fall = calls
            if stale_call(self.time):
                self.supervision.safe_stop(stale, "stale_sensor")
            # the estimator's feet's placements: no second forward kinematics
            self.fall_detector.screen(state, self.base_estimator.foot_position)
            if fall_call():
                self.supervision.safe_stop(fall, "fall")
            return
        state.foot_contact[:] = self.base_estimator.contact  # the sensor's, or the kinematics'
        state.clock[:] = self.time
        stale = self.base_estimator.time_since_fresh > self.robot.config.safety.stale_limit
        self.supervision.safe_stop(stale, "stale_sensor")
        fallen = self.fall_detector.check(state, self.base_estimator.foot_position)
        fallen &= (self.mode == RUNNING) | (self.mode == RAMP_IN)
        # an operator laying the robot down or standing it up: a low base is no fall, a tilt is
        fallen &= ~self.lying_expected | self.fall_detector.signals[:, 0]
        self.supervision.safe_stop(fallen, "fall")

    def _base_screens(self, state: RobotState):
        """:meth:`_update_base`'s work after the estimate as two compiled calls bound to the
        runtime's arrays (made again when one is another array): ``(stale_call(time),
        fall_call(), stale, fall)``, the calls answering whether any env is stale or fell, into
        the masks ``stale`` and ``fall``; None where an array does not fit them (numpy's path)."""
        est, fd = self.base_estimator, self.fall_detector
        key = (state.foot_contact, state.clock, est.contact, est.time_since_fresh, self.mode)
        key += (self.lying_expected, fd.signals)
        bound = self._base_screens_bound
        if bound is not None and all(map(operator.is_, key, bound[0])):
            return bound[1]
        from sim2real.deploy.estimation.fall import fall_screen, stale_screen

        self._base_screens_bound = None
        envs, feet = self.envs, est.contact.shape[1]
        ok = (
            fits(state.foot_contact, np.float64, (envs, feet))
            and fits(state.clock, np.float64, (envs,))
            and fits(est.contact, np.bool_, (envs, feet))
            and isinstance(est.time_since_fresh, np.ndarray)
            and est.time_since_fresh.dtype == np.float64
            and fits(self.mode, np.int8, (envs,))
            and fits(self.lying_expected, np.bool_, (envs,))
        )
        if not ok:
            return None
        stale, fall = np.zeros(envs, dtype=bool), np.zeros(envs, dtype=bool)
        limit = float(self.robot.config.safety.stale_limit)
        stale_call = bind(
            stale_screen, est.contact, state.foot_contact, state.clock, est.time_since_fresh,
            limit, stale, rest=(0.0,),
        )  # fmt: skip
        fall_call = bind(
            fall_screen, fd._fallen, self.mode, self.lying_expected, fd.signals, fall,
            int(RUNNING), int(RAMP_IN),
        )  # fmt: skip
        self._base_screens_bound = (key, (stale_call, fall_call, stale, fall))
        return self._base_screens_bound[1]
