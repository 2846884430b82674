"""Base state estimation of a floating-base (legged) robot: attitude, angular and linear velocity.
One error-state extended Kalman filter per env, fed by a
:class:`~sim2real.deploy.core.backend.SensorFrame`'s IMU and foot-contact fields and by the joint
estimate ``q``, ``dq`` (rad, rad/s): the kinematic- inertial filter of legged robots with leg
odometry as a velocity measurement (M. Bloesch et al., "State estimation for legged robots", RSS
2012; M. Camurri et al., "Pronto", Frontiers in Robotics and AI 2020), reduced to the states a
velocity policy observes: the base-to-world rotation, the base velocity (world, at the base
origin) and the IMU's biases, the gyro's and the accelerometer's. The IMU predicts (the
accelerometer's lever arm, a turn's centripetal term and its acceleration taken off); the
accelerometer is a weak gravity measurement; each foot in contact measures the base velocity
through the leg kinematics (a rolling sphere's centre is not its contact point). A foot whose
reading is more than
``SLIP_GATE`` (chi-square, 3 dof) from the prediction is slipping and not absorbed
(``rejected_contacts``), unless no foot has been absorbed for ``MAX_REJECTED_READINGS`` readings:
the velocity then restarts from the legs. The equations are in
:mod:`sim2real.deploy.estimation.base_kernel`, which compiles them; the reference
(:class:`~sim2real.deploy.estimation.reference.ReferenceBaseStateEstimator`) runs them in numpy through
one ``filterpy`` KalmanFilter per env.

Unlike a complementary filter that takes the accelerometer for gravity, the tilt is observed
through the velocity: a tilt error puts gravity into the integrated acceleration, which the legs
contradict, so a walking robot's own acceleration is not taken for tilt. An IMU reading that is
NaN, not newer than the last one absorbed or stamped after ``frame.time`` is not fed
(``missing_readings`` / ``stale_readings``): the output is predicted to ``frame.time`` and
``time_since_fresh`` grows. Contacts without a fresh stamp give no velocity update.
"""

from __future__ import annotations

import functools
import operator
from inspect import signature

import numpy as np
import pinocchio as pin

from sim2real.deploy.core.attitude import align_up, quaternion_to_matrix
from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import BaseState
from sim2real.deploy.core.stateful import check, env_index, put, take
from sim2real.deploy.estimation import base_tick as bt
from sim2real.deploy.estimation.base_kernel import attitude_step, imu_step, leg_step
from sim2real.deploy.estimation.base_params import (  # noqa: F401 (this module's names too)
    ACCEL_MEASUREMENT_SIGMA,
    ATTITUDE_SIGMA_FACTOR,
    DEAD_FOOT_TIME,
    INITIAL_TILT_SIGMA,
    INITIAL_VELOCITY_SIGMA,
    INITIAL_YAW_SIGMA,
    KINEMATIC_CONTACT_BAND,
    LEG_VELOCITY_SIGMA,
    MAX_REJECTED_READINGS,
    MIN_ACCEL_BIAS_SIGMA,
    MIN_ACCEL_BIAS_WALK,
    MIN_ATTITUDE_SIGMA,
    MIN_GYRO_BIAS_SIGMA,
    MIN_GYRO_BIAS_WALK,
    REST_ACCELERATION_TOLERANCE,
    SLIP_GATE,
    UNMODELLED_ACCELERATION,
    foot_radii,
    packed_constants,
    require_floating_base,
)
from sim2real.deploy.estimation.base_steps import BaseSteps
from sim2real.deploy.kernels.calls import bind
from sim2real.robots import Robot

_ALIGNED = pin.LOCAL_WORLD_ALIGNED  # the feet's velocities' frame (_read_legs)


