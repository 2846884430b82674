"""Compiled steps of the base estimator's error-state filter (:mod:`sim2real.deploy.estimation.base`) of
one env; the numpy reference of the same algebra (filterpy's predict and update) is
:class:`sim2real.deploy.estimation.reference.ReferenceBaseStateEstimator`.

Nominal state: rotation ``R`` (base to world), velocity ``v`` (m/s, world), the biases ``b``
(6,): the gyro's ``b_g`` (rad/s) and the accelerometer's ``b_a`` (m/s^2), base frame. Error state
(12,): ``dtheta`` (rad, world frame, ``R_true = Exp(dtheta) R``), ``dv``, ``db_g``, ``db_a``. With
the gyro ``omega = w - b_g`` and the specific force at the base origin
``f = a - b_a - omega x (omega x r) - alpha x r`` (``r`` the IMU's lever arm, ``alpha`` the
turn's mean acceleration since the last reading, ``(omega - omega_last) / dt``: over the interval
it integrates to the change of the lever arm's velocity, ``(omega - omega_last) x r``)::

    predict:  v' = v + dt (R f + g)     R' = R Exp(omega dt)     b' = b
              F = [[I, 0, -R dt, 0], [-dt [R f]x, I, 0, -R dt], [0, 0, I, 0], [0, 0, 0, I]]
              Q = diag(sigma_g^2 dt^2 I, sigma_a^2 dt^2 I, walk_g^2 dt I, walk_a^2 dt I)
    gravity:  z = f,  h = R^T (-g) + omega x R^T v,
              H = [R^T [-g]x + [omega]x R^T [v]x, [omega]x R^T, 0, I]
              (only while |f| is within ``rest_band`` of |g|)
    a foot:   z = -(v_foot + omega_foot x (rho u)),  h = R^T v,  H = [R^T [v]x, R^T, 0, 0]
    attitude: z = -R_imu[2] (the IMU's own attitude, where it sends one),  h = -R[2],
              H = [R^T [(0, 0, -1)]x, 0, 0, 0]

with ``v_foot``, ``omega_foot`` the foot's velocity in the base frame (the base at the origin,
turning at ``omega``), ``rho`` its contact sphere's radius and ``u`` the world's down in the base
frame. Updates are Joseph-form, the error folded into the nominal state and zeroed. The
accelerometer's bias drifts (a MEMS random walk) and is observed by the legs, whose velocity
does not drift. The heading is locked (:func:`lock_heading`).

Products are loops into a :func:`workspace`, fused multiply-adds in ``k``'s order: numpy's BLAS
rounding (OpenBLAS, x86-64 with FMA; ``tests/test_base_tick.py``, ``test_legged.py``)."""

from __future__ import annotations

import math

import numba
import numpy as np
from numba import types
from numba.extending import intrinsic

N_ERROR = 12
#: (12, 12) slots of a workspace (:func:`workspace`).
WORK_SLOTS = 8


@intrinsic
def fma(typingctx, a, b, c):
    """``a * b + c`` rounded once (LLVM's ``llvm.fma``; float64)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return sig, codegen


@numba.njit(cache=True, nogil=True)
def workspace() -> np.ndarray:
    """A step's scratch: (``WORK_SLOTS``, 12, 12) float64."""
    return np.empty((WORK_SLOTS, N_ERROR, N_ERROR))


@numba.njit(cache=True, nogil=True)
def _mm(A, B, out, at: bool, bt: bool) -> None:
    """``out`` (m, n) = ``op(A) op(B)``, ``op`` the transpose where ``at`` / ``bt``: each entry
    ``fma`` over ``k`` from 0 (BLAS's gemm). ``out`` shares no memory with ``A`` or ``B``.

    The same sum either way: an entry at a time in a register where ``out`` is narrow or
    ``B`` is transposed (a strided inner loop), else a row of ``out`` at a time (contiguous)."""
    m, n = out.shape[0], out.shape[1]
    kk = A.shape[0] if at else A.shape[1]
    if n <= 3 or bt:
        for i in range(m):
            for j in range(n):
                acc = 0.0
                for k in range(kk):
                    acc = fma(A[k, i] if at else A[i, k], B[j, k] if bt else B[k, j], acc)
                out[i, j] = acc
        return
    for i in range(m):
        for j in range(n):
            out[i, j] = 0.0
        for k in range(kk):
            a = A[k, i] if at else A[i, k]
            for j in range(n):
                out[i, j] = fma(a, B[j, k] if bt else B[k, j], out[i, j])


@numba.njit(cache=True, nogil=True)
def _mm12(A, B, out, BT) -> None:
    """``out`` = ``A op(B)`` of (12, 12) row-major matrices, ``op(B) = B^T`` when ``BT`` (the
    transpose's scratch, (12, 12)) is given, else ``B``: :func:`_mm`'s numbers, its inner loop
    over contiguous rows (vectorized)."""
    if BT is not None:
        for i in range(N_ERROR):
            for j in range(N_ERROR):
                BT[i, j] = B[j, i]
        B = BT
    for i in range(N_ERROR):
        row = out[i]
        for j in range(N_ERROR):
            row[j] = 0.0
        for k in range(N_ERROR):
            a, b = A[i, k], B[k]
            for j in range(N_ERROR):
                row[j] = fma(a, b[j], row[j])


