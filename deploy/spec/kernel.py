"""Kernel of :meth:`deploy.spec.policy_spec.PolicySpec.observation`: assemble, normalize, clip,
cast.

The blocks are coded as integers (``KIND_CODES``, the order of
``deploy.spec.policy_spec.OBSERVATION_KINDS``
is not assumed); each block has its start column, size and joint indices (a (blocks, max_joints)
int64 array, padded). The arithmetic is the reference's: ``(raw - offset) / scale``, then the
upper clip, then the lower clip, then the cast to float32; ``goal_in_ee`` is
``(goal - ee) @ R`` summed in the order of numpy's matmul loop. The floating-base blocks read the
base estimate (linear and angular velocity, projected gravity, orientation), the velocity command,
the clock and the foot contacts; ``gait_phase`` is ``sin, cos`` of ``(2 pi / period) * clock``
and ``heading_sincos`` of the yaw ``atan2(2 (w z + x y), 1 - 2 (y^2 + z^2))``, as the reference
computes them (:func:`deploy.spec.observation_plan._legged_block`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from deploy.kernels import np_max, np_min

KIND_CODES = {
    "joint_position": 0,
    "joint_velocity": 1,
    "joint_position_sincos": 2,
    "ee_position": 3,
    "goal_position": 4,
    "goal_in_ee": 5,
    "last_action": 6,
    "winding_temperature": 7,
    "base_linear_velocity": 8,
    "base_angular_velocity": 9,
    "projected_gravity": 10,
    "velocity_command": 11,
    "gait_phase": 12,
    "foot_contact": 13,
    "heading_sincos": 14,
}


@numba.njit(cache=True, nogil=True)
def observation(
    kinds: np.ndarray,
    starts: np.ndarray,
    joints: np.ndarray,
    periods: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    ee_position: np.ndarray,
    ee_rotation: np.ndarray,
    goal: np.ndarray,
    last_action: np.ndarray,
    temperature: np.ndarray,
    linear_velocity: np.ndarray,
    angular_velocity: np.ndarray,
    gravity: np.ndarray,
    command: np.ndarray,
    orientation: np.ndarray,
    clock: np.ndarray,
    contact: np.ndarray,
    norm: np.ndarray,
    raw: np.ndarray,
    out: np.ndarray,
) -> None:
    """Write the observation of every env into ``out`` (float32 (envs, dim)).

    Args:
        kinds, starts: (blocks,) int64, block codes (``KIND_CODES``) and first columns.
        joints: (blocks, k) int64 joint indices, -1 padded (a block's size is its column span).
        periods: (blocks,) float64, the gait clock's period of a ``gait_phase`` block, s.
        q, dq, last_action, temperature: (envs, n); ee_position, goal (envs, 3); ee_rotation
            (envs, 3, 3): the inputs of the reference, same units.
        linear_velocity, angular_velocity, gravity, command: (envs, 3) base linear velocity
            (m/s), angular velocity (rad/s), projected gravity, velocity command (vx, vy m/s,
            yaw rate rad/s), base frame; orientation (envs, 4) ``[w, x, y, z]``; clock (envs,)
            s; contact (envs, feet). Read by the floating-base blocks only.
        norm: (3, dim) float64 rows offset, scale, clip.
        raw: (>= envs, dim) float64 work array.
    """
    envs = q.shape[0]
    dim = out.shape[1]
    blocks = kinds.shape[0]
    for e in range(envs):
        for b in range(blocks):
            kind, s0 = kinds[b], starts[b]
            s1 = starts[b + 1] if b + 1 < blocks else dim
            size = s1 - s0
            if kind == 0:
                for i in range(size):
                    raw[e, s0 + i] = q[e, joints[b, i]]
            elif kind == 1:
                for i in range(size):
                    raw[e, s0 + i] = dq[e, joints[b, i]]
            elif kind == 2:
                k = size // 2
                for i in range(k):
                    raw[e, s0 + i] = math.sin(q[e, joints[b, i]])
                for i in range(k):
                    raw[e, s0 + k + i] = math.cos(q[e, joints[b, i]])
            elif kind == 3:
                for i in range(size):
                    raw[e, s0 + i] = ee_position[e, i]
            elif kind == 4:
                for i in range(size):
                    raw[e, s0 + i] = goal[e, i]
            elif kind == 5:
                v0 = goal[e, 0] - ee_position[e, 0]
                v1 = goal[e, 1] - ee_position[e, 1]
                v2 = goal[e, 2] - ee_position[e, 2]
                for i in range(3):
                    acc = 0.0
                    acc += v0 * ee_rotation[e, 0, i]
                    acc += v1 * ee_rotation[e, 1, i]
                    acc += v2 * ee_rotation[e, 2, i]
                    raw[e, s0 + i] = acc
            elif kind == 6:
                for i in range(size):
                    raw[e, s0 + i] = last_action[e, joints[b, i]]
            elif kind == 7:
                for i in range(size):
                    raw[e, s0 + i] = temperature[e, joints[b, i]]
            elif kind == 8:
                for i in range(size):
                    raw[e, s0 + i] = linear_velocity[e, i]
            elif kind == 9:
                for i in range(size):
                    raw[e, s0 + i] = angular_velocity[e, i]
            elif kind == 10:
                for i in range(size):
                    raw[e, s0 + i] = gravity[e, i]
            elif kind == 11:
                for i in range(size):
                    raw[e, s0 + i] = command[e, i]
            elif kind == 12:
                phase = (2.0 * math.pi / periods[b]) * clock[e]
                raw[e, s0] = math.sin(phase)
                raw[e, s0 + 1] = math.cos(phase)
            elif kind == 13:
                for i in range(size):
                    raw[e, s0 + i] = contact[e, i]
            else:
                w, x = orientation[e, 0], orientation[e, 1]
                y, z = orientation[e, 2], orientation[e, 3]
                yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
                raw[e, s0] = math.sin(yaw)
                raw[e, s0 + 1] = math.cos(yaw)
        for i in range(dim):
            v = raw[e, i] - norm[0, i]
            v = v / norm[1, i]
            v = np_min(v, norm[2, i])
            v = np_max(v, -norm[2, i])
            out[e, i] = np.float32(v)
