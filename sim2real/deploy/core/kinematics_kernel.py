"""Compiled forward kinematics of a serial chain of revolute joints about the x, y or z axis of
their frames (Pinocchio's ``JointModelRX``/``RY``/``RZ``): the end-effector placement as
``pinocchio.forwardKinematics`` and ``updateFramePlacement`` compute it, bit for bit.

The arithmetic is Pinocchio's (4.x, ``TransformRevoluteTpl::se3Action`` and ``SE3Tpl``'s
product), in its order: the joint's rotated column ``cos q col_a + sin q col_b``, the third
column the cross product of the other two, then each link ``oMi = oMi[parent] * liMi``, whose
3x3 products Eigen sums left to right in rows 0 and 1 (one SIMD packet) and right to left in row
2. :class:`sim2real.deploy.core.state.Kinematics` uses it only after checking it against
Pinocchio bit for bit (other builds of Eigen may order the sums differently).
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: Pinocchio's joint models the kernel computes, as its axis codes.
AXES = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}


@numba.njit(cache=True, nogil=True, inline="always")
def _product(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a * b`` of two (3, 4) placements ``[R | p]``, in Eigen's order of the sums."""
    for r in range(3):
        for k in range(4):
            t0 = a[r, 0] * b[0, k]
            t1 = a[r, 1] * b[1, k]
            t2 = a[r, 2] * b[2, k]
            v = (t0 + t1) + t2 if r < 2 else t0 + (t1 + t2)
            out[r, k] = v if k < 3 else a[r, 3] + v


@numba.njit(cache=True, nogil=True, _nrt=False)
def chain_fk(
    q: np.ndarray,
    chain: np.ndarray,
    placements: np.ndarray,
    work: np.ndarray,
    position: np.ndarray,
    rotation: np.ndarray,
) -> None:
    """Write the end-effector placement of every env.

    Args:
        q: (envs, nq) rad, joint angles.
        chain: (joints + 1, 3) int64, per joint its axis (``AXES``), its parent's row (-1: the
            base) and its index in ``q``; the last row (-1, the frame's joint's row, -1).
        placements: (joints + 1, 3, 4) float64, each joint's placement in its parent's frame
            (``model.jointPlacements``), then the frame's in its joint's, ``[R | p]`` (m).
        work: (joints + 1, 3, 4) float64 scratch.
        position: (envs, 3) m and rotation (envs, 3, 3), written: the frame in the base frame.
    """
    joints = chain.shape[0] - 1
    link = work[joints]
    for e in range(q.shape[0]):
        for i in range(joints):
            axis, parent = chain[i, 0], chain[i, 1]
            s = math.sin(q[e, chain[i, 2]])
            c = math.cos(q[e, chain[i, 2]])
            m = placements[i]
            # Pinocchio's se3Action: column ``axis`` kept, column a = c col_a + s col_t, and
            # column t the cross product col_axis x col_a
            a, t = (axis + 1) % 3, (axis + 2) % 3
            for r in range(3):
                link[r, a] = c * m[r, a] + s * m[r, t]
                link[r, axis] = m[r, axis]
                link[r, 3] = m[r, 3]
            link[0, t] = link[1, axis] * link[2, a] - link[2, axis] * link[1, a]
            link[1, t] = link[2, axis] * link[0, a] - link[0, axis] * link[2, a]
            link[2, t] = link[0, axis] * link[1, a] - link[1, axis] * link[0, a]
            out = work[i]
            if parent < 0:
                for r in range(3):
                    for k in range(4):
                        out[r, k] = link[r, k]
            else:
                _product(work[parent], link, out)
        _product(work[chain[joints, 1]], placements[joints], link)
        for r in range(3):
            position[e, r] = link[r, 3]
            for k in range(3):
                rotation[e, r, k] = link[r, k]
