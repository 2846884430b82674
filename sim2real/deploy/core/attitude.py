"""Attitude math of the base estimator: quaternions ``[w, x, y, z]`` (base-to-world), rotation
vectors, projected gravity and tilt. Angles in rad, arrays batch-first. These numpy functions are
the references of the compiled rows of :mod:`sim2real.deploy.core.attitude_kernel` (the same numbers);
:func:`quaternion_to_matrix`, :func:`quat_multiply` and :func:`rotation_quaternions` themselves go
through those kernels for float64 rows and single quaternions (numpy's ``np.stack`` of small
arrays costs a few microseconds a call; the simulated IMU calls them every tick).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.attitude_kernel import quat_mul_rows, quat_to_mat_rows, rotation_rows


def _rows(a, width: int) -> bool:
    """Whether ``a`` is a float64 array of one or a row of ``width``-vectors (a kernel's input)."""
    return isinstance(a, np.ndarray) and a.dtype == np.float64 and a.shape[-1:] == (width,)


def _stretch(rows: np.ndarray, k: int) -> np.ndarray:
    """(k, 4) contiguous rows: ``rows`` (1 or k, 4) broadcast."""
    return np.ascontiguousarray(rows if len(rows) == k else np.broadcast_to(rows, (k, 4)))


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions ``[w, x, y, z]`` (..., 4), broadcast; a (4,) or (k, 4)
    result of float64 inputs is computed by
    :func:`~sim2real.deploy.core.attitude_kernel.quat_mul_rows` (the same numbers)."""
    if _rows(a, 4) and _rows(b, 4) and a.ndim <= 2 and b.ndim <= 2:
        rows_a, rows_b = a.reshape(-1, 4), b.reshape(-1, 4)
        k = max(len(rows_a), len(rows_b))
        if len(rows_a) in (1, k) and len(rows_b) in (1, k):  # else numpy's broadcast error
            out = np.empty((k, 4))
            quat_mul_rows(_stretch(rows_a, k), _stretch(rows_b, k), out)
            return out if max(a.ndim, b.ndim) == 2 else out[0]
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def rotation_quaternions(rotvec: np.ndarray) -> np.ndarray:
    """Quaternions ``[w, x, y, z]`` (k, 4) of rotation vectors (k, 3) rad (below 1e-12 rad the
    first-order ``[1, rotvec / 2]``); float64 rows through
    :func:`~sim2real.deploy.core.attitude_kernel.rotation_rows` (the same numbers)."""
    if _rows(rotvec, 3) and rotvec.ndim == 2:
        out = np.empty((rotvec.shape[0], 4))
        rotation_rows(np.ascontiguousarray(rotvec), out)
        return out
    angle = np.linalg.norm(rotvec, axis=1)
    small = angle < 1e-12
    half = np.where(small, 0.5, np.sin(angle / 2) / np.where(small, 1.0, angle))
    w = np.where(small, 1.0, np.cos(angle / 2))
    return np.concatenate([w[:, None], rotvec * half[:, None]], axis=1)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions ``[w, x, y, z]`` (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim in (1, 2):  # a row of rows, or one quaternion: the same expressions, compiled
        rows = np.ascontiguousarray(q.reshape(-1, 4))
        out = np.empty((rows.shape[0], 3, 3))
        quat_to_mat_rows(rows, out)
        return out if q.ndim == 2 else out[0]
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def projected_gravity(q: np.ndarray) -> np.ndarray:
    """Unit gravity direction in the base frame, ``R^T [0, 0, -1]``, (..., 3), for base-to-world
    quaternions ``[w, x, y, z]`` (..., 4)."""
    return -quaternion_to_matrix(q)[..., 2, :]


def tilt_of(gravity: np.ndarray) -> np.ndarray:
    """Angle (rad) between the base's z axis and the world's up, (...,), from projected gravity
    (..., 3): 0 upright, pi/2 on its side, pi upside down."""
    g = np.asarray(gravity, dtype=np.float64)
    g = g / np.linalg.norm(g, axis=-1, keepdims=True)
    return np.arccos(np.clip(-g[..., 2], -1.0, 1.0))


def yaw_of(q: np.ndarray) -> np.ndarray:
    """Yaw (rad, (-pi, pi]) of the base's x axis about the world's up, (...,), from base-to-world
    unit quaternions ``[w, x, y, z]`` (..., 4)."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def align_up(up: np.ndarray) -> np.ndarray:
    """Base-to-world quaternion (yaw 0) that turns the unit vector ``up`` (base frame) onto the
    world's +z."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    s, c = np.linalg.norm(axis), float(np.dot(up, z))
    if s < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0]) if c > 0 else np.array([0.0, 1.0, 0.0, 0.0])
    return rotation_quaternions((axis / s * np.arctan2(s, c))[None])[0]