@numba.njit(cache=True, nogil=True)
def mv(A, x, out, at: bool) -> None:
    """``out`` (m,) float64 = ``op(A) x``, ``A`` (m, 3) (``at`` False) or (3, m) (``at`` True:
    ``A.T x``), ``x`` (3,), as BLAS's gemv (numpy's ``A @ x``) rounds it: a row-major ``A``
    ``fma(a2 x2, fma(a0 x0, a1 x1))``, a transposed one ``fma(a2 x2, fma(a1 x1, a0 x0))``."""
    for i in range(out.shape[0]):
        if at:
            out[i] = fma(A[2, i], x[2], fma(A[1, i], x[1], A[0, i] * x[0]))
        else:
            out[i] = fma(A[i, 2], x[2], fma(A[i, 0], x[0], A[i, 1] * x[1]))


@numba.njit(cache=True, nogil=True)
def _cross(a, b, out) -> None:
    """``out`` = ``a x b`` (np.cross's expressions)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


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
    w, x, y, z = q[0], q[1], q[2], q[3]
    r0, r1, r2 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)  # R[2]
    for c in range(K.shape[1]):
        K[2, c] = 0.0
        along = K[6, c] * r0 + K[7, c] * r1 + K[8, c] * r2
        K[6, c] -= along * r0
        K[7, c] -= along * r1
        K[8, c] -= along * r2


@numba.njit(cache=True, nogil=True)
def _correct(P, y, H, r_var: float, q, v, b, gate: float, work) -> bool:
    """The error-state update with innovation ``y`` (3,), ``H`` (3, 12), noise ``r_var I``,
    its gain locked in heading (:func:`lock_heading`), folded into the nominal state ``q``,
    ``v``, ``b`` (6,); False (nothing changed) when the innovation's chi-square exceeds
    ``gate``. ``work``: a :func:`workspace` (its slots 2 to 7; ``H``, ``y`` not in them)."""
    PHt = work[2, :, 0:3]
    S = work[2, 0:3, 3:6]
    _mm(P, H, PHt, False, True)
    _mm(H, PHt, S, False, False)
    for i in range(3):
        S[i, i] += r_var
    if gate < np.inf:
        if y @ np.linalg.solve(S, y) > gate:
            return False
    K = np.linalg.solve(S, PHt.T).T
    lock_heading(K, q)
    ikh, left, P2, kk = work[3], work[4], work[5], work[6]
    _mm(K, H, ikh, False, False)
    for i in range(N_ERROR):
        for j in range(N_ERROR):
            ikh[i, j] = (1.0 if i == j else 0.0) - ikh[i, j]
    _mm12(ikh, P, left, None)
    _mm12(left, ikh, P2, work[7])
    _mm(K, K, kk, False, True)
    for i in range(N_ERROR):
        for j in range(N_ERROR):
            P2[i, j] += r_var * kk[i, j]
    for i in range(N_ERROR):
        for j in range(N_ERROR):
            P[i, j] = 0.5 * (P2[i, j] + P2[j, i])
    dx = work[2, 3]
    mv(K, y, dx, False)
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
    ``P`` in place. ``omega_out`` (3,): in, the last reading's bias-free angular velocity (rad/s;
    its change over ``dt`` is the turn's acceleration); out, this reading's."""
    imu_step_in(
        q, v, b, P, gyro_b, acc_b, dt, lever, gravity, gyro_var, accel_var, walk_var,
        accel_walk_var, accel_meas_var, rest_band, omega_out, workspace(),
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def imu_step_in(
    q, v, b, P, gyro_b, acc_b, dt, lever, gravity, gyro_var, accel_var, walk_var,
    accel_walk_var, accel_meas_var, rest_band, omega_out, work,
) -> None:  # fmt: skip
    """:func:`imu_step` in the :func:`workspace` ``work``."""
    small = work[1]
    omega, f, c1, c2, rf = (
        small[0, 0:3],
        small[0, 3:6],
        small[0, 6:9],
        small[0, 9:12],
        small[1, 0:3],
    )
    up, tv, y = small[1, 3:6], small[1, 6:9], small[1, 9:12]
    R, sk, turn, sk_up, sk_v = (
        small[2:5, 0:3],
        small[2:5, 3:6],
        small[2:5, 6:9],
        small[5:8, 0:3],
        small[5:8, 3:6],
    )
    tmp, tmp2 = small[5:8, 6:9], small[8:11, 0:3]
    alpha, c3 = small[11, 0:3], small[11, 3:6]
    for i in range(3):
        omega[i] = gyro_b[i] - b[i]
        alpha[i] = (omega[i] - omega_out[i]) / dt  # the turn's mean acceleration since the last
    _cross(omega, lever, c1)
    _cross(omega, c1, c2)
    _cross(alpha, lever, c3)
    for i in range(3):
        f[i] = acc_b[i] - b[3 + i] - c2[i] - c3[i]
    _quat_to_mat(q, R)
    mv(R, f, rf, False)
    F, P2 = work[0], work[2]
    _skew(rf, sk)
    for i in range(N_ERROR):
        for j in range(N_ERROR):
            F[i, j] = 1.0 if i == j else 0.0
    for i in range(3):
        for j in range(3):
            F[i, 6 + j] = -R[i, j] * dt
            F[3 + i, j] = -dt * sk[i, j]
            F[3 + i, 9 + j] = -R[i, j] * dt
    FP = work[3]
    _mm12(F, P, FP, None)
    _mm12(FP, F, P2, work[4])
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
        c1[i] = omega[i] * dt
    _turn(c1, q, False)
    g = math.sqrt(gravity[0] ** 2 + gravity[1] ** 2 + gravity[2] ** 2)
    fn = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
    if abs(fn - g) < rest_band * g:
        for i in range(3):
            up[i] = -gravity[i]
        _quat_to_mat(q, R)
        _skew(omega, sk)
        _mm(sk, R, turn, False, True)
        _skew(up, sk_up)
        _skew(v, sk_v)
        H = work[0, 0:3, :]
        H[:, :] = 0.0
        _mm(R, sk_up, tmp, True, False)
        _mm(turn, sk_v, tmp2, False, False)
        for i in range(3):
            for j in range(3):
                H[i, j] = tmp[i, j] + tmp2[i, j]
                H[i, 3 + j] = turn[i, j]
            H[i, 9 + i] = 1.0
        mv(R, up, c1, True)
        mv(turn, v, tv, False)
        for i in range(3):
            y[i] = f[i] - (c1[i] + tv[i])
        _correct(P, y, H, accel_meas_var, q, v, b, np.inf, work)
    for i in range(3):
        omega_out[i] = gyro_b[i] - b[i]


@numba.njit(cache=True, nogil=True)
def leg_step(q, v, b, P, foot_linear, foot_angular, radius: float, leg_var: float, gate: float):
    """One foot's velocity correction of one env: the foot's velocity (linear, angular; m/s,
    rad/s, base frame at the base's pose) taken as the base's (a rolling sphere of ``radius``);
    True when absorbed, False when gated out as a slip."""
    return leg_step_in(q, v, b, P, foot_linear, foot_angular, radius, leg_var, gate, workspace())


@numba.njit(cache=True, nogil=True)
def leg_step_in(q, v, b, P, foot_linear, foot_angular, radius, leg_var, gate, work) -> bool:
    """:func:`leg_step` in the :func:`workspace` ``work``."""
    small = work[1]
    down, c1, z, rv, y = small[0, 0:3], small[0, 3:6], small[0, 6:9], small[0, 9:12], small[1, 0:3]
    R, sk_v, tmp = small[2:5, 0:3], small[2:5, 3:6], small[2:5, 6:9]
    _quat_to_mat(q, R)
    for i in range(3):
        down[i] = radius * -R[2, i]  # the world's down in the base frame, times the radius
    _cross(foot_angular, down, c1)
    for i in range(3):
        z[i] = -(foot_linear[i] + c1[i])
    _skew(v, sk_v)
    H = work[0, 0:3, :]
    H[:, :] = 0.0
    _mm(R, sk_v, tmp, True, False)
    for i in range(3):
        for j in range(3):
            H[i, j] = tmp[i, j]
            H[i, 3 + j] = R[j, i]
    mv(R, v, rv, True)
    for i in range(3):
        y[i] = z[i] - rv[i]
    return _correct(P, y, H, leg_var, q, v, b, gate, work)


@numba.njit(cache=True, nogil=True)
def attitude_step(q, v, b, P, measured, var: float) -> None:
    """One env's correction by the IMU's own attitude ``measured`` (3, 3), the base-to-world
    rotation it implies: its projected gravity ``z = -measured[2]`` against ``h = R^T (0, 0, -1)``,
    ``H = [R^T [(0, 0, -1)]x, 0, 0]``, noise ``var I``."""
    attitude_step_in(q, v, b, P, measured, var, workspace())


@numba.njit(cache=True, nogil=True)
def attitude_step_in(q, v, b, P, measured, var, work) -> None:
    """:func:`attitude_step` in the :func:`workspace` ``work``."""
    small = work[1]
    down, y = small[0, 0:3], small[0, 3:6]
    R, sk, tmp = small[2:5, 0:3], small[2:5, 3:6], small[2:5, 6:9]
    _quat_to_mat(q, R)
    down[0], down[1], down[2] = 0.0, 0.0, -1.0
    _skew(down, sk)
    H = work[0, 0:3, :]
    H[:, :] = 0.0
    _mm(R, sk, tmp, True, False)
    H[:, 0:3] = tmp
    for i in range(3):
        y[i] = -measured[2, i] - (-R[2, i])
    _correct(P, y, H, var, q, v, b, np.inf, work)
