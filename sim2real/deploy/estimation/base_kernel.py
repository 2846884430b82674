"""Compiled steps of the base estimator's error-state filter (:mod:`sim2real.deploy.estimation.base`) of
one env; the numpy reference of the same algebra (filterpy's predict and update) is
:class:`sim2real.deploy.estimation.reference.ReferenceBaseStateEstimator`.

Nominal state: rotation ``R`` (base to world), velocity ``v`` (m/s, world), the biases ``b``
(6,): the gyro's ``b_g`` (rad/s) and the accelerometer's ``b_a`` (m/s^2), base frame. Error state
(12,): ``dtheta`` (rad, world frame, ``R_true = Exp(dtheta) R``), ``dv``, ``db_g``, ``db_a``. With
the gyro ``omega = w - b_g`` and the specific force at the base origin
``f = a - b_a - omega x (omega x r)`` (``r`` the IMU's lever arm)::

    predict:  v' = v + dt (R f + g)     R' = R Exp(omega dt)     b' = b
              F = [[I, 0, -R dt, 0], [-dt [R f]x, I, 0, -R dt], [0, 0, I, 0], [0, 0, 0, I]]
              Q = diag(sigma_g^2 dt^2 I, sigma_a^2 dt^2 I, walk_g^2 dt I, walk_a^2 dt I)
    gravity:  z = f,  h = R^T (-g) + omega x R^T v,
              H = [R^T [-g]x + [omega]x R^T [v]x, [omega]x R^T, 0, I]
              (only while |f| is within ``rest_band`` of |g|)
    a foot:   z = -(v_foot + omega_foot x (rho u)),  h = R^T v,  H = [R^T [v]x, R^T, 0, 0]
    attitude: z = -R_imu[2] (the IMU's own attitude, where it sends one),  h = -R[2],
              H = [R^T [(0, 0, -1)]x, 0, 0, 0]

The accelerometer's bias drifts (a MEMS part's bias random walk, hours of a soak): unmodelled, a
vertical bias of 1 m/s^2 reads a trotting Go2 sinking at 1 m/s between the feet's corrections.
The legs make it observable: the velocity they measure does not drift.

with ``v_foot``, ``omega_foot`` the foot's velocity in the base frame (the base at the origin,
turning at ``omega``), ``rho`` its contact sphere's radius and ``u`` the world's down in the base
frame. Updates are Joseph-form, the error folded into the nominal state and zeroed.

Heading is locked (:func:`lock_heading`): the heading is the gyro's, integrated, and the world
frame's (its error has no variance; left to grow, it fed the velocity's through ``[R f]x``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

N_ERROR = 12


@numba.njit(cache=True, nogil=True)
def _skew(a, out) -> None:
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -a[2], a[1]
    out[1, 0], out[1, 1], out[1, 2] = a[2], 0.0, -a[0]
    out[2, 0], out[2, 1], out[2, 2] = -a[1], a[0], 0.0


@numba.njit(cache=True, nogil=True)
def _quat_to_mat(q, out) -> None:
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0, 0] = 1 - 2 * (y * y + z * z)
    out[0, 1] = 2 * (x * y - w * z)
    out[0, 2] = 2 * (x * z + w * y)
    out[1, 0] = 2 * (x * y + w * z)
    out[1, 1] = 1 - 2 * (x * x + z * z)
    out[1, 2] = 2 * (y * z - w * x)
    out[2, 0] = 2 * (x * z - w * y)
    out[2, 1] = 2 * (y * z + w * x)
    out[2, 2] = 1 - 2 * (x * x + y * y)


@numba.njit(cache=True, nogil=True)
def _turn(rotvec, q, left: bool) -> None:
    """``q`` (4,) <- ``Exp(rotvec) q`` (left) or ``q Exp(rotvec)``, normalized."""
    angle = math.sqrt(rotvec[0] ** 2 + rotvec[1] ** 2 + rotvec[2] ** 2)
    if angle < 1e-12:
        half, bw = 0.5, 1.0
    else:
        half, bw = math.sin(angle / 2) / angle, math.cos(angle / 2)
    bx, by, bz = rotvec[0] * half, rotvec[1] * half, rotvec[2] * half
    aw, ax, ay, az = q[0], q[1], q[2], q[3]
    if left:  # b a
        aw, ax, ay, az, bw, bx, by, bz = bw, bx, by, bz, aw, ax, ay, az
    w = aw * bw - ax * bx - ay * by - az * bz
    x = aw * bx + ax * bw + ay * bz - az * by
    y = aw * by - ax * bz + ay * bw + az * bx
    z = aw * bz + ax * by - ay * bx + az * bw
    n = math.sqrt(w * w + x * x + y * y + z * z)
    q[0], q[1], q[2], q[3] = w / n, x / n, y / n, z / n


@numba.njit(cache=True, nogil=True)
def lock_heading(K, q) -> None:
    """Zero, in place, the rows of the gain ``K`` (12, m) that turn the base about the world's
    up (``dtheta_z``) or move the gyro's bias along it (``b_g . R^T e_z``), ``q`` the base's
    attitude ``[w, x, y, z]``.

    The yaw of a base is unobservable from an IMU and leg kinematics (rotating the world about
    gravity changes no measurement; Bloesch et al., "State Estimation for Legged Robots:
    Consistent Fusion of Leg Kinematics and an IMU", RSS 2012), but a linearized filter's gain
    reaches it through its cross-covariances, and every unmodelled error then turns the heading:
    the Go2 on Unitree's simulator, whose feet report no force (the contacts then come from the
    kinematics), read -23 deg for a true -107 deg turn in 30 s. Those rows are zeroed (a
    consider state, Schmidt's Kalman filter; the Joseph form keeps the covariance right for any
    gain), and :func:`imu_step` holds the heading's variance at zero: left to grow (1.8 rad^2 in
    3 minutes), it fed the velocity's through ``[R f]x`` whenever the base accelerated, and the
    Go2's planar velocity error in a soak doubled."""
    R = np.empty((3, 3))
    _quat_to_mat(q, R)
    for c in range(K.shape[1]):
        K[2, c] = 0.0
        along = K[6, c] * R[2, 0] + K[7, c] * R[2, 1] + K[8, c] * R[2, 2]
        for i in range(3):
            K[6 + i, c] -= along * R[2, i]