class BaseStateEstimator(BaseSteps):
    """The kinematic-inertial error-state filter of ``envs`` floating-base robots (module
    docstring).

    Args:
        robot: A floating-base robot (robot.toml's ``[base]``).
        envs: Batch size.
        leg_sigma: Leg odometry noise, m/s (``LEG_VELOCITY_SIGMA``).
        accel_sigma: The accelerometer as a gravity measurement, m/s^2
            (``ACCEL_MEASUREMENT_SIGMA``).
        slip_gate: Chi-square bound of a foot's reading (``SLIP_GATE``); ``inf``: no gate.

    Attributes:
        orientation: (envs, 4) base-to-world quaternion at ``filter_time``.
        velocity: (envs, 3) m/s, base velocity, world frame.
        bias: (envs, 6) the IMU's biases, base frame: the gyro's (rad/s, ``gyro_bias``, a view
            of the first three columns) and the accelerometer's (m/s^2, ``accel_bias``, the
            last three).
        covariance: (envs, 12, 12) the error state's covariance (rad, m/s, rad/s, m/s^2).
        velocity_variance: (envs,) m^2/s^2, the mean of the velocity block's diagonal (derived).
        filter_time: (envs,) s, stamp of the last absorbed IMU reading.
        time_since_fresh: (envs,) s, ``frame.time - filter_time`` at the last update.
        missing_readings, stale_readings: (envs,) int IMU readings not absorbed.
        velocity_updates: (envs,) int feet readings absorbed; rejected_contacts: (envs,) int
            feet in contact whose reading was gated out as a slip.

    The state arrays are views into the packed arrays of the compiled tick
    (:mod:`sim2real.deploy.estimation.base_tick`): written in place, never rebound. The tick
    runs compiled unless a subclass replaces a step of :class:`~.base_steps.BaseSteps` (the
    filterpy reference): then one env at a time, in Python.

    Raises:
        ValueError: a fixed-base robot, an IMU site off the base body or ``envs < 1``.
    """

    def __init__(
        self,
        robot: Robot,
        envs: int,
        leg_sigma: float = LEG_VELOCITY_SIGMA,
        accel_sigma: float = ACCEL_MEASUREMENT_SIGMA,
        slip_gate: float = SLIP_GATE,
    ):
        require_floating_base(robot, "base estimation")
        if envs < 1:
            raise ValueError(f"envs must be >= 1, got {envs}")
        self.robot, self.envs = robot, envs
        imu = robot.config.sensors.imu
        m = robot.mj_model
        if m.body(m.site_bodyid[robot.imu_site_id]).name != robot.base_body:
            raise ValueError(f"robot {robot.name}: the IMU site is not on the base body")
        self._imu_to_base = quaternion_to_matrix(m.site_quat[robot.imu_site_id])
        #: (3,) m, the IMU site on the base (the accelerometer's lever arm)
        self.lever_arm = np.array(m.site_pos[robot.imu_site_id], dtype=np.float64)
        # the filter's world frame is the gravity frame: its z axis up against gravity (the
        # model's gravity may be tilted to stand for a slope; an IMU knows only gravity)
        self.gravity = np.array([0.0, 0.0, -np.linalg.norm(m.opt.gravity)])
        self.gyro_variance = imu.gyro_noise_sigma**2
        self.accel_variance = imu.accel_noise_sigma**2 + UNMODELLED_ACCELERATION**2
        self.bias_walk_variance = max(imu.gyro_bias_walk, MIN_GYRO_BIAS_WALK) ** 2
        self.bias_variance = max(imu.gyro_bias_sigma, MIN_GYRO_BIAS_SIGMA) ** 2
        self.accel_bias_walk_variance = max(imu.accel_bias_walk, MIN_ACCEL_BIAS_WALK) ** 2
        self.accel_bias_variance = max(imu.accel_bias_sigma, MIN_ACCEL_BIAS_SIGMA) ** 2
        self.leg_variance = float(leg_sigma) ** 2
        self.accel_meas_variance = float(accel_sigma) ** 2
        self.slip_gate = float(slip_gate)
        onboard = imu.orientation_sigma
        self.attitude_variance = (
            None
            if onboard is None
            else max(onboard * ATTITUDE_SIGMA_FACTOR, MIN_ATTITUDE_SIGMA) ** 2
        )
        self.radii = foot_radii(robot)
        self._pin = robot.pin_model.createData()
        self._q = robot.pin_configuration(robot.home)
        self._v = np.zeros(robot.pin_model.nv)
        n_feet, n_joints = robot.n_feet, robot.n_joints
        # the state, packed for the compiled tick (base_tick's layout); the attributes are views
        self._x = x = np.zeros((envs, bt.NX))
        x[:, bt.ORIENTATION] = 1.0
        x[:, bt.TIME], x[:, bt.AGE] = np.nan, np.inf
        self.orientation = x[:, bt.ORIENTATION : bt.VELOCITY]
        self.velocity = x[:, bt.VELOCITY : bt.BIAS]
        self.bias = x[:, bt.BIAS : bt.OMEGA]
        self.gyro_bias = self.bias[:, :3]  # views: written in place, never rebound
        self.accel_bias = self.bias[:, 3:]
        self.angular_velocity = x[:, bt.OMEGA : bt.TIME]
        self.filter_time, self.time_since_fresh = x[:, bt.TIME], x[:, bt.AGE]
        self.covariance = np.tile(self._initial_covariance(), (envs, 1, 1))
        self._n = np.zeros((envs, 5), dtype=np.int64)
        self.missing_readings, self.stale_readings = self._n[:, bt.MISSING], self._n[:, bt.STALE]
        self.velocity_updates = self._n[:, bt.UPDATES]
        self.rejected_contacts, self._rejected_run = self._n[:, bt.REJECTED], self._n[:, bt.RUN]
        self._initialized = np.zeros(envs, dtype=bool)
        self._all_initialized = False
        self._feet = np.zeros((2, envs, n_feet), dtype=bool)
        #: (envs, n_feet) bool: the feet in contact at the last update: the sensor's, or (at a
        #: fresh IMU reading) the kinematics' for a foot in ``dead_feet``
        self.contact = self._feet[0]
        #: (envs, n_feet) bool: feet whose force reading stayed the same for ``DEAD_FOOT_TIME``
        self.dead_feet = self._feet[1]
        #: each foot's last force reading and its time; each encoder's last reading (rad) and
        #: its stamp (s)
        self._force = np.full((2, envs, n_feet), np.nan)
        self._force_last, self._force_since = self._force
        self._encoder = np.full((2, envs, n_joints), np.nan)
        self._encoder_position, self._encoder_stamp = self._encoder
        # the compiled tick's constants and work arrays
        self._p = packed_constants(self)
        self._foot_ids = list(robot.foot_frame_ids)
        self._legs = np.zeros(envs, dtype=np.int64)
        self._rate = np.zeros((envs, n_joints))
        self._no_velocity = np.full((envs, n_joints), np.nan)
        self._foot_motion = np.zeros((envs, n_feet, 6))
        self._foot_position = np.zeros((envs, n_feet, 3))
        self._held = -1  # the env whose legs' kinematics the Pinocchio data holds (-1: none)
        self._bound_calls = None  # (the arrays, the two calls bound to them): see _bound
        #: the tick runs compiled unless a subclass replaces the algebra's steps (the reference)
        self._compiled = all(
            getattr(type(self), name) is getattr(BaseStateEstimator, name)
            for name in ("_imu_step", "_attitude_step", "_absorb_feet", "_legs_step")
        )
        self._warm_kernels()

    def _warm_kernels(self) -> None:
        """Compile (or load from numba's cache) the filter's steps before the first tick, for
        the argument types the tick passes, on scratch copies (nothing of the estimator
        changes): a first call inside a tick costs milliseconds."""
        q, v, b = self.orientation[0].copy(), self.velocity[0].copy(), self.bias[0].copy()
        P, omega = self.covariance[0].copy(), np.zeros(3)
        up = -self.gravity
        imu_step(
            q, v, b, P, np.zeros(3), up, 0.02, self.lever_arm, self.gravity,
            self.gyro_variance, self.accel_variance, self.bias_walk_variance,
            self.accel_bias_walk_variance, self.accel_meas_variance,
            3 * REST_ACCELERATION_TOLERANCE, omega,
        )  # fmt: skip
        leg_step(q, v, b, P, np.zeros(3), np.zeros(3), 0.0, self.leg_variance, self.slip_gate)
        attitude_step(q, v, b, P, np.eye(3), MIN_ATTITUDE_SIGMA**2)
        leg_step(q, v, b, P, np.zeros(3), np.zeros(3), 0.0, self.leg_variance, np.inf)
        # the batched tick, one env of NaN readings (no step taken), for a frame of float64
        # arrays and bool contacts
        nj, nf = self.robot.n_joints, self.robot.n_feet
        x, n, feet = self._x[:1].copy(), self._n[:1].copy(), self._feet[:, :1].copy()
        one, nan3, joints = np.zeros(1), np.full((1, 3), np.nan), np.zeros((1, nj))
        legs = np.zeros(1, dtype=np.int64)
        bt.absorb_imu(
            x, P[None].copy(), n, feet, self._force[:, :1].copy(), self._encoder[:, :1].copy(),
            self._p, one, one, nan3, nan3, np.zeros((1, 4)), np.zeros((1, nf)),
            np.zeros((1, nf), dtype=bool), one, joints, joints, joints, joints, joints,
            joints.copy(), legs,
        )  # fmt: skip
        bind(bt.tick_stage, bt.TICK.empty(), rest=(0,))
        out = BaseState.zeros(1)
        bt.absorb_legs(
            x, P[None].copy(), n, feet, self._p, one, one, legs, self._foot_motion[:1],
            self._foot_position[:1], out.orientation, out.projected_gravity,
            out.linear_velocity, out.angular_velocity, out.linear_velocity_world,
        )  # fmt: skip

    def __getstate__(self) -> dict:
        """A copy (``copy.deepcopy``, pickle) binds its kernels afresh at its first update (they
        are bound to the frame's arrays, which a copy of the estimator alone does not share)."""
        return self.__dict__ | {"_bound_calls": None}

    def _initial_covariance(self) -> np.ndarray:
        """(12, 12) the error state's covariance at a reset (``INITIAL_*_SIGMA``, the IMU's
        turn-on biases)."""
        sigma = [INITIAL_TILT_SIGMA] * 2 + [INITIAL_YAW_SIGMA] + [INITIAL_VELOCITY_SIGMA] * 3
        return np.diag(
            np.concatenate(
                [
                    np.array(sigma) ** 2,
                    np.full(3, self.bias_variance),
                    np.full(3, self.accel_bias_variance),
                ]
            )
        )

    @property
    def imu_to_base(self) -> np.ndarray:
        """(3, 3) float64, the rotation of the IMU's frame into the base's (from the MJCF's IMU
        site): a vector the IMU measures is ``imu_to_base @ v`` in the base frame."""
        return self._imu_to_base

    @property
    def velocity_variance(self) -> np.ndarray:
        """(envs,) m^2/s^2, the mean of the covariance's velocity block's diagonal."""
        return np.trace(self.covariance[:, 3:6, 3:6], axis1=1, axis2=2) / 3

    # ------------------------------------------------------------------ lifecycle
    def reset(self, t, acceleration: np.ndarray | None = None, envs=None, orientation=None) -> None:
        """Start the filters at rest at time ``t`` (s; float or (envs,)).

        ``orientation``: (envs, 4) the IMU's own attitude (``SensorFrame.imu_orientation``):
        where a row is finite, the initial roll and pitch are its (yaw 0). Else
        ``acceleration``: (envs, 3) accelerometer readings (m/s^2, IMU frame) of the robot at
        rest: the initial roll and pitch put them along the world's up (yaw 0); default upright.
        A reading whose magnitude is more than ``REST_ACCELERATION_TOLERANCE`` from gravity's is
        not the robot at rest (dropped on its feet, landing) and is ignored: upright.
        Bias estimates restart at 0, velocity at 0, the covariance at its initial value.
        ``envs``: bool mask or indices (default all).

        Raises:
            ValueError: a non-finite ``t`` or acceleration in a reset env.
        """
        sel = np.arange(self.envs)[slice(None) if envs is None else envs]
        t = np.broadcast_to(np.asarray(t, dtype=np.float64), (self.envs,))
        if not np.isfinite(t[sel]).all():
            raise ValueError("reset: t must be finite")
        for e in sel:
            q = np.array([1.0, 0.0, 0.0, 0.0])
            if orientation is not None and np.isfinite(orientation[e]).all():
                measured = quaternion_to_matrix(orientation[e]) @ self._imu_to_base.T
                q = align_up(measured[2])  # the world's up in the base frame: its tilt, yaw 0
            elif acceleration is not None:
                a = self._imu_to_base @ np.asarray(acceleration[e], dtype=np.float64)
                if not (np.isfinite(a).all() and np.linalg.norm(a) > 0):
                    raise ValueError(f"reset: env {e}: acceleration {a} is not a finite reading")
                g = np.linalg.norm(self.gravity)
                if abs(np.linalg.norm(a) - g) <= REST_ACCELERATION_TOLERANCE * g:
                    q = align_up(a / np.linalg.norm(a))
            self.orientation[e] = q
            self.covariance[e] = self._initial_covariance()
            self._restart_filter(e)
        self.bias[sel] = 0.0
        self.angular_velocity[sel] = 0.0
        self.velocity[sel] = 0.0
        self.filter_time[sel] = t[sel]
        self.time_since_fresh[sel] = 0.0
        self.contact[sel] = False
        self.dead_feet[sel] = False
        self._force_last[sel] = np.nan
        self._force_since[sel] = np.nan
        self._n[sel] = 0
        self._initialized[sel] = True
        self._all_initialized = bool(self._initialized.all())

    def _restart_filter(self, e: int) -> None:
        """Hook of the reference: env ``e``'s filter objects restart from ``covariance[e]``."""

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        return {
            "orientation": self.orientation,
            "angular_velocity": self.angular_velocity,
            "velocity": self.velocity,
            "gyro_bias": self.gyro_bias,
            "accel_bias": self.accel_bias,
            "covariance": self.covariance,
            "filter_time": self.filter_time,
            "time_since_fresh": self.time_since_fresh,
            "missing_readings": self.missing_readings,
            "stale_readings": self.stale_readings,
            "velocity_updates": self.velocity_updates,
            "rejected_contacts": self.rejected_contacts,
            "rejected_run": self._rejected_run,
            "contact": self.contact,
            "dead_feet": self.dead_feet,
            "force_last": self._force_last,
            "force_since": self._force_since,
            "initialized": self._initialized,
        }

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The filter's state (copies; conventions of :mod:`sim2real.deploy.core.stateful`): the attributes
        of the class docstring, ``rejected_run`` (envs,) int (readings in a row without an
        absorbed foot) and ``initialized`` (envs,) bool; the env axis has length 1 for one env
        ``env``."""
        return take(self._state_fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        check(self._state_fields(), state, env)
        put(self._state_fields(), state, env)
        self._all_initialized = bool(self._initialized.all())
        for e in np.arange(self.envs)[env_index(env)]:
            self._restart_filter(int(e))

    # ------------------------------------------------------------------ the tick
    def update(
        self, frame: SensorFrame, q: np.ndarray, dq: np.ndarray, out: BaseState | None = None
    ) -> BaseState:
        """Absorb the frame's fresh IMU and contact readings; the base estimate at ``frame.time``.

        Args:
            frame: A floating-base robot's frame (IMU and contact fields set).
            q, dq: (envs, n_joints) rad, rad/s, the joint estimate (``RobotState.q``, ``dq``).
            out: A :class:`BaseState` to fill (default: a new one).

        Raises:
            RuntimeError: :meth:`reset` was not called for every env.
            ValueError: a frame without IMU fields.
        """
        if not self._all_initialized:
            if not self._initialized.all():
                raise RuntimeError("BaseStateEstimator.update before reset(t) of every env")
            self._all_initialized = True
        if frame.imu_stamp is None:
            raise ValueError("frame: no IMU fields (a floating-base robot's frame expected)")
        out = BaseState.zeros(self.envs) if out is None else out
        self._held = -1
        if not self._compiled:
            return self._tick_per_env(frame, q, dq, out)
        calls = self._bound(frame, q, dq, out)
        if calls is None:  # an array the bound calls do not take: numba's dispatch
            calls = self._calls(frame, q, dq, out, bound=False)
        absorb_imu, absorb_legs = calls
        absorb_imu()
        legs = self._legs
        for e in range(self.envs) if self.envs <= 8 else np.flatnonzero(legs):
            if legs[e]:
                self._read_legs(e, q[e], legs[e] & bt.DEAD)
        absorb_legs()
        return out

    def _bound(self, frame: SensorFrame, q: np.ndarray, dq: np.ndarray, out: BaseState):
        """The tick's two kernels bound to these arrays (:func:`~sim2real.deploy.kernels.calls.
        bind`; made again when one of them is another array), or None where one is not a
        C-contiguous array (numba's dispatch then)."""
        key = (
            frame.time, frame.imu_stamp, frame.imu_angular_velocity, frame.imu_acceleration,
            frame.imu_orientation, frame.foot_force, frame.foot_contact, frame.contact_stamp,
            frame.position, frame.position_stamp, frame.velocity, q, dq, out.orientation,
            out.projected_gravity, out.linear_velocity, out.angular_velocity,
            out.linear_velocity_world,
        )  # fmt: skip
        bound = self._bound_calls
        if bound is not None and all(map(operator.is_, key, bound[0])):
            return bound[1]
        self._bound_calls = None
        arrays = [a for a in key if a is not None]
        if not all(isinstance(a, np.ndarray) and a.flags.c_contiguous for a in arrays):
            return None
        self._bound_calls = (key, self._calls(frame, q, dq, out, bound=True))
        return self._bound_calls[1]

    def _calls(self, frame: SensorFrame, q, dq, out: BaseState, bound: bool) -> tuple:
        """The two kernels' calls on these arrays: bound (``bound``: as one table of them,
        :data:`~sim2real.deploy.estimation.base_tick.TICK`, where each is of its dtype and
        dimensions), else through numba's dispatch."""
        values = dict(
            x=self._x, P=self.covariance, n=self._n, feet=self._feet, force=self._force,
            encoder=self._encoder, p=self._p, time=frame.time, imu_stamp=frame.imu_stamp,
            gyro=frame.imu_angular_velocity, acc=frame.imu_acceleration,
            onboard=frame.imu_orientation, foot_force=frame.foot_force,
            foot_contact=frame.foot_contact, contact_stamp=frame.contact_stamp,
            position=frame.position, position_stamp=frame.position_stamp,
            velocity=self._no_velocity if frame.velocity is None else frame.velocity, q=q, dq=dq,
            rate=self._rate, legs=self._legs, foot_motion=self._foot_motion,
            foot_position=self._foot_position, out_q=out.orientation, out_g=out.projected_gravity,
            out_v=out.linear_velocity, out_w=out.angular_velocity, out_vw=out.linear_velocity_world,
        )  # fmt: skip
        table = bt.TICK.pack_or_none(**values) if bound else None
        if table is not None:
            stage = bind(bt.tick_stage, table, rest=(0,))
            return functools.partial(stage, 0), functools.partial(stage, 1)
        return tuple(  # through numba's dispatch, each argument by its name
            functools.partial(k, **{a: values[a] for a in signature(k.py_func).parameters})
            for k in (bt.absorb_imu, bt.absorb_legs)
        )

    def _read_legs(self, e: int, q: np.ndarray, dead: int) -> None:
        """Env ``e``'s feet's velocities into ``_foot_motion[e]`` (n_feet, 6) (linear m/s, angular
        rad/s, base frame, the base at the origin turning at ``angular_velocity[e]``: Pinocchio,
        joint positions ``q`` (n_joints,) rad and the odometry's rates ``_rate[e]``); with a dead
        foot (``dead``) their placements into ``_foot_position[e]`` (the kinematic contact)."""
        model, data, config, vel = self.robot.pin_model, self._pin, self._q, self._v
        config[7:] = q
        vel[3:6] = self.angular_velocity[e]
        vel[6:] = self._rate[e]
        pin.forwardKinematics(model, data, config, vel)
        self._held = e
        motion, velocity, aligned = self._foot_motion[e], pin.getFrameVelocity, _ALIGNED
        for i, f in enumerate(self._foot_ids):
            motion[i] = velocity(model, data, f, aligned).vector
        if dead:
            position = self._foot_position[e]
            for i, f in enumerate(self._foot_ids):
                position[i] = pin.updateFramePlacement(model, data, f).translation

    def foot_position(self, e: int, out: np.ndarray) -> bool:
        """Env ``e``'s feet's positions in the base frame into ``out`` (n_feet, 3) m (the feet in
        ``robot.foot_frame_ids`` order; Pinocchio's placements, the base at the origin and
        upright, the joint estimate ``q`` of the last :meth:`update`) from the kinematics that
        update ran for the legs, where it holds env ``e``'s (the last env whose legs it read: a
        fresh IMU reading and a finite ``q``). Returns whether it did; ``out`` is untouched if
        not."""
        if e != self._held:
            return False
        model, data, place = self.robot.pin_model, self._pin, pin.updateFramePlacement
        for i, f in enumerate(self._foot_ids):
            out[i] = place(model, data, f).translation
        return True
