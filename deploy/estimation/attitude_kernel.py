"""Compiled rows of the attitude math (:mod:`deploy.estimation.attitude`): rotation matrices and
Hamilton products of k quaternions ``[w, x, y, z]``, the same expressions in the same order, so
both give the same numbers bit for bit. For one robot the numpy versions cost most of the legged
estimate stage (each ``np.stack`` of small arrays is a few microseconds); these cost one call.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, _nrt=False)
def quat_to_mat_rows(q, out) -> None:
    """``out[e]`` (3, 3) = the rotation matrix of unit quaternion ``q[e]`` (k, 4) float64."""
    for e in range(q.shape[0]):
        w, x, y, z = q[e, 0], q[e, 1], q[e, 2], q[e, 3]
        out[e, 0, 0] = 1 - 2 * (y * y + z * z)
        out[e, 0, 1] = 2 * (x * y - w * z)
        out[e, 0, 2] = 2 * (x * z + w * y)
        out[e, 1, 0] = 2 * (x * y + w * z)
        out[e, 1, 1] = 1 - 2 * (x * x + z * z)
        out[e, 1, 2] = 2 * (y * z - w * x)
        out[e, 2, 0] = 2 * (x * z - w * y)
        out[e, 2, 1] = 2 * (y * z + w * x)
        out[e, 2, 2] = 1 - 2 * (x * x + y * y)


@numba.njit(cache=True, nogil=True, _nrt=False)
def quat_mul_rows(a, b, out) -> None:
    """``out[e]`` (4,) = the Hamilton product ``a[e] b[e]`` of (k, 4) float64 quaternions."""
    for e in range(a.shape[0]):
        aw, ax, ay, az = a[e, 0], a[e, 1], a[e, 2], a[e, 3]
        bw, bx, by, bz = b[e, 0], b[e, 1], b[e, 2], b[e, 3]
        out[e, 0] = aw * bw - ax * bx - ay * by - az * bz
        out[e, 1] = aw * bx + ax * bw + ay * bz - az * by
        out[e, 2] = aw * by - ax * bz + ay * bw + az * bx
        out[e, 3] = aw * bz + ax * by - ay * bx + az * bw


@numba.njit(cache=True, nogil=True, _nrt=False)
def _norm(v0: float, v1: float, v2: float, v3: float) -> float:
    """``np.linalg.norm`` of a row of 4 (3 with ``v3 = 0``): numpy's sequential sum of squares."""
    return math.sqrt(v0 * v0 + v1 * v1 + v2 * v2 + v3 * v3)


@numba.njit(cache=True, nogil=True, _nrt=False)
def mahony_rows(quaternion, bias, gyro, acceleration, dt, k_p: float, k_i: float, out) -> None:
    """:func:`deploy.estimation.attitude.mahony_update` of k filters, row by row, into ``out``
    (k, 4); ``bias`` (k, 3) updated in place. The same expressions in the same order."""
    for e in range(quaternion.shape[0]):
        n = _norm(quaternion[e, 0], quaternion[e, 1], quaternion[e, 2], quaternion[e, 3])
        w, x, y, z = (
            quaternion[e, 0] / n,
            quaternion[e, 1] / n,
            quaternion[e, 2] / n,
            quaternion[e, 3] / n,
        )
        g0, g1, g2 = gyro[e, 0], gyro[e, 1], gyro[e, 2]
        a0, a1, a2 = acceleration[e, 0], acceleration[e, 1], acceleration[e, 2]
        moving = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2) != 0
        a_norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        corrected = 1.0 if (moving and a_norm > 0) else 0.0
        u0 = 2 * (x * z - w * y)  # the rotation matrix's last row: R^T [0, 0, 1]
        u1 = 2 * (y * z + w * x)
        u2 = 1 - 2 * (x * x + y * y)
        safe = a_norm if a_norm > 0 else 1.0
        b0, b1, b2 = a0 / safe, a1 / safe, a2 / safe
        e0 = (b1 * u2 - b2 * u1) * corrected
        e1 = (b2 * u0 - b0 * u2) * corrected
        e2 = (b0 * u1 - b1 * u0) * corrected
        bias[e, 0] += (-k_i * e0) * dt[e]
        bias[e, 1] += (-k_i * e1) * dt[e]
        bias[e, 2] += (-k_i * e2) * dt[e]
        if corrected != 0.0:
            o0 = g0 - bias[e, 0] + k_p * e0
            o1 = g1 - bias[e, 1] + k_p * e1
            o2 = g2 - bias[e, 2] + k_p * e2
        else:
            o0, o1, o2 = g0, g1, g2
        if not moving:
            out[e, 0], out[e, 1], out[e, 2], out[e, 3] = w, x, y, z
            continue
        r0 = 0.5 * (w * 0.0 - x * o0 - y * o1 - z * o2)
        r1 = 0.5 * (w * o0 + x * 0.0 + y * o2 - z * o1)
        r2 = 0.5 * (w * o1 - x * o2 + y * 0.0 + z * o0)
        r3 = 0.5 * (w * o2 + x * o1 - y * o0 + z * 0.0)
        n0, n1, n2, n3 = w + r0 * dt[e], x + r1 * dt[e], y + r2 * dt[e], z + r3 * dt[e]
        m = _norm(n0, n1, n2, n3)
        out[e, 0], out[e, 1], out[e, 2], out[e, 3] = n0 / m, n1 / m, n2 / m, n3 / m


