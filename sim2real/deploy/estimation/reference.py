"""The references of the estimators, each a subclass with the same constructor:

- :class:`ReferenceJointStateEstimator`, of the joint estimator's kernel
  (:mod:`sim2real.deploy.estimation.kernel`): its tick runs in numpy around one
  ``filterpy.kalman.KalmanFilter(dim_x=2, dim_z=1)`` per (env, joint) (filterpy's predict and
  update for each fresh reading; ``tests/test_estimation.py``);
- :class:`ReferenceBaseStateEstimator`, of the base estimator's error-state algebra
  (:mod:`sim2real.deploy.estimation.base`): one ``filterpy.kalman.KalmanFilter(dim_x=12, dim_z=3)`` per env
  (``tests/test_legged.py``).

Each gives the same numbers as its estimator to rounding.
"""

from __future__ import annotations

import numpy as np
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from sim2real.deploy.core.attitude import quat_multiply, quaternion_to_matrix, rotation_quaternions
from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.estimation.base import (
    REST_ACCELERATION_TOLERANCE,
    BaseStateEstimator,
)
from sim2real.deploy.estimation.base_kernel import N_ERROR
from sim2real.deploy.estimation.joints import JointStateEstimator
from sim2real.robots import Robot


class ReferenceJointStateEstimator(JointStateEstimator):
    """A :class:`~sim2real.deploy.estimation.joints.JointStateEstimator` whose tick runs in numpy and
    filterpy (module docstring); the same arguments, attributes and errors. It compiles nothing."""

    def __init__(
        self,
        robot: Robot,
        envs: int,
        process_noise: float | np.ndarray | None = None,
        measurement_sigma: float | np.ndarray | None = None,
        input_extrapolates: bool = True,
    ):
        super().__init__(robot, envs, process_noise, measurement_sigma, input_extrapolates)
        n, shape = self.n_joints, (envs, self.n_joints)

        # constants and work arrays of the numpy tick, all (envs, n): it allocates nothing
        def full(value) -> np.ndarray:
            return np.broadcast_to(np.asarray(value, dtype=np.float64), shape).copy()

        self._var = full(self.process_noise)
        self._r = full(self.measurement_variance)
        self._bound0 = full(self.covariance_bound[:, 0])
        self._bound1 = full(self.covariance_bound[:, 1])
        self._zero, self._half, self._one = full(0.0), full(0.5), full(1.0)
        self._one_int = np.ones(shape, dtype=np.int64)
        self._now = np.zeros(shape)
        self._now_t = self._now.T  # (n, envs) view: broadcasts frame.time (envs,) into _now
        self._w = {k: np.empty(shape) for k in ("tmp", "det")}
        self._count = np.empty(shape, dtype=np.int64)
        # row views, made once (unpacking a (2, envs, n) array every tick would create them anew)
        self._pv = tuple(self._p)
        self._valid = np.empty(shape, dtype=bool)
        self._mask = np.empty(shape, dtype=bool)

        self._kfs: list[list[KalmanFilter]] = []
        for _ in range(envs):
            row = []
            for j in range(n):
                kf = KalmanFilter(dim_x=2, dim_z=1)
                kf.H = np.array([[1.0, 0.0]])
                kf.R = np.array([[self.measurement_variance[j]]])
                row.append(kf)
            self._kfs.append(row)

    def _warm_up(self) -> None:
        """Nothing to compile."""

    def update(
        self, frame: SensorFrame, state: RobotState, acceleration: np.ndarray | None = None
    ) -> RobotState:
        """:meth:`JointStateEstimator.update <sim2real.deploy.estimation.joints.
        JointStateEstimator.update>` (the same arguments, outputs and errors), in numpy and
        filterpy."""
        if not self._all_initialized:
            raise RuntimeError("JointStateEstimator.update before reset(q, t) of every env")
        self._check_frame(frame)
        if acceleration is None:
            self._u.fill(0.0)
        else:
            np.copyto(self._u, acceleration)
        return self._tick(frame, state)

    def _tick(self, frame: SensorFrame, state: RobotState) -> RobotState:
        """:meth:`update` after its checks, with ``_u`` set, in numpy and filterpy."""
        z, ts = frame.position, frame.position_stamp
        x0, x1 = self._xv
        valid, fresh, mask, tf = self._valid, self._fresh, self._mask, self.filter_time
        np.copyto(self._now_t, frame.time)
        # missing: no finite value or stamp; fresh: stamped after filter_time, not in the future
        np.isfinite(z, out=valid)
        np.isfinite(ts, out=mask)
        np.logical_and(valid, mask, out=valid)
        np.logical_not(valid, out=mask)
        self._increment(self.missing_per_joint, mask)
        np.greater(ts, tf, out=fresh)
        np.logical_and(fresh, valid, out=fresh)
        np.less_equal(ts, self._now, out=mask)
        np.logical_and(fresh, mask, out=fresh)
        np.logical_xor(valid, fresh, out=mask)
        self._increment(self.stale_per_joint, mask)

        # a state written from outside may hold inf: its arithmetic must not warn; the check
        # below re-initializes whatever came out of it
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            # checked before (a state written from outside) and after the step (numerics)
            if not self._check():
                self._reinitialize(z, ts)
            if np.count_nonzero(fresh):
                self._absorb_filterpy(z, ts)
                np.copyto(tf, ts, where=fresh)
                if not self._check():
                    self._reinitialize(z, ts)
            self._output(state)
            if self.velocity_variance is not None and frame.velocity is not None:
                self._absorb_velocity_filterpy(frame.velocity)
                self._output(state)
        np.isfinite(frame.winding_temperature, out=mask)
        np.copyto(state.winding_temperature, frame.winding_temperature, where=mask)
        return state

    def _absorb_velocity_filterpy(self, velocity: np.ndarray) -> None:
        """The drives' reported velocity (envs, n) rad/s of each fresh reading: filterpy's
        ``update`` with ``H = [[0, 1]]`` and ``R = velocity_variance``."""
        cov = self.covariance
        for e, j in zip(*np.nonzero(self._fresh & np.isfinite(velocity)), strict=True):
            kf = self._kfs[e][j]
            kf.x = np.array([[self._x[0, e, j]], [self._x[1, e, j]]])
            kf.P = cov[e, j].copy()
            kf.update(
                float(velocity[e, j]),
                R=np.array([[self.velocity_variance[j]]]),
                H=np.array([[0.0, 1.0]]),
            )
            self._x[:, e, j] = kf.x[:, 0]
            cov[e, j] = kf.P

    def _output(self, state: RobotState) -> None:
        """``state.q``, ``state.dq``: the prediction from ``filter_time`` to the frame's time
        (not stored), and ``time_since_fresh``."""
        x0, x1 = self._xv
        mask, tf = self._mask, self.filter_time
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            age, tmp = self.time_since_fresh, self._w["tmp"]
            np.subtract(self._now, tf, out=age)
            np.multiply(age, x1, out=state.q)
            np.add(state.q, x0, out=state.q)
            np.multiply(age, self._u, out=state.dq)  # + B(age) u; 0 for a lost joint (age inf)
            if not self.input_extrapolates:
                state.dq.fill(0.0)
            np.isfinite(state.dq, out=mask)
            np.copyto(state.dq, 0.0, where=~mask)
            np.multiply(state.dq, age, out=tmp)
            np.multiply(tmp, 0.5, out=tmp)
            np.add(state.q, tmp, out=state.q)
            np.add(state.dq, x1, out=state.dq)

    def _increment(self, counter: np.ndarray, mask: np.ndarray) -> None:
        np.add(counter, self._one_int, out=self._count)
        np.copyto(counter, self._count, where=mask)

    def _absorb_filterpy(self, z: np.ndarray, ts: np.ndarray) -> None:
        """The reference: filterpy's predict + update, one filter per fresh (env, joint)."""
        cov = self.covariance
        for e, j in zip(*np.nonzero(self._fresh), strict=True):
            kf = self._kfs[e][j]
            kf.x = np.array([[self._x[0, e, j]], [self._x[1, e, j]]])
            kf.P = cov[e, j].copy()
            dt = float(ts[e, j] - self.filter_time[e, j])
            kf.F = np.array([[1.0, dt], [0.0, 1.0]])
            kf.Q = Q_discrete_white_noise(2, dt=dt, var=float(self.process_noise[j]))
            kf.B = np.array([[0.5 * dt * dt], [dt]])
            kf.predict(u=np.array([[self._u[e, j]]]))
            kf.update(float(z[e, j]))
            rx = self.angle_rest_variance[j]
            if np.isfinite(rx):  # the angle's held-back share: K = [k0, 0], P by Joseph's form
                k = np.array([[kf.P[0, 0] / (kf.P[0, 0] + rx)], [0.0]])
                a = np.eye(2) - k @ kf.H
                kf.x = kf.x + k * (float(z[e, j]) - kf.x[0, 0])
                kf.P = a @ kf.P @ a.T + rx * (k @ k.T)
            self._x[:, e, j] = kf.x[:, 0]
            cov[e, j] = kf.P

    def _check(self) -> bool:
        """Symmetrize P; ``_good`` = finite state, P positive definite and within the bound.

        Returns whether every joint is good.
        """
        p00, p01, p10, p11 = self._pv
        good, mask, det, tmp = self._good, self._mask, self._w["det"], self._w["tmp"]
        np.add(p01, p10, out=tmp)
        np.multiply(tmp, self._half, out=p01)
        np.copyto(p10, p01)
        # comparisons are False for NaN; inf fails the bounds
        np.greater(p00, self._zero, out=good)
        np.less_equal(p00, self._bound0, out=mask)
        np.logical_and(good, mask, out=good)
        np.less_equal(p11, self._bound1, out=mask)
        np.logical_and(good, mask, out=good)
        np.multiply(p00, p11, out=det)
        np.multiply(p01, p01, out=tmp)
        np.subtract(det, tmp, out=det)
        np.greater(det, self._zero, out=mask)  # with p00 > 0: positive definite
        np.logical_and(good, mask, out=good)
        np.add(*self._xv, out=tmp)
        np.isfinite(tmp, out=mask)
        np.logical_and(good, mask, out=good)
        return np.count_nonzero(good) == good.size


