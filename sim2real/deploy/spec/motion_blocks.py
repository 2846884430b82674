"""The observation blocks of a whole-body motion-tracking policy, as rl_sar computes them.

rl_sar (fan-ziqi/rl_sar ``RL::ComputeObservation``, ``MotionLoader``, ``vector_math.hpp``)
defines two terms from the reference clip:

- ``motion_command`` (2k): the clip's joint angles, rad, then its joint velocities, rad/s, of
  the block's k joints in the policy's order, at the motion clock's time.
- ``motion_anchor_ori_b`` (6): the anchor body's (G1: ``torso_link``) orientation error
  ``R = R(q_torso)^T R(q_ref)``, ``q_ref`` the clip's anchor yaw-aligned to the robot at the
  clip's start, as the first two columns of ``R`` flattened row by row
  ``[R00, R01, R10, R11, R20, R21]`` (rl_sar's ``MatrixFirstTwoColumns``). The robot's torso
  is ``q_base * Rz(yaw) * Rx(roll) * Ry(pitch)`` of the block's three joints (rl_sar's
  ``ComputeTorsoQuat``): the torso sits at the end of the waist chain yaw, roll, pitch whose
  bodies carry no rotation of their own in unitree_mujoco's ``g1_29dof.xml``
  (``tests/test_motion_blocks.py`` checks it against MuJoCo's ``xquat`` of ``torso_link``).
  ``q_base`` is what the robot senses (:func:`anchor_base_orientation`): the IMU's own attitude
  where the robot's IMU sends one (rl_sar's ``RL_Real::RunModel`` on the G1: ``base_quat =
  imu_state.quaternion``), else the base estimate's.

A phase-clocked policy (rl_sar's ``RoboMimic_Deploy/phase``; no clip at run time) reads
``motion_phase`` (1): ``t / T``, ``t`` the runtime's motion clock (``RobotState.motion_time``,
:class:`~sim2real.deploy.core.phase_clock.MotionPhaseClock`), ``T`` the block's ``period``, not
clamped (``rl_sdk.cpp``); a stack whose first tick reads more than 0 says so in the offset.

The first two read what the motion task writes into ``RobotState.motion`` (envs, 2n + 4): the clip's
joint angles (n) and velocities (n) in the robot's joint order, then the reference anchor
quaternion ``w x y z`` in the world frame, already yaw-aligned
(:mod:`sim2real.deploy.tasks.motion.clock`). Quaternions here are ``w x y z``, arrays (..., 4).
They run in numpy (``NUMPY_REASON``): the compiled kernel has no input for a clip.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.attitude import quat_multiply as quat_mul
from sim2real.robots.errors import Sim2RealError


class MotionBlockError(Sim2RealError, ValueError):
    """A motion block asked for its observation with no reference motion written."""


#: Why the motion blocks run in numpy, not in the compiled kernel (ObservationPlan.numpy_reason).
NUMPY_REASON = (
    "a motion-tracking block reads the clip the motion task writes (RobotState.motion), which the "
    "compiled kernel has no input for"
)


#: The kinds these writers are (:mod:`sim2real.deploy.spec.kinds`) that read the clip.
KIND_NAMES = ["motion_command", "motion_anchor_ori_b"]
#: Why ``motion_phase`` runs in numpy.
PHASE_REASON = (
    "a motion phase block reads the runtime's motion clock (RobotState.motion_time), which the "
    "compiled kernel has no input for"
)


def quat_conj(q: np.ndarray) -> np.ndarray:
    """The conjugate ``w -x -y -z`` (..., 4)."""
    return np.asarray(q, float) * np.array([1.0, -1.0, -1.0, -1.0])


def axis_quat(axis: int, angle: np.ndarray) -> np.ndarray:
    """The rotation by ``angle`` (..., rad) about the unit axis ``axis`` (0 x, 1 y, 2 z)."""
    angle = np.asarray(angle, float)
    out = np.zeros(angle.shape + (4,))
    out[..., 0] = np.cos(0.5 * angle)
    out[..., 1 + axis] = np.sin(0.5 * angle)
    return out


def yaw_only(q: np.ndarray) -> np.ndarray:
    """The yaw-only quaternion of ``q`` (..., 4): ``atan2(2(wz + xy), 1 - 2(y^2 + z^2))`` about
    z (rl_sar's ``QuaternionYawOnly``)."""
    w, x, y, z = np.moveaxis(np.asarray(q, float), -1, 0)
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return axis_quat(2, yaw)


def torso_quat(base: np.ndarray, waist: np.ndarray) -> np.ndarray:
    """The torso's orientation (..., 4), normalized: ``base * Rz(yaw) * Rx(roll) * Ry(pitch)``
    of the waist angles ``waist`` (..., 3) rad, yaw, roll, pitch (rl_sar's ``ComputeTorsoQuat``)."""
    waist = np.asarray(waist, float)
    q = quat_mul(base, axis_quat(2, waist[..., 0]))
    q = quat_mul(q, axis_quat(0, waist[..., 1]))
    q = quat_mul(q, axis_quat(1, waist[..., 2]))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def first_two_columns(q: np.ndarray) -> np.ndarray:
    """(..., 6) the first two columns of ``q``'s rotation matrix, row by row: ``R00, R01, R10,
    R11, R20, R21`` (rl_sar's ``QuaternionToRotationMatrix`` then ``MatrixFirstTwoColumns``; the
    matrix of a non-unit ``q`` as its formula gives it)."""
    w, x, y, z = np.moveaxis(np.asarray(q, float), -1, 0)
    return np.stack(
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
        ],
        axis=-1,
    )