@numba.njit(cache=True, nogil=True)
def _correct(P, y, H, r_var: float, q, v, b, gate: float) -> bool:
    """The error-state update with innovation ``y`` (3,), ``H`` (3, 12), noise ``r_var I``,
    its gain locked in heading (:func:`lock_heading`), folded into the nominal state ``q``,
    ``v``, ``b`` (6,); False (nothing changed) when the innovation's chi-square exceeds
    ``gate``."""
    PHt = P @ H.T
    S = H @ PHt
    for i in range(3):
        S[i, i] += r_var
    if gate < np.inf:
        if y @ np.linalg.solve(S, y) > gate:
            return False
    K = np.linalg.solve(S, PHt.T).T
    lock_heading(K, q)
    ikh = np.eye(N_ERROR) - K @ H
    P2 = ikh @ P @ ikh.T + r_var * (K @ K.T)
    for i in range(N_ERROR):
        for j in range(N_ERROR):
            P[i, j] = 0.5 * (P2[i, j] + P2[j, i])
    dx = K @ y
    _turn(dx[0:3], q, True)  # R = Exp(dtheta) R: a world-frame error
    for i in range(3):
        v[i] += dx[3 + i]
    for i in range(6):
        b[i] += dx[6 + i]
    return True


@numba.njit(cache=True, nogil=True)
def imu_step(
    q,
    v,
    b,
    P,
    gyro_b,
    acc_b,
    dt: float,
    lever,
    gravity,
    gyro_var: float,
    accel_var: float,
    walk_var: float,
    accel_walk_var: float,
    accel_meas_var: float,
    rest_band: float,
    omega_out,
) -> None:
    """One env's prediction over ``dt`` (s) from a reading already in the base frame and the
    accelerometer's gravity correction (:mod:`sim2real.deploy.estimation.base`); ``q``, ``v``, ``b``,
    ``P`` in place, the bias-free angular velocity in ``omega_out`` (3,)."""
    omega = gyro_b - b[0:3]
    f = acc_b - b[3:6] - np.cross(omega, np.cross(omega, lever))
    R = np.empty((3, 3))
    _quat_to_mat(q, R)
    rf = R @ f
    F = np.eye(N_ERROR)
    sk = np.empty((3, 3))
    _skew(rf, sk)
    for i in range(3):
        for j in range(3):
            F[i, 6 + j] = -R[i, j] * dt
            F[3 + i, j] = -dt * sk[i, j]
            F[3 + i, 9 + j] = -R[i, j] * dt
    P2 = F @ P @ F.T
    for i in range(3):
        P2[i, i] += gyro_var * dt * dt
        P2[3 + i, 3 + i] += accel_var * dt * dt
        P2[6 + i, 6 + i] += walk_var * dt
        P2[9 + i, 9 + i] += accel_walk_var * dt
    P[:, :] = P2
    for i in range(N_ERROR):  # the heading is the filter's own: no uncertainty (lock_heading)
        P[2, i] = 0.0
        P[i, 2] = 0.0
    for i in range(3):
        v[i] += dt * (rf[i] + gravity[i])
    _turn(omega * dt, q, False)
    g = math.sqrt(gravity[0] ** 2 + gravity[1] ** 2 + gravity[2] ** 2)
    fn = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
    if abs(fn - g) < rest_band * g:
        up = -gravity
        _quat_to_mat(q, R)
        turn = np.empty((3, 3))
        _skew(omega, sk)
        turn[:, :] = sk @ R.T
        sk_up = np.empty((3, 3))
        _skew(up, sk_up)
        sk_v = np.empty((3, 3))
        _skew(v, sk_v)
        H = np.zeros((3, N_ERROR))
        H[:, 0:3] = R.T @ sk_up + turn @ sk_v
        H[:, 3:6] = turn
        for i in range(3):
            H[i, 9 + i] = 1.0
        y = f - (R.T @ up + turn @ v)
        _correct(P, y, H, accel_meas_var, q, v, b, np.inf)
    for i in range(3):
        omega_out[i] = gyro_b[i] - b[i]


