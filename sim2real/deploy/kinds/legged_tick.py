"""The part of the tick a floating base adds (:class:`LeggedTick`, the stage
:meth:`sim2real.deploy.kinds.legged.Legged.tick_stage` gives the runtime): after the joints'
estimate, the base estimate from the IMU and the legs' kinematics, the feet's contact, the gait
clock, the stale IMU's stop and the fall check's (compiled as two calls bound to the runtime's
arrays), and the IMU's own attitude where it sends one (``RobotState.sensed_orientation``: the
source of a motion-tracking policy's anchor, as rl_sar's G1 loop reads
``imu_state.quaternion``); after the smoother, the damped command of every env in a safe stop
(a legged robot's every stop lays it down). A phase-clocked policy's motion clock
(:class:`~sim2real.deploy.core.phase_clock.MotionPhaseClock`) is the stage's too, advanced first.
A fixed base adds none (:class:`sim2real.deploy.kinds.arm.FixedBase`).

The stage is given its runtime (:class:`~sim2real.deploy.runtime.loop.Runtime`) and reads its
public arrays (``mode``, ``time``, ``lying_expected``, ``height_map``, ``supervision``); it
imports nothing above the kinds' floor.
"""

from __future__ import annotations

import functools
import operator

import numpy as np
import pinocchio as pin

from sim2real.deploy.core.attitude import quat_multiply
from sim2real.deploy.core.attitude_kernel import quat_mul_finite_rows
from sim2real.deploy.core.modes import RAMP_IN, RUNNING, SAFE_STOP
from sim2real.deploy.core.phase_clock import phase_clock_for
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.kernels import mark_at_least
from sim2real.deploy.kernels.calls import bind, fits


