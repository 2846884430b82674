"""Base state estimation of a floating-base (legged) robot: attitude, angular and linear velocity.
One error-state extended Kalman filter per env, fed by a
:class:`~sim2real.deploy.core.backend.SensorFrame`'s IMU and foot-contact fields and by the joint
estimate ``q``, ``dq`` (rad, rad/s): the kinematic- inertial filter of legged robots with leg
odometry as a velocity measurement (M. Bloesch et al., "State estimation for legged robots", RSS
2012; M. Camurri et al., "Pronto", Frontiers in Robotics and AI 2020), reduced to the states a
velocity policy observes: the base-to-world rotation, the base velocity (world, at the base
origin) and the IMU's biases, the gyro's and the accelerometer's. The IMU predicts (the
accelerometer's lever arm and a turn's centripetal term taken off); the accelerometer is a weak
gravity measurement; each foot in contact measures the base velocity through the leg kinematics
(a rolling sphere's centre is not its contact point). A foot whose reading is more than
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

import numpy as np
import pinocchio as pin

from sim2real.deploy.core.attitude import (
    align_up,
    quat_multiply,
    quaternion_to_matrix,
    rotation_quaternions,
)
from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import BaseState
from sim2real.deploy.core.stateful import check, env_index, put, take
from sim2real.deploy.estimation.base_kernel import attitude_step, imu_step, leg_step
from sim2real.robots import Robot

#: Leg odometry noise, m/s per foot (our choice): foot roll and micro-slip, and the joint velocity
#: estimate's noise through the leg Jacobian (about 0.3 m/rad). Tried 0.05, 0.15 and 0.2 on the
#: go2, h1 and h1_2 walking (``python -m bench.estimation``).
LEG_VELOCITY_SIGMA = 0.1
#: Unmodelled acceleration, m/s^2, added to the accelerometer's white noise in the prediction
#: (our choice): the lever arm's angular-acceleration term and a reading sampled once a tick
#: (tried 1.5 and 3: the tilt follows the legs' errors).
UNMODELLED_ACCELERATION = 0.5
#: The accelerometer as a gravity measurement, m/s^2 (our choice): a walking base's own
#: acceleration, which averages out over a gait cycle (tried 0.5 and 1: 0.5 deg more tilt error).
ACCEL_MEASUREMENT_SIGMA = 2.0
#: Chi-square bound (3 dof, p about 0.03) past which a foot's velocity reading is a slip (tried
#: 6 and 16 on the go2, h1 and h1_2 over seeds 0-2: 16 let the Go2's sliding rear feet read it 5-7 %
#: slow).
SLIP_GATE = 9.0
#: Readings in a row without an absorbed foot after which the gate opens (our choice: 0.1 s at 50
#: Hz; a prediction that drifted must not lock every foot out).
MAX_REJECTED_READINGS = 5
#: The IMU's own attitude as a measurement: its ``orientation_sigma`` times this factor (our
#: choice: its error is correlated over ``orientation_tau``, so one reading a tick is not
#: independent of the last), at least ``MIN_ATTITUDE_SIGMA`` rad.
ATTITUDE_SIGMA_FACTOR = 3.0
MIN_ATTITUDE_SIGMA = 0.002
#: s a foot's force reading may stay the same before its sensor is taken for dead (our choice:
#: a live sensor's noise changes every reading; a Go2 with a dead foot sensor, and Unitree's
#: simulation bridge, report a constant, often 0). Latched until :meth:`reset`.
DEAD_FOOT_TIME = 1.0
#: m, a foot whose sensor is dead is in contact when it is this close to the lowest foot, by
#: the leg kinematics in the gravity frame (our choice: a trot lifts its swing feet 5-8 cm).
KINEMATIC_CONTACT_BAND = 0.02
#: Initial standard deviations (our choice: a robot reset at rest on level ground): roll and
#: pitch rad, yaw rad (unobserved, kept small), velocity m/s.
INITIAL_TILT_SIGMA = 0.02
INITIAL_YAW_SIGMA = 1e-3
INITIAL_VELOCITY_SIGMA = 0.1
#: An accelerometer reading within this fraction of gravity's magnitude is taken as the robot at
#: rest when the filter starts (our choice: 10 %, about 6 times the seed's largest accelerometer
#: noise, 0.1 m/s^2 x bias). Dropped onto its feet at the start of a soak session, a Go2 read
#: a specific force that put its initial tilt estimate at 0.29 rad (true 0.006): the policy
#: answered a tilt that was not there and fell within 0.5 s.
REST_ACCELERATION_TOLERANCE = 0.1
#: Floor of the gyro bias walk and bias sigma, rad/s (/sqrt(s)): a robot.toml with a perfect
#: gyro still lets the filter learn a bias (our choice).
MIN_GYRO_BIAS_WALK = 1e-5
MIN_GYRO_BIAS_SIGMA = 1e-3
#: The same floors for the accelerometer's bias, m/s^2 (/sqrt(s)) (our choice).
MIN_ACCEL_BIAS_WALK = 1e-4
MIN_ACCEL_BIAS_SIGMA = 0.01


def foot_radii(robot: Robot) -> np.ndarray:
    """(n_feet,) m: each foot's contact-sphere radius, the sphere geom centred on its foot site
    (the importer's and example-robot-data's point feet); 0 where the foot is not one sphere."""
    m = robot.mj_model
    out = np.zeros(len(robot.foot_site_ids))
    for i, s in enumerate(robot.foot_site_ids):
        body = m.site_bodyid[s]
        for g in range(m.ngeom):
            if (
                m.geom_bodyid[g] == body
                and m.geom_type[g] == 2  # mjGEOM_SPHERE
                and np.allclose(m.geom_pos[g], m.site_pos[s], atol=1e-6)
            ):
                out[i] = float(m.geom_size[g, 0])
    return out


def require_floating_base(robot: Robot, stage: str) -> None:
    """Refuse a fixed-base ``robot`` for a base stage (the runtime builds them for a legged robot
    kind only, :meth:`sim2real.deploy.robot_kind.RobotKind.base_stages`); ``stage`` names what the
    stage does, for the message.

    Raises:
        ValueError: ``robot`` has no floating base (``robot <name>: <stage> needs a floating
            base``).
    """
    if not robot.floating_base:
        raise ValueError(f"robot {robot.name}: {stage} needs a floating base")


class BaseStateEstimator:
    """The kinematic-inertial error-state filter of ``envs`` floating-base robots (module
    docstring).

    Args:
        robot: A floating-base robot (``robot.floating_base``).
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
        self.orientation = np.tile([1.0, 0.0, 0.0, 0.0], (envs, 1))
        self.angular_velocity = np.zeros((envs, 3))
        self.velocity = np.zeros((envs, 3))
        self.bias = np.zeros((envs, 6))
        self.gyro_bias = self.bias[:, :3]  # views: written in place, never rebound
        self.accel_bias = self.bias[:, 3:]
        self.covariance = np.tile(self._initial_covariance(), (envs, 1, 1))
        self.filter_time = np.full(envs, np.nan)
        self.time_since_fresh = np.full(envs, np.inf)
        self.missing_readings = np.zeros(envs, dtype=np.int64)
        self.stale_readings = np.zeros(envs, dtype=np.int64)
        self.velocity_updates = np.zeros(envs, dtype=np.int64)
        self.rejected_contacts = np.zeros(envs, dtype=np.int64)
        self._rejected_run = np.zeros(envs, dtype=np.int64)
        self._initialized = np.zeros(envs, dtype=bool)
        #: (envs, n_joints) rad, s: each encoder's last reading and its stamp
        #: (envs, n_feet) bool: the feet in contact at the last update: the sensor's, or (at a
        #: fresh IMU reading) the kinematics' for a foot in ``dead_feet``
        self.contact = np.zeros((envs, robot.n_feet), dtype=bool)
        #: (envs, n_feet) bool: feet whose force reading stayed the same for ``DEAD_FOOT_TIME``
        self.dead_feet = np.zeros((envs, robot.n_feet), dtype=bool)
        self._force_last = np.full((envs, robot.n_feet), np.nan)
        self._force_since = np.full((envs, robot.n_feet), np.nan)
        self._encoder_position = np.full((envs, robot.n_joints), np.nan)
        self._encoder_stamp = np.full((envs, robot.n_joints), np.nan)
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
        for counter in (
            self.missing_readings,
            self.stale_readings,
            self.velocity_updates,
            self.rejected_contacts,
            self._rejected_run,
        ):
            counter[sel] = 0
        self._initialized[sel] = True

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
        if not self._initialized.all():
            raise RuntimeError("BaseStateEstimator.update before reset(t) of every env")
        if frame.imu_stamp is None:
            raise ValueError("frame: no IMU fields (a floating-base robot's frame expected)")
        out = BaseState.zeros(self.envs) if out is None else out
        now, stamp = frame.time, frame.imu_stamp
        gyro, acc = frame.imu_angular_velocity, frame.imu_acceleration
        finite = np.isfinite(stamp) & np.isfinite(gyro).all(axis=1) & np.isfinite(acc).all(axis=1)
        with np.errstate(invalid="ignore"):  # NaN stamps are not fresh
            fresh = finite & (self.filter_time < stamp) & (stamp <= now)
        self.missing_readings += ~finite
        self.stale_readings += finite & ~fresh
        onboard = frame.imu_orientation
        rate = self._encoder_rate(frame, dq)
        self._watch_feet(frame)
        np.logical_and(frame.foot_contact, ~self.dead_feet, out=self.contact)  # the sensors'
        for e in np.flatnonzero(fresh):
            self._imu_step(e, float(stamp[e]), gyro[e], acc[e])
            if self.attitude_variance is not None and np.isfinite(onboard[e]).all():
                self._attitude_step(e, onboard[e])
            self._legs_step(e, frame, q[e], rate[e])
        # output: predicted from filter_time to now (orientation turned by omega; v held), every
        # env at once (an env not behind turns by a zero rotation: its quaternion unchanged)
        np.subtract(now, self.filter_time, out=self.time_since_fresh)
        age = np.maximum(self.time_since_fresh, 0.0)[:, None]
        quat = quat_multiply(self.orientation, rotation_quaternions(self.angular_velocity * age))
        rot = quaternion_to_matrix(quat)
        out.orientation[:] = quat
        out.projected_gravity[:] = -rot[:, 2]
        out.linear_velocity[:] = np.matmul(rot.transpose(0, 2, 1), self.velocity[:, :, None])[
            :, :, 0
        ]
        out.angular_velocity[:] = self.angular_velocity
        out.linear_velocity_world[:] = self.velocity
        return out

    def _imu_step(self, e: int, stamp: float, gyro: np.ndarray, acc: np.ndarray) -> None:
        """Env ``e``'s prediction to ``stamp`` and the accelerometer's gravity correction
        (:func:`sim2real.deploy.estimation.base_kernel.imu_step`)."""
        imu_step(
            self.orientation[e],
            self.velocity[e],
            self.bias[e],
            self.covariance[e],
            self._imu_to_base @ gyro,
            self._imu_to_base @ acc,
            stamp - self.filter_time[e],
            self.lever_arm,
            self.gravity,
            self.gyro_variance,
            self.accel_variance,
            self.bias_walk_variance,
            self.accel_bias_walk_variance,
            self.accel_meas_variance,
            3 * REST_ACCELERATION_TOLERANCE,
            self.angular_velocity[e],
        )
        self.filter_time[e] = stamp

    def _encoder_rate(self, frame: SensorFrame, dq: np.ndarray) -> np.ndarray:
        """(envs, n_joints) rad/s, the joint velocities the leg odometry uses: the velocity the
        drive reported (``frame.velocity``) where it did; else each encoder's reading differenced
        against its previous one over their stamps (half a reading's period behind; the joint
        filter's constant-velocity estimate lags a stepping leg by two to three control periods);
        else the joint estimate ``dq``."""
        pos, stamp = frame.position, frame.position_stamp
        with np.errstate(invalid="ignore", divide="ignore"):
            gap = stamp - self._encoder_stamp
            rate = (pos - self._encoder_position) / gap
            ok = np.isfinite(rate) & (gap > 0) & (gap <= 2.5 * self.robot.control_period)
        out = np.where(ok, rate, dq)
        if frame.velocity is not None:
            reported = np.isfinite(frame.velocity)
            out[reported] = frame.velocity[reported]
        fresh = np.isfinite(pos) & np.isfinite(stamp)
        self._encoder_position[fresh] = pos[fresh]
        self._encoder_stamp[fresh] = stamp[fresh]
        return out

    def _attitude_step(self, e: int, quaternion: np.ndarray) -> None:
        """Env ``e``'s correction by the IMU's own attitude (``quaternion``: the IMU site to
        the world; :func:`sim2real.deploy.estimation.base_kernel.attitude_step`)."""
        measured = quaternion_to_matrix(quaternion) @ self._imu_to_base.T  # base to world
        attitude_step(
            self.orientation[e],
            self.velocity[e],
            self.bias[e],
            self.covariance[e],
            measured,
            self.attitude_variance,
        )

    def _foot_velocities(self, e: int, q, dq):
        """Env ``e``'s feet's velocities, linear and angular, (n_feet, 3) each (m/s, rad/s, base
        frame, the base at the origin turning at ``angular_velocity[e]``: Pinocchio)."""
        model, data = self.robot.pin_model, self._pin
        self._q[7:] = q
        self._v[3:6] = self.angular_velocity[e]
        self._v[6:] = dq
        pin.forwardKinematics(model, data, self._q, self._v)
        for f in self.robot.foot_frame_ids:  # placements too: the kinematic contact
            pin.updateFramePlacement(model, data, f)
        frames = [
            pin.getFrameVelocity(model, data, f, pin.LOCAL_WORLD_ALIGNED)
            for f in self.robot.foot_frame_ids
        ]
        return [m.linear for m in frames], [m.angular for m in frames]

    def _gate(self, e: int) -> float:
        """Env ``e``'s slip gate for this reading: ``slip_gate``, or ``inf`` after
        ``MAX_REJECTED_READINGS`` readings without an absorbed foot. Opening it, the velocity
        restarts from the legs: its block of the covariance is widened (``INITIAL_VELOCITY_SIGMA``
        added) and its correlation with the attitude and bias dropped, so that a base whose
        velocity jumped (a push, a landing) is not read as a tilt."""
        if self._rejected_run[e] < MAX_REJECTED_READINGS:
            return self.slip_gate
        P = self.covariance[e]
        P[3:6, :3] = P[:3, 3:6] = P[3:6, 6:] = P[6:, 3:6] = 0.0
        P[3:6, 3:6] += np.eye(3) * INITIAL_VELOCITY_SIGMA**2
        return np.inf

    def _watch_feet(self, frame: SensorFrame) -> None:
        """Latch ``dead_feet``: a foot whose force reading (finite) has not changed for
        ``DEAD_FOOT_TIME`` s of the frame's time, and at once a foot with no force reading in a
        fresh contact frame (a robot without foot sensors: the G1 and H1-2's ``unitree_hg``
        LowState carries none)."""
        force = frame.foot_force
        with np.errstate(invalid="ignore"):
            self.dead_feet |= np.isnan(force) & np.isfinite(frame.contact_stamp)[:, None]
        with np.errstate(invalid="ignore"):
            changed = np.isfinite(force) & (force != self._force_last)
        now = np.broadcast_to(frame.time[:, None], force.shape)
        self._force_since[changed] = now[changed]
        self._force_last[changed] = force[changed]
        with np.errstate(invalid="ignore"):
            self.dead_feet |= (now - self._force_since) >= DEAD_FOOT_TIME

    def _contacts(self, e: int, frame: SensorFrame) -> np.ndarray | None:
        """Env ``e``'s feet in contact for the leg odometry, (n_feet,) bool, into
        ``contact[e]``: the sensor's where it is alive and fresh, the kinematics' (within
        ``KINEMATIC_CONTACT_BAND`` of the lowest foot, gravity frame; Pinocchio's placements of
        the last :meth:`_foot_velocities`) for a dead foot; None without either."""
        dead = self.dead_feet[e]
        fresh = np.isfinite(frame.contact_stamp[e])
        contact = self.contact[e] if fresh else np.zeros_like(dead)
        if dead.any():
            rot = quaternion_to_matrix(self.orientation[e])
            data = self._pin
            height = np.array(
                [(rot @ data.oMf[f].translation)[2] for f in self.robot.foot_frame_ids]
            )
            height -= self.radii
            contact = contact | (dead & (height - height.min() < KINEMATIC_CONTACT_BAND))
        elif not fresh:
            return None
        self.contact[e] = contact
        return contact

    def _legs_step(self, e: int, frame: SensorFrame, q, dq) -> None:
        """Env ``e``'s leg odometry: one gated velocity correction per foot in contact
        (:meth:`_contacts`; :func:`sim2real.deploy.estimation.base_kernel.leg_step`)."""
        if not (np.isfinite(q).all() and np.isfinite(dq).all()):
            return
        linear, angular = self._foot_velocities(e, q, dq)
        contact = self._contacts(e, frame)
        if contact is None or not contact.any():
            return
        self._absorb_feet(e, contact, linear, angular, self._gate(e))

    def _absorb_feet(self, e: int, contact, linear, angular, gate: float) -> None:
        """Env ``e``'s velocity corrections by its feet in ``contact`` ((n_feet,) bool; their
        velocities ``linear``, ``angular``), each gated at ``gate`` (chi-square)."""
        absorbed = False
        for i in np.flatnonzero(contact):
            ok = leg_step(
                self.orientation[e],
                self.velocity[e],
                self.bias[e],
                self.covariance[e],
                linear[i],
                angular[i],
                float(self.radii[i]),
                self.leg_variance,
                gate,
            )
            self.velocity_updates[e] += ok
            self.rejected_contacts[e] += not ok
            absorbed |= ok
        self._rejected_run[e] = 0 if absorbed else self._rejected_run[e] + 1