@numba.njit(cache=True, nogil=True)
def leg_step(q, v, b, P, foot_linear, foot_angular, radius: float, leg_var: float, gate: float):
    """One foot's velocity correction of one env: the foot's velocity (linear, angular; m/s,
    rad/s, base frame at the base's pose) taken as the base's (a rolling sphere of ``radius``);
    True when absorbed, False when gated out as a slip."""
    R = np.empty((3, 3))
    _quat_to_mat(q, R)
    down = -R[2]  # the world's down in the base frame
    z = -(foot_linear + np.cross(foot_angular, radius * down))
    sk_v = np.empty((3, 3))
    _skew(v, sk_v)
    H = np.zeros((3, N_ERROR))
    H[:, 0:3] = R.T @ sk_v
    H[:, 3:6] = R.T
    y = z - R.T @ v
    return _correct(P, y, H, leg_var, q, v, b, gate)


@numba.njit(cache=True, nogil=True)
def attitude_step(q, v, b, P, measured, var: float) -> None:
    """One env's correction by the IMU's own attitude ``measured`` (3, 3), the base-to-world
    rotation it implies: its projected gravity ``z = -measured[2]`` against ``h = R^T (0, 0, -1)``,
    ``H = [R^T [(0, 0, -1)]x, 0, 0]``, noise ``var I``."""
    R = np.empty((3, 3))
    _quat_to_mat(q, R)
    down = np.array([0.0, 0.0, -1.0])
    sk = np.empty((3, 3))
    _skew(down, sk)
    H = np.zeros((3, N_ERROR))
    H[:, 0:3] = R.T @ sk
    y = -measured[2] - (-R[2])
    _correct(P, y, H, var, q, v, b, np.inf)