@numba.njit(cache=True, nogil=True, _nrt=False)
def rotation_rows(rotvec, out) -> None:
    """``out[e]`` (4,) = :func:`deploy.estimation.attitude.rotation_quaternions` of ``rotvec[e]``
    (k, 3) rad (below 1e-12 rad the first-order ``[1, rotvec / 2]``)."""
    for e in range(rotvec.shape[0]):
        r0, r1, r2 = rotvec[e, 0], rotvec[e, 1], rotvec[e, 2]
        angle = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if angle < 1e-12:
            half, w = 0.5, 1.0
        else:
            half, w = math.sin(angle / 2) / angle, math.cos(angle / 2)
        out[e, 0], out[e, 1], out[e, 2], out[e, 3] = w, r0 * half, r1 * half, r2 * half


@numba.njit(cache=True, nogil=True)
def imu_rows(
    envs,
    stamp,
    gyro,
    acc,
    imu_to_base,
    filter_time,
    orientation,
    bias,
    angular_velocity,
    velocity,
    velocity_variance,
    motion_acceleration,
    gravity,
    accel_variance: float,
    k_p: float,
    k_i: float,
    rot_out,
) -> None:
    """The base estimator's IMU step (:meth:`deploy.estimation.base.BaseStateEstimator.update`)
    for the envs ``envs`` (int64 (k,)) with a fresh reading: the readings turned into the base
    frame, the base's own acceleration ``motion_acceleration + omega x v`` taken off the
    accelerometer's (``omega`` the gyro less the bias, ``v`` the base velocity estimate in the
    base frame, ``motion_acceleration`` (envs, 3) m/s^2 the leg odometry's), Mahony's update on it,
    the velocity filter's prediction on the reading itself; the state arrays (env axis first)
    updated in place and each env's new rotation matrix in ``rot_out`` (k, 3, 3)."""
    q_in = np.empty((1, 4))
    b_row = np.empty((1, 3))
    g_row = np.empty((1, 3))
    a_row = np.empty((1, 3))
    up_row = np.empty((1, 3))
    v_b = np.empty(3)
    w = np.empty(3)
    dt_row = np.empty(1)
    q_out = np.empty((1, 4))
    rot = np.empty((1, 3, 3))
    for k in range(envs.shape[0]):
        e = envs[k]
        dt = stamp[e] - filter_time[e]
        for i in range(3):
            g_row[0, i] = (
                gyro[e, 0] * imu_to_base[i, 0]
                + gyro[e, 1] * imu_to_base[i, 1]
                + gyro[e, 2] * imu_to_base[i, 2]
            )
            a_row[0, i] = (
                acc[e, 0] * imu_to_base[i, 0]
                + acc[e, 1] * imu_to_base[i, 1]
                + acc[e, 2] * imu_to_base[i, 2]
            )
            b_row[0, i] = bias[e, i]
        for i in range(4):
            q_in[0, i] = orientation[e, i]
        quat_to_mat_rows(q_in, rot)  # the previous orientation: v in the base frame
        for i in range(3):
            v_b[i] = (
                rot[0, 0, i] * velocity[e, 0]
                + rot[0, 1, i] * velocity[e, 1]
                + rot[0, 2, i] * velocity[e, 2]
            )
            w[i] = g_row[0, i] - b_row[0, i]
        m = motion_acceleration
        up_row[0, 0] = a_row[0, 0] - (m[e, 0] + (w[1] * v_b[2] - w[2] * v_b[1]))
        up_row[0, 1] = a_row[0, 1] - (m[e, 1] + (w[2] * v_b[0] - w[0] * v_b[2]))
        up_row[0, 2] = a_row[0, 2] - (m[e, 2] + (w[0] * v_b[1] - w[1] * v_b[0]))
        dt_row[0] = dt
        mahony_rows(q_in, b_row, g_row, up_row, dt_row, k_p, k_i, q_out)
        quat_to_mat_rows(q_out, rot)
        for i in range(4):
            orientation[e, i] = q_out[0, i]
        for i in range(3):
            bias[e, i] = b_row[0, i]
            angular_velocity[e, i] = g_row[0, i] - b_row[0, i]
        for i in range(3):
            world = (
                rot[0, i, 0] * a_row[0, 0] + rot[0, i, 1] * a_row[0, 1] + rot[0, i, 2] * a_row[0, 2]
            )
            velocity[e, i] += dt * (world + gravity[i])
            for j in range(3):
                rot_out[k, i, j] = rot[0, i, j]
        velocity_variance[e] += dt * dt * accel_variance
        filter_time[e] = stamp[e]


@numba.njit(cache=True, nogil=True)
def predict_rows(
    now,
    filter_time,
    angular_velocity,
    orientation,
    velocity,
    time_since_fresh,
    out_orientation,
    out_gravity,
    out_velocity,
) -> None:
    """The base estimate predicted from each env's filter time to ``now`` (k,) s: the orientation
    turned by its angular velocity (held where the filter is not behind), projected gravity and
    the body-frame linear velocity (the velocity held)."""
    turn = np.empty((1, 4))
    omega_dt = np.empty((1, 3))
    q_row = np.empty((1, 4))
    turned = np.empty((1, 4))
    rot = np.empty((1, 3, 3))
    for e in range(orientation.shape[0]):
        age = now[e] - filter_time[e]
        time_since_fresh[e] = age
        for i in range(4):
            q_row[0, i] = orientation[e, i]
        if age > 0:
            for i in range(3):
                omega_dt[0, i] = angular_velocity[e, i] * age
            rotation_rows(omega_dt, turn)
            quat_mul_rows(q_row, turn, turned)
            for i in range(4):
                q_row[0, i] = turned[0, i]
        quat_to_mat_rows(q_row, rot)
        for i in range(4):
            out_orientation[e, i] = q_row[0, i]
        for i in range(3):
            out_gravity[e, i] = -rot[0, 2, i]
            out_velocity[e, i] = (
                rot[0, 0, i] * velocity[e, 0]
                + rot[0, 1, i] * velocity[e, 1]
                + rot[0, 2, i] * velocity[e, 2]
            )