class ReferenceBaseStateEstimator(BaseStateEstimator):
    """A :class:`~sim2real.deploy.estimation.base.BaseStateEstimator` whose error-state algebra runs in one
    ``filterpy.kalman.KalmanFilter(dim_x=12, dim_z=3)`` per env (filterpy's ``predict`` with the
    error-state transition and ``update`` with each measurement's ``H`` and ``R``; the error
    state is folded into the nominal state and zeroed after each update); the same arguments,
    attributes, state and errors."""

    def __init__(self, robot: Robot, envs: int, *args, **kwargs):
        self._kfs: list[KalmanFilter] = [KalmanFilter(dim_x=N_ERROR, dim_z=3) for _ in range(envs)]
        super().__init__(robot, envs, *args, **kwargs)
        for e in range(envs):
            self._restart_filter(e)

    def _restart_filter(self, e: int) -> None:
        if not hasattr(self, "_kfs"):
            return
        kf = self._kfs[e]
        kf.x = np.zeros((N_ERROR, 1))
        kf.P = self.covariance[e].copy()

    def _predict(self, e: int, F: np.ndarray, Q: np.ndarray) -> None:
        kf = self._kfs[e]
        kf.F, kf.Q = F, Q
        kf.predict()
        kf.P[2, :] = 0.0  # the heading has no uncertainty (base_kernel.lock_heading)
        kf.P[:, 2] = 0.0
        self.covariance[e] = kf.P

    def _correct(self, e: int, y: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
        kf = self._kfs[e]
        kf.x = np.zeros((N_ERROR, 1))
        prior = kf.P.copy()
        # filterpy's residual is z - H x: with x = 0 the innovation is z itself
        kf.update(y.reshape(3, 1), R=R, H=H)
        # its gain locked in heading (base_kernel's module docstring): the Joseph form again
        K = kf.K.copy()
        rot = quaternion_to_matrix(self.orientation[e])
        up = rot[2]  # the world's up in the base frame
        K[2] = 0.0
        K[6:9] -= np.outer(up, up @ K[6:9])
        ikh = np.eye(N_ERROR) - K @ H
        kf.P = ikh @ prior @ ikh.T + K @ R @ K.T
        kf.x = K @ y.reshape(3, 1)
        kf.P = 0.5 * (kf.P + kf.P.T)
        self.covariance[e] = kf.P
        dx = kf.x[:, 0].copy()
        kf.x = np.zeros((N_ERROR, 1))
        return dx

    def _inject(self, e: int, dx: np.ndarray) -> None:
        """Fold the error ``dx`` (12,) into env ``e``'s nominal state."""
        turn = rotation_quaternions(dx[None, 0:3])[0]
        q = quat_multiply(turn, self.orientation[e])  # R = Exp(dtheta) R: world-frame error
        self.orientation[e] = q / np.linalg.norm(q)
        self.velocity[e] += dx[3:6]
        self.bias[e] += dx[6:12]

    def _imu_step(self, e: int, stamp: float, gyro: np.ndarray, acc: np.ndarray) -> None:
        dt = stamp - self.filter_time[e]
        omega = self._imu_to_base @ gyro - self.gyro_bias[e]
        f = self._imu_to_base @ acc - self.accel_bias[e]
        f -= np.cross(omega, np.cross(omega, self.lever_arm))
        f -= np.cross((omega - self.angular_velocity[e]) / dt, self.lever_arm)
        rot = quaternion_to_matrix(self.orientation[e])
        rf = rot @ f
        F = np.eye(N_ERROR)
        F[0:3, 6:9] = -rot * dt
        F[3:6, 0:3] = -dt * skew(rf)
        F[3:6, 9:12] = -rot * dt
        Q = np.diag(
            np.concatenate(
                [
                    np.full(3, self.gyro_variance * dt * dt),
                    np.full(3, self.accel_variance * dt * dt),
                    np.full(3, self.bias_walk_variance * dt),
                    np.full(3, self.accel_bias_walk_variance * dt),
                ]
            )
        )
        self.velocity[e] += dt * (rf + self.gravity)
        turn = rotation_quaternions((omega * dt)[None])[0]
        quat = quat_multiply(self.orientation[e], turn)
        self.orientation[e] = quat / np.linalg.norm(quat)
        self._predict(e, F, Q)
        self.filter_time[e] = stamp
        g = np.linalg.norm(self.gravity)
        if abs(np.linalg.norm(f) - g) < 3 * REST_ACCELERATION_TOLERANCE * g:
            up, v = -self.gravity, self.velocity[e]
            rot = quaternion_to_matrix(self.orientation[e])
            turn = skew(omega) @ rot.T
            H = np.zeros((3, N_ERROR))
            H[:, 0:3] = rot.T @ skew(up) + turn @ skew(v)
            H[:, 3:6] = turn
            H[:, 9:12] = np.eye(3)
            y = f - (rot.T @ up + turn @ v)
            self._inject(e, self._correct(e, y, H, np.eye(3) * self.accel_meas_variance))
        self.angular_velocity[e] = self._imu_to_base @ gyro - self.gyro_bias[e]

    def _attitude_step(self, e: int, quaternion: np.ndarray) -> None:
        measured = quaternion_to_matrix(quaternion) @ self._imu_to_base.T
        rot = quaternion_to_matrix(self.orientation[e])
        H = np.zeros((3, N_ERROR))
        H[:, 0:3] = rot.T @ skew(np.array([0.0, 0.0, -1.0]))
        y = -measured[2] + rot[2]
        self._inject(e, self._correct(e, y, H, np.eye(3) * self.attitude_variance))

    def _absorb_feet(self, e: int, contact, linear, angular, gate: float) -> None:
        if gate == np.inf:
            self._kfs[e].P = self.covariance[e].copy()
        absorbed = False
        for i in np.flatnonzero(contact):
            rot = quaternion_to_matrix(self.orientation[e])
            z = -(linear[i] + np.cross(angular[i], self.radii[i] * -rot[2]))
            v = self.velocity[e]
            H = np.zeros((3, N_ERROR))
            H[:, 0:3] = rot.T @ skew(v)
            H[:, 3:6] = rot.T
            R = np.eye(3) * self.leg_variance
            y = z - rot.T @ v
            S = H @ self.covariance[e] @ H.T + R
            if y @ np.linalg.solve(S, y) > gate:
                self.rejected_contacts[e] += 1
                continue
            self._inject(e, self._correct(e, y, H, R))
            self.velocity_updates[e] += 1
            absorbed = True
        self._rejected_run[e] = 0 if absorbed else self._rejected_run[e] + 1


def skew(a: np.ndarray) -> np.ndarray:
    """(3, 3) cross-product matrix ``[a]x`` of a (3,) vector: ``[a]x b = a x b``."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