def anchor_ori_b(robot_torso: np.ndarray, reference_anchor: np.ndarray) -> np.ndarray:
    """(..., 6) ``first_two_columns(conj(robot_torso) * reference_anchor)`` (rl_sar's
    ``whole_body_tracking/motion_anchor_ori_b``), both (..., 4) world frame."""
    return first_two_columns(quat_mul(quat_conj(robot_torso), reference_anchor))


def slerp(q0: np.ndarray, q1: np.ndarray, t: float) -> np.ndarray:
    """rl_sar's ``MotionLoader::Slerp`` of two (4,) quaternions at ``t`` in [0, 1]: the shorter
    arc (``q1`` negated when ``q0 . q1 < 0``); a normalized linear blend when ``q0 . q1 >
    0.9995``."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    dot = float(q0 @ q1)
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + t * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = float(np.arccos(min(max(dot, -1.0), 1.0)))
    s = np.sin(theta)
    return q0 * (np.sin((1.0 - t) * theta) / s) + q1 * (np.sin(t * theta) / s)


def anchor_base_orientation(state) -> np.ndarray:
    """(envs, 4) the base orientation the anchor is built from and the clip aligned to:
    ``state.sensed_orientation`` (the IMU's own attitude) where the robot's IMU sends one,
    else the base estimate's ``state.base.orientation`` (robot.toml ``[sensors.imu]
    orientation_sigma`` says which: the legged kind's state carries
    ``sensed_orientation`` only where it is set)."""
    sensed = getattr(state, "sensed_orientation", None)
    return state.base.orientation if sensed is None else sensed


def motion_buffer(spec, envs: int, n: int) -> np.ndarray | None:
    """``RobotState.motion`` for a spec that reads a clip (envs, 2n + 4): zero angles and
    velocities, the identity anchor, until the motion task writes the clip; None otherwise."""
    if not any(KIND_NAMES.count(b.name) for b in spec.observation_blocks):
        return None
    out = np.zeros((envs, 2 * n + 4))
    out[:, 2 * n] = 1.0
    return out


def _motion(state, block) -> np.ndarray:
    motion = getattr(state, "motion", None)
    if motion is None:
        raise MotionBlockError(
            f"observation: block '{block.kind.name}' needs a reference motion (deploy-run "
            "--motion CLIP, or the clip its contract names)"
        )
    return motion


def motion_command(state, goal, raw, block, vec, rot) -> None:
    """Writer of ``motion_command`` (module docstring): ``raw`` (envs, 2k)."""
    motion = _motion(state, block)
    n, k = state.q.shape[1], len(block.joints)
    raw[:, :k] = motion[:, block.joints]
    raw[:, k:] = motion[:, n + block.joints]


def motion_anchor_ori_b(state, goal, raw, block, vec, rot) -> None:
    """Writer of ``motion_anchor_ori_b`` (module docstring): ``raw`` (envs, 6); the block's
    joints are the waist's yaw, roll and pitch joints; the base as
    :func:`anchor_base_orientation` gives it."""
    motion = _motion(state, block)
    n = state.q.shape[1]
    torso = torso_quat(anchor_base_orientation(state), state.q[:, block.joints])
    raw[:] = anchor_ori_b(torso, motion[:, 2 * n : 2 * n + 4])


def motion_phase(state, goal, raw, block, vec, rot) -> None:
    """Writer of ``motion_phase`` (module docstring): ``raw`` (envs, 1) ``t / T``."""
    t = getattr(state, "motion_time", None)
    if t is None:
        raise MotionBlockError(
            f"observation: block '{block.kind.name}' needs the runtime's motion clock "
            "(RobotState.motion_time)"
        )
    raw[:, 0] = np.asarray(t, float) / block.period
