"""Compiled rows of the attitude math (:mod:`sim2real.deploy.core.attitude`): rotation matrices and
Hamilton products of k quaternions ``[w, x, y, z]``, the same expressions in the same order, so
both give the same numbers bit for bit. For one robot the numpy versions cost most of the legged
estimate stage (each ``np.stack`` of small arrays is a few microseconds); these cost one call.
"""

from __future__ import annotations

import math

import numba


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
def quat_mul_finite_rows(a, b, out) -> None:
    """``out[e]`` (4,) = the Hamilton product ``a[e] b`` of the (k, 4) float64 quaternions ``a``
    and one (4,) float64 ``b``, for each row of ``a`` whose four components are finite; the other
    rows of ``out`` are left as they are (:func:`quat_mul_rows`' expressions, the same numbers)."""
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    for e in range(a.shape[0]):
        aw, ax, ay, az = a[e, 0], a[e, 1], a[e, 2], a[e, 3]
        if not (math.isfinite(aw) and math.isfinite(ax) and math.isfinite(ay)):
            continue
        if not math.isfinite(az):
            continue
        out[e, 0] = aw * bw - ax * bx - ay * by - az * bz
        out[e, 1] = aw * bx + ax * bw + ay * bz - az * by
        out[e, 2] = aw * by - ax * bz + ay * bw + az * bx
        out[e, 3] = aw * bz + ax * by - ay * bx + az * bw


@numba.njit(cache=True, nogil=True, _nrt=False)
def _norm(v0: float, v1: float, v2: float, v3: float) -> float:
    """``np.linalg.norm`` of a row of 4 (3 with ``v3 = 0``): numpy's sequential sum of squares."""
    return math.sqrt(v0 * v0 + v1 * v1 + v2 * v2 + v3 * v3)


@numba.njit(cache=True, nogil=True, _nrt=False)
def rotation_rows(rotvec, out) -> None:
    """``out[e]`` (4,) = :func:`sim2real.deploy.core.attitude.rotation_quaternions` of ``rotvec[e]``
    (k, 3) rad (below 1e-12 rad the first-order ``[1, rotvec / 2]``)."""
    for e in range(rotvec.shape[0]):
        r0, r1, r2 = rotvec[e, 0], rotvec[e, 1], rotvec[e, 2]
        angle = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if angle < 1e-12:
            half, w = 0.5, 1.0
        else:
            half, w = math.sin(angle / 2) / angle, math.cos(angle / 2)
        out[e, 0], out[e, 1], out[e, 2], out[e, 3] = w, r0 * half, r1 * half, r2 * half
