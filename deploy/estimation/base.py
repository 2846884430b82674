"""Base state estimation of a floating-base (legged) robot: attitude, angular and linear velocity.

Two filters per env, fed by a :class:`~deploy.backends.base.SensorFrame`'s IMU and foot-contact
fields and by the joint estimate ``q``, ``dq`` (rad, rad/s):

- attitude: Mahony's complementary filter with gyro bias (:mod:`deploy.estimation.attitude`; gains
  ``MAHONY_K_P = 0.3``, ``MAHONY_K_I = 0.03``), on the IMU readings turned into the base frame
  (accelerometer lever arm neglected): orientation (yaw unobserved), projected gravity, angular
  velocity (rad/s, base frame). Its accelerometer reading has the base's own acceleration taken
  off, ``dv/dt + omega x v`` (base frame; ``dv/dt`` the leg odometry's difference between
  readings, bounded and low-passed, needing no attitude; ``omega x v`` from the gyro and the
  velocity filter): a walking humanoid's acceleration and turn, taken for tilt, threw its policy;
- linear velocity: the kinematic-inertial Kalman filter of legged robots (M. Bloesch et al., RSS
  2012; the linear form of G. Bledt et al., "MIT Cheetah 3", IROS 2018), state ``v`` (m/s, world)::

    predict:  v' = v + dt (R a + g)               Q = dt^2 (accel_sigma^2 + accel_bias_sigma^2) I
    update:   z = R mean_i(-(omega x p_i + J_i(q) dq))   R_z = leg_sigma^2 / n_contact I

  with ``p_i``, ``J_i`` a foot's position and Jacobian in the base frame (Pinocchio).

Both run over every env at once; their reference
(:class:`~deploy.estimation.reference.ReferenceBaseStateEstimator`) runs one ``ahrs`` filter and
one ``filterpy`` KalmanFilter per env. An IMU
reading that is NaN, not newer than the last one absorbed or stamped after ``frame.time`` is not
fed (``missing_readings`` / ``stale_readings``): the output is predicted to ``frame.time`` and
``time_since_fresh`` grows. Contacts without a fresh stamp give no velocity update.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from deploy.backends.base import SensorFrame
from deploy.estimation.attitude import align_up, quaternion_to_matrix, tilt_of
from deploy.estimation.attitude_kernel import imu_rows, predict_rows
from deploy.stateful import check, env_index, put, take
from robots import Robot

#: Mahony's proportional and integral gains, rad/s per unit error (our choice; ``ahrs``'s
#: defaults are 1 and 0.3). Under legged_gym's pushes (``python -m bench.push_reference``, 50
#: sequences of 60 s) the accelerometer's reading of a recovering base's own acceleration pulled
#: the attitude with the defaults: the H1, H1-2 and a G1 survived 107, 45 and 176 pushes, against
#: 126, 54 and 281 in unitree_rl_gym's own loop on the true state; with 0.3 and 0.03, 139, 50 and
#: 278. The turn-on gyro bias (0.01 rad/s on the shipped humanoids) then tilts the estimate by
#: ``bias / k_p`` until the integral term has learned it (time constant about ``k_p / k_i`` s).
MAHONY_K_P = 0.3
MAHONY_K_I = 0.03
#: Leg odometry noise, m/s (our choice): foot roll and micro-slip of a point foot, and the joint
#: velocity estimate's noise through the leg Jacobian (about 0.3 m/rad).
LEG_VELOCITY_SIGMA = 0.1
#: Initial velocity standard deviation, m/s (our choice: a robot reset at rest).
INITIAL_VELOCITY_SIGMA = 0.1
#: An accelerometer reading within this fraction of gravity's magnitude is taken as the robot at
#: rest when the filter starts (our choice: 10 %, about 6 times the seed's largest accelerometer
#: noise, 0.1 m/s^2 x bias). Dropped onto its feet at the start of a soak session, a Go2 read
#: a specific force that put its initial tilt estimate at 0.29 rad (true 0.006): the policy
#: answered a tilt that was not there and fell within 0.5 s.
REST_ACCELERATION_TOLERANCE = 0.1
#: Time constant, s, of the first-order low-pass on the leg odometry's difference (our choice,
#: tried against 0.03 and 0.2 s and none on a turning G1): differenced at 50 Hz, joint-velocity
#: noise makes metres per second squared per reading, which the attitude took for tilt.
MOTION_ACCELERATION_TAU = 0.1
#: Bound, m/s^2, on one reading's leg-odometry difference (our choice: 0.3 g, above a walking
#: base's own acceleration; tried against 10 m/s^2 and none on the H1 and G1): a robot dropped
#: onto its feet, or a slipping foot, makes tens of m/s^2 that are not the base's.
MAX_MOTION_ACCELERATION = 3.0


@dataclass
class BaseState:
    """The base estimate of ``envs`` robots at ``frame.time``.

    Attributes:
        orientation: (envs, 4) base-to-world unit quaternion ``[w, x, y, z]`` (yaw unobserved).
        projected_gravity: (envs, 3) unit vector, gravity's direction in the base frame.
        angular_velocity: (envs, 3) rad/s, base frame, gyroscope bias removed.
        linear_velocity: (envs, 3) m/s, base frame.
        linear_velocity_world: (envs, 3) m/s, in the (yaw-drifting) world frame of the filter.
    """

    orientation: np.ndarray
    projected_gravity: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    linear_velocity_world: np.ndarray

    @classmethod
    def zeros(cls, envs: int) -> BaseState:
        q = np.zeros((envs, 4))
        q[:, 0] = 1.0
        g = np.zeros((envs, 3))
        g[:, 2] = -1.0
        return cls(q, g, np.zeros((envs, 3)), np.zeros((envs, 3)), np.zeros((envs, 3)))

    def set_truth(self, truth: np.ndarray) -> BaseState:
        """Fill every field from a simulated base's true state (evaluation, parity replays and
        training rewards): ``truth`` (envs, 13) as :meth:`deploy.backends.sim.plant.SimBackend.
        true_base_state` gives it (position m, quaternion ``[w, x, y, z]``, linear velocity m/s
        world, angular velocity rad/s base frame). Returns self."""
        rot = quaternion_to_matrix(truth[:, 3:7])
        velocity = truth[:, 7:10]
        self.orientation[:] = truth[:, 3:7]
        self.projected_gravity[:] = -rot[:, 2]
        self.angular_velocity[:] = truth[:, 10:13]
        self.linear_velocity_world[:] = velocity
        self.linear_velocity[:] = np.matmul(rot.transpose(0, 2, 1), velocity[:, :, None])[:, :, 0]
        return self

    @property
    def tilt(self) -> np.ndarray:
        """(envs,) rad, angle between the base's z axis and the world's up (:func:`tilt_of`)."""
        return tilt_of(self.projected_gravity)


class BaseStateEstimator:
    """Attitude and base velocity filters of ``envs`` floating-base robots (module docstring).

    Args:
        robot: A floating-base robot (``robot.floating_base``).
        envs: Batch size.
        k_p, k_i: Mahony's proportional and integral (gyro bias) gains, rad/s per unit error
            (``MAHONY_K_P``, ``MAHONY_K_I``).
        leg_sigma: Leg odometry noise, m/s (``LEG_VELOCITY_SIGMA``).

    Attributes:
        velocity_variance: (envs,) m^2/s^2, the velocity filter's covariance ``p`` (``P = p I``).
        filter_time: (envs,) s, stamp of the last absorbed IMU reading.
        time_since_fresh: (envs,) s, ``frame.time - filter_time`` at the last update.
        missing_readings, stale_readings: (envs,) int IMU readings not absorbed.
        velocity_updates: (envs,) int leg-odometry updates absorbed.

    Raises:
        ValueError: a fixed-base robot or ``envs < 1``.
    """

    def __init__(
        self,
        robot: Robot,
        envs: int,
        k_p: float = MAHONY_K_P,
        k_i: float = MAHONY_K_I,
        leg_sigma: float = LEG_VELOCITY_SIGMA,
    ):
        if not robot.floating_base:
            raise ValueError(f"robot {robot.name}: base estimation needs a floating base")
        if envs < 1:
            raise ValueError(f"envs must be >= 1, got {envs}")
        self.robot, self.envs = robot, envs
        imu = robot.config.sensors.imu
        self.accel_variance = imu.accel_noise_sigma**2 + imu.accel_bias_sigma**2
        self.leg_variance = float(leg_sigma) ** 2
        self.gravity = np.array(robot.mj_model.opt.gravity, dtype=np.float64)
        # the IMU site's orientation on the base (the site sits on the base body: checked)
        m = robot.mj_model
        if m.body(m.site_bodyid[robot.imu_site_id]).name != robot.base_body:
            raise ValueError(f"robot {robot.name}: the IMU site is not on the base body")
        self._imu_to_base = quaternion_to_matrix(m.site_quat[robot.imu_site_id])
        self.k_p, self.k_i = float(k_p), float(k_i)
        #: (envs, 3) rad/s, Mahony's gyro bias (the reference keeps it in its ``ahrs`` objects)
        self._bias = np.zeros((envs, 3))
        self._pin = robot.pin_model.createData()
        self._q = robot.pin_configuration(robot.home)
        self._v = np.zeros(robot.pin_model.nv)
        self.orientation = np.tile([1.0, 0.0, 0.0, 0.0], (envs, 1))
        self._rot = np.zeros((envs, 3, 3))  # the IMU step's rotation matrices
        self.angular_velocity = np.zeros((envs, 3))
        self.velocity = np.zeros((envs, 3))
        self.velocity_variance = np.full(envs, INITIAL_VELOCITY_SIGMA**2)
        self.filter_time = np.full(envs, np.nan)
        self.time_since_fresh = np.full(envs, np.inf)
        self.missing_readings = np.zeros(envs, dtype=np.int64)
        self.stale_readings = np.zeros(envs, dtype=np.int64)
        self.velocity_updates = np.zeros(envs, dtype=np.int64)
        #: (envs, 3) m/s, base frame: the last leg odometry (attitude-free), at ``leg_time``
        self.leg_velocity = np.zeros((envs, 3))
        self.leg_time = np.full(envs, np.nan)
        #: (envs, 3) m/s^2, base frame: the base's acceleration, the leg odometry's difference
        self.motion_acceleration = np.zeros((envs, 3))
        self._initialized = np.zeros(envs, dtype=bool)
        self._warm_kernels()

    def _warm_kernels(self) -> None:
        """Compile (or load from numba's cache) the attitude kernels before the first tick, on
        scratch copies of the state (nothing of the estimator changes)."""
        n = self.envs
        fields = [a.copy() for a in (self.filter_time, self.orientation, self._bias)]
        imu_rows(
            np.zeros(0, dtype=np.int64),
            np.zeros(n),
            np.zeros((n, 3)),
            np.zeros((n, 3)),
            self._imu_to_base,
            *fields,
            np.zeros((n, 3)),
            np.zeros((n, 3)),
            np.zeros(n),
            np.zeros((n, 3)),
            self.gravity,
            self.accel_variance,
            self.k_p,
            self.k_i,
            self._rot.copy(),
        )
        out = BaseState.zeros(n)
        predict_rows(
            np.zeros(n),
            np.zeros(n),
            np.zeros((n, 3)),
            np.tile([1.0, 0, 0, 0], (n, 1)),
            np.zeros((n, 3)),
            np.zeros(n),
            out.orientation,
            out.projected_gravity,
            out.linear_velocity,
        )
        quaternion_to_matrix(out.orientation)  # the leg update's and the fall check's

    # ------------------------------------------------------------------ lifecycle
    def reset(self, t, acceleration: np.ndarray | None = None, envs=None) -> None:
        """Start the filters at rest at time ``t`` (s; float or (envs,)).

        ``acceleration``: (envs, 3) accelerometer readings (m/s^2, IMU frame) of the robot at
        rest: the initial roll and pitch put them along the world's up (yaw 0); default upright.
        A reading whose magnitude is more than ``REST_ACCELERATION_TOLERANCE`` from gravity's is
        not the robot at rest (dropped on its feet, landing) and is ignored: upright.
        Gyro bias estimates restart at 0, velocity at 0 with ``INITIAL_VELOCITY_SIGMA``.
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
            if acceleration is not None:
                a = self._imu_to_base @ np.asarray(acceleration[e], dtype=np.float64)
                if not (np.isfinite(a).all() and np.linalg.norm(a) > 0):
                    raise ValueError(f"reset: env {e}: acceleration {a} is not a finite reading")
                g = np.linalg.norm(self.gravity)
                if abs(np.linalg.norm(a) - g) <= REST_ACCELERATION_TOLERANCE * g:
                    q = align_up(a / np.linalg.norm(a))
            self.orientation[e] = q
            self._bias[e] = 0.0
        self.angular_velocity[sel] = 0.0
        self.velocity[sel] = 0.0
        self.leg_velocity[sel] = 0.0
        self.leg_time[sel] = np.nan
        self.motion_acceleration[sel] = 0.0
        self.velocity_variance[sel] = INITIAL_VELOCITY_SIGMA**2
        self.filter_time[sel] = t[sel]
        self.time_since_fresh[sel] = 0.0
        for counter in (self.missing_readings, self.stale_readings, self.velocity_updates):
            counter[sel] = 0
        self._initialized[sel] = True

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        return {
            "orientation": self.orientation,
            "angular_velocity": self.angular_velocity,
            "velocity": self.velocity,
            "velocity_variance": self.velocity_variance,
            "filter_time": self.filter_time,
            "time_since_fresh": self.time_since_fresh,
            "missing_readings": self.missing_readings,
            "stale_readings": self.stale_readings,
            "velocity_updates": self.velocity_updates,
            "leg_velocity": self.leg_velocity,
            "leg_time": self.leg_time,
            "motion_acceleration": self.motion_acceleration,
            "initialized": self._initialized,
        }

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The filters' state (copies; conventions of :mod:`deploy.stateful`): the attributes
        of the class docstring, ``orientation`` (envs, 4), ``angular_velocity`` (envs, 3) rad/s,
        ``velocity`` (envs, 3) m/s (world), ``gyro_bias`` (envs, 3) rad/s (Mahony's integral
        term) and ``initialized`` (envs,) bool; the env axis has length 1 for one env ``env``.
        The filterpy reference's ``x`` and ``P`` are ``velocity`` and ``velocity_variance I``."""
        out = take(self._state_fields(), env)
        out["gyro_bias"] = self._gyro_bias()[env_index(env)].copy()
        return out

    def _gyro_bias(self) -> np.ndarray:
        """(envs, 3) rad/s, Mahony's integral term of every env."""
        return self._bias

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        bias = np.zeros((self.envs, 3))
        check({"gyro_bias": bias}, state, env)
        put(self._state_fields(), state, env)
        sel = np.arange(self.envs)[env_index(env)]
        for k, e in enumerate(sel):
            self._bias[e] = state["gyro_bias"][k]

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
        if fresh.any():
            e = np.flatnonzero(fresh)
            rot = self._rot[: len(e)]
            legs = [self._leg_odometry(env, frame, q[env], dq[env]) for env in e]
            imu_rows(
                e,
                np.ascontiguousarray(stamp),
                np.ascontiguousarray(gyro),
                np.ascontiguousarray(acc),
                self._imu_to_base,
                self.filter_time,
                self.orientation,
                self._bias,
                self.angular_velocity,
                self.velocity,
                self.velocity_variance,
                self.motion_acceleration,
                self.gravity,
                self.accel_variance,
                self.k_p,
                self.k_i,
                rot,
            )
            for k, env in enumerate(e):
                if legs[k] is not None:
                    self._absorb_leg_velocity(env, rot[k] @ legs[k][0], legs[k][1])
        # output: predicted from filter_time to now (orientation turned by omega; v held)
        predict_rows(
            np.ascontiguousarray(now),
            self.filter_time,
            self.angular_velocity,
            self.orientation,
            self.velocity,
            self.time_since_fresh,
            out.orientation,
            out.projected_gravity,
            out.linear_velocity,
        )
        out.angular_velocity[:] = self.angular_velocity
        out.linear_velocity_world[:] = self.velocity
        return out

    def _leg_odometry(self, e: int, frame: SensorFrame, q, dq) -> tuple[np.ndarray, float] | None:
        """Env ``e``'s leg odometry at its fresh IMU stamp: the base velocity (3,) m/s in the
        base frame, ``-mean_i(omega x p_i + J_i dq)`` over the feet in contact (``omega`` the
        gyro less the bias), and its variance (m^2/s^2, per axis); None without a fresh contact
        reading or a finite joint estimate. It sets ``motion_acceleration[e]`` (m/s^2, base
        frame), the odometry's difference since the last (0 after a gap), which the IMU step
        takes off the accelerometer's reading with the centripetal term."""
        contact = frame.foot_contact[e]
        fresh = np.isfinite(frame.contact_stamp[e]) and contact.any()
        if not (fresh and np.isfinite(q).all() and np.isfinite(dq).all()):
            self.leg_time[e] = np.nan
            self.motion_acceleration[e] = 0.0
            return None
        model, data = self.robot.pin_model, self._pin
        self._q[7:] = q
        gyro = self._imu_to_base @ frame.imu_angular_velocity[e]
        self._v[3:6] = gyro - self._gyro_bias()[e]
        self._v[6:] = dq
        pin.forwardKinematics(model, data, self._q, self._v)
        feet = [f for f, c in zip(self.robot.foot_frame_ids, contact, strict=True) if c]
        foot_velocity = np.mean(
            [pin.getFrameVelocity(model, data, f, pin.LOCAL_WORLD_ALIGNED).linear for f in feet],
            axis=0,
        )
        v, t = -foot_velocity, float(frame.imu_stamp[e])
        gap = t - self.leg_time[e]
        if gap > 0:
            alpha = gap / (MOTION_ACCELERATION_TAU + gap)
            raw = (v - self.leg_velocity[e]) / gap
            size = np.linalg.norm(raw)
            if size > MAX_MOTION_ACCELERATION:
                raw *= MAX_MOTION_ACCELERATION / size
            self.motion_acceleration[e] += alpha * (raw - self.motion_acceleration[e])
        else:
            self.motion_acceleration[e] = 0.0
        self.leg_velocity[e], self.leg_time[e] = v, t
        self.velocity_updates[e] += 1
        return v, self.leg_variance / len(feet)

    def _absorb_leg_velocity(self, e: int, z: np.ndarray, r_var: float) -> None:
        """The velocity filter's update of env ``e`` with the leg odometry ``z`` (3,) m/s (world)
        of variance ``r_var`` (m^2/s^2, per axis)."""
        p = self.velocity_variance[e]
        gain = p / (p + r_var)
        self.velocity[e] += gain * (z - self.velocity[e])
        # Joseph form (filterpy's): (1 - k)^2 p + k^2 r = (1 - k) p for the optimal gain
        self.velocity_variance[e] = (1 - gain) ** 2 * p + gain**2 * r_var