class LeggedTick:
    """A floating base's part of ``runtime``'s tick (module docstring).

    Args:
        runtime: The runtime being built (its ``robot``, ``envs``, ``backend``; its ``mode``,
            ``supervision`` and the rest are read once it is built).
        base_estimator: :class:`~sim2real.deploy.estimation.base.BaseStateEstimator` of its envs.
        fall_detector: :class:`~sim2real.deploy.estimation.fall.FallDetector` of its envs.

    Attributes:
        stages: ``(base_estimator, fall_detector)``.
        fusable: False: the base's estimate runs between the joints' and the observation.
        compiled: The work after the base estimate runs compiled (:meth:`screens`); False:
            numpy's path (the reference).
        bound: The compiled calls' arrays and calls (:meth:`screens`), or None.
        phase_clock: The motion clock of a policy with a ``motion_phase`` block
            (``RobotState.motion_time`` its time; a part of the runtime's state), else None.
    """

    fusable = False

    def __init__(self, runtime, base_estimator, fall_detector):
        self.rt = runtime
        self.stages = (base_estimator, fall_detector)
        self.compiled = True
        self.bound = None
        #: ``(imu_orientation, sensed, call)``: :meth:`sense`'s compiled call bound to those
        #: arrays (None: numpy's path for arrays it does not take)
        self._sense_bound: tuple | None = None
        #: the backend's ``damp(envs)`` (drivers with a damping mode of their own, e.g. a
        #: Unitree robot's: kp 0, a damping kd), told every tick which envs damp
        self._backend_damp = getattr(runtime.backend, "damp", None)
        #: (envs,) bool: the envs whose command damps, this tick's
        self._damp = np.zeros(runtime.envs, dtype=bool)
        self._damp_bound = None  # (mode, call): damp's compiled mask bound to the runtime's mode
        mark_at_least(np.zeros(1, dtype=np.int8), SAFE_STOP, np.zeros(1, dtype=bool))  # compiled
        #: (4,) ``w x y z``: the base-to-IMU-site rotation, the conjugate of the site's in the
        #: base (the estimator's ``imu_to_base``): ``q_base = q_site * site_to_base``
        x, y, z, w = pin.Quaternion(np.asarray(base_estimator.imu_to_base, float)).coeffs()
        self._site_to_base = np.array([w, -x, -y, -z])
        self.phase_clock = phase_clock_for(runtime.spec, runtime.state, runtime.dt)

    def bind(self) -> None:
        """Compile (or load) and bind the tick's calls before its first tick."""
        self.screens(self.rt.state)

    def start(self, frame) -> None:
        """``Runtime.start``: the base estimate anchored as the IMU's attitude or
        accelerometer says (yaw 0)."""
        acc = frame.imu_acceleration
        finite = np.isfinite(acc).all() and (np.linalg.norm(acc, axis=1) > 0).all()
        self.stages[0].reset(
            frame.time, acceleration=acc if finite else None, orientation=frame.imu_orientation
        )
        sensed = self.rt.state.sensed_orientation
        if sensed is not None:  # until the IMU's first attitude: the estimate's (yaw 0)
            sensed[:] = self.stages[0].orientation
            self.sense(frame, sensed)

    def sense(self, frame, sensed: np.ndarray) -> None:
        """Into ``sensed`` (envs, 4), the base's orientation by the IMU's own attitude
        (``frame.imu_orientation``, the IMU site's) of each env whose reading arrived; an env
        without one (a lost or late reading) keeps its last, as a loop reading the last
        ``LowState`` does."""
        quat = frame.imu_orientation
        if quat is None:
            return
        bound = self._sense_bound
        if bound is None or bound[0] is not quat or bound[1] is not sensed:
            bound = self._sense_bound = (quat, sensed, self._sense_call(quat, sensed))
        if bound[2] is not None:  # the same products, one compiled call (quat_mul_finite_rows)
            bound[2]()
            return
        ok = np.isfinite(quat).all(axis=1)
        if ok.all():
            sensed[:] = quat_multiply(quat, self._site_to_base)
        elif ok.any():
            sensed[ok] = quat_multiply(quat[ok], self._site_to_base)

    def _sense_call(self, quat: np.ndarray, sensed: np.ndarray):
        """:meth:`sense`'s products as one compiled call bound to ``quat`` and ``sensed``
        (:func:`~sim2real.deploy.core.attitude_kernel.quat_mul_finite_rows`), or None where one
        is not a C-contiguous (envs, 4) float64 array (numpy's path)."""
        shape = (self.rt.envs, 4)
        if not (fits(quat, np.float64, shape) and fits(sensed, np.float64, shape)):
            return None
        if not sensed.flags.writeable:
            return None
        return bind(quat_mul_finite_rows, quat, self._site_to_base, sensed)

    def restart(self, t, envs: np.ndarray) -> None:
        """``Runtime.restart``: the envs of ``envs`` upright again at time ``t``."""
        self.stages[0].reset(t, envs=envs)

    def parts(self) -> dict:
        """The stages whose state is the runtime's: ``base_estimator``, ``fall_detector`` and a
        phase-clocked policy's ``motion_phase`` clock."""
        parts = {"base_estimator": self.stages[0], "fall_detector": self.stages[1]}
        if self.phase_clock is not None:
            parts["motion_phase"] = self.phase_clock
        return parts

    def damping(self, mode: np.ndarray) -> np.ndarray:
        """(envs,) bool: the envs whose command damps: SAFE_STOP or FAULTED (holding its stance
        against gravity with a low-gain PD heated the thighs past 200 degC in simulation: it
        lies down instead)."""
        return mode >= SAFE_STOP  # SAFE_STOP or FAULTED, the last modes

    def lying(self, mode: np.ndarray) -> np.ndarray:
        """(envs,) bool: the envs lying damped after a stop (:meth:`damping`'s): what the
        monitors count apart (what a fallen robot's joints do on the floor is not its
        policy's)."""
        return self.damping(mode)

    def damp(self, cmd: np.ndarray, state: RobotState) -> None:
        """After the smoother: the command of the envs in SAFE_STOP or FAULTED damps (their
        drives' own damping mode too, where the backend has one)."""
        rt, damp, bound = self.rt, self._damp, self._damp_bound
        if bound is None or bound[0] is not rt.mode:  # np.greater_equal and .any(), one call
            bound = self._damp_bound = (rt.mode, self._damp_call(rt.mode))
        if bound[1]():
            rt.supervision.damp(cmd, state, damp)
        if self._backend_damp is not None:  # drivers with a damping mode of their own
            self._backend_damp(damp)

    def _damp_call(self, mode: np.ndarray):
        """:meth:`damp`'s mask of ``mode`` into ``_damp``, answering whether any env damps: the
        kernel bound to them where ``mode`` is a C-contiguous (envs,) int8 array, else through
        numba's dispatch."""
        if fits(mode, np.int8, (self.rt.envs,)):
            return bind(mark_at_least, mode, SAFE_STOP, self._damp)
        return functools.partial(mark_at_least, mode, SAFE_STOP, self._damp)

    def update(self, frame, state: RobotState) -> None:
        """After the joints' estimate: the base estimate from the IMU and leg kinematics, the
        feet's contact, the gait clock; an IMU silent past ``Robot.stale_limit`` makes a safe
        stop (stale_sensor), a fall (:class:`sim2real.deploy.estimation.fall.FallDetector`) a
        damped one (fall); so does an elevation map older than the stale limit (a policy with
        a height scan, :mod:`sim2real.deploy.runtime.height_map`)."""
        rt = self.rt
        est, fd = self.stages
        if self.phase_clock is not None:  # the modes the previous tick ended in
            self.phase_clock.advance(rt.mode)
        if rt.height_map is not None:
            rt.supervision.safe_stop(rt.height_map.update(frame), "stale_sensor")
        est.update(frame, state.q, state.dq, out=state.base)
        if state.sensed_orientation is not None:
            self.sense(frame, state.sensed_orientation)
        calls = self.screens(state) if self.compiled else None
        if calls is not None:  # the same, compiled (estimation.fall's stale_screen, fall_screen)
            stale_call, fall_call, stale, fall = calls
            if stale_call(rt.time):
                rt.supervision.safe_stop(stale, "stale_sensor")
            # the estimator's feet's placements: no second forward kinematics
            fd.screen(state, est.foot_position)
            if fall_call():
                rt.supervision.safe_stop(fall, "fall")
            return
        state.foot_contact[:] = est.contact  # the sensor's, or the kinematics'
        state.clock[:] = rt.time
        stale = est.time_since_fresh > rt.robot.stale_limit
        rt.supervision.safe_stop(stale, "stale_sensor")
        fallen = fd.check(state, est.foot_position)
        fallen &= (rt.mode == RUNNING) | (rt.mode == RAMP_IN)
        # an operator laying the robot down or standing it up: a low base is no fall, a tilt is
        fallen &= ~rt.lying_expected | fd.signals[:, 0]
        rt.supervision.safe_stop(fallen, "fall")

    def screens(self, state: RobotState):
        """:meth:`update`'s work after the estimate as two compiled calls bound to the
        runtime's arrays (made again when one is another array): ``(stale_call(time),
        fall_call(), stale, fall)``, the calls answering whether any env is stale or fell, into
        the masks ``stale`` and ``fall``; None where an array does not fit them (numpy's path)."""
        rt = self.rt
        est, fd = self.stages
        key = (state.foot_contact, state.clock, est.contact, est.time_since_fresh, rt.mode)
        key += (rt.lying_expected, fd.signals)
        bound = self.bound
        if bound is not None and all(map(operator.is_, key, bound[0])):
            return bound[1]
        from sim2real.deploy.estimation.fall import fall_screen, stale_screen

        self.bound = None
        envs, feet = rt.envs, est.contact.shape[1]
        ok = (
            fits(state.foot_contact, np.float64, (envs, feet))
            and fits(state.clock, np.float64, (envs,))
            and fits(est.contact, np.bool_, (envs, feet))
            and isinstance(est.time_since_fresh, np.ndarray)
            and est.time_since_fresh.dtype == np.float64
            and fits(rt.mode, np.int8, (envs,))
            and fits(rt.lying_expected, np.bool_, (envs,))
        )
        if not ok:
            return None
        stale, fall = np.zeros(envs, dtype=bool), np.zeros(envs, dtype=bool)
        limit = float(rt.robot.stale_limit)
        stale_call = bind(
            stale_screen, est.contact, state.foot_contact, state.clock, est.time_since_fresh,
            limit, stale, rest=(0.0,),
        )  # fmt: skip
        fall_call = bind(
            fall_screen, fd.fallen_mask, rt.mode, rt.lying_expected, fd.signals, fall,
            int(RUNNING), int(RAMP_IN),
        )  # fmt: skip
        self.bound = (key, (stale_call, fall_call, stale, fall))
        return self.bound[1]
