"""holosoma's whole-body-tracking motion NPZ (amazon-far/holosoma) read into a :class:`MotionClip`.

Its ``holosoma_retargeting/data_conversion/convert_data_format_mj.py`` replays a retargeted
motion in MuJoCo at ``output_fps`` and saves, per frame, the model's state:

- ``fps``: ``[output_fps]``;
- ``joint_pos``: (T, 7 + J) MuJoCo's ``qpos``: root position x y z, root quaternion **w x y z**,
  then the hinge joints in the MJCF's order; ``joint_vel``: (T, 6 + J) ``qvel`` (the joints'
  columns from ``torch.gradient`` of the resampled joints);
- ``body_pos_w``, ``body_quat_w`` (``xpos``, ``xquat``: ``w x y z``), ``body_lin_vel_w``,
  ``body_ang_vel_w``: (T, B, ...) for every body of the model, body 0 MuJoCo's ``world``;
- ``joint_names``: (J,) the hinge joints (the free joint dropped); ``body_names``: (B,);
- with an object, ``object_*`` arrays and the object's qpos/qvel removed from the joints'.

Its ``MotionLoader`` (``holosoma/managers/command/terms/wbt.py``) drops the first 7 / 6 columns,
maps joints and bodies to the robot's by name and turns the quaternions to ``x y z w`` inside.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sim2real.deploy.tasks.motion.clip import ClipError, MotionClip
from sim2real.deploy.tasks.motion.npz_fields import (
    by_robot_order,
    columns,
    load_npz,
    read_fps,
    read_names,
    unit_quaternions,
)

KEYS = ("fps", "joint_pos", "joint_vel", "body_pos_w", "body_quat_w", "joint_names", "body_names")
#: MuJoCo's body 0, fixed at the origin: not a body of the robot, dropped from the clip.
WORLD = "world"


def read_holosoma_npz(path, robot_joints: Sequence[str] | None = None) -> MotionClip:
    """The clip of holosoma's motion NPZ at ``path``, its joints and bodies named by the file.

    Args:
        path: the ``.npz`` written by ``convert_data_format_mj.py``.
        robot_joints: the robot's joints in the order the clip should carry them (each one
            must have a column, and no column may name another joint); None keeps the file's.

    Returns:
        A :class:`MotionClip` at the file's ``fps``: joints (T, J) rad and rad/s, the root from
        ``qpos`` (position m, quaternion ``w x y z``), the bodies but ``world``.

    Raises:
        ClipError: one line naming the file and field: a missing key, an ``fps`` that is not a
            positive number, ``joint_pos`` other than 7 + J columns (``joint_vel`` 6 + J), a
            robot joint without a column, quaternions that are not unit, a body count other
            than ``len(body_names)``.
    """
    path = Path(path)
    data = load_npz(path, KEYS, "holosoma")
    fps = read_fps(path, data["fps"])
    names = read_names(path, "joint_names", data["joint_names"])
    body_names = read_names(path, "body_names", data["body_names"])
    j = len(names)
    qpos = columns(
        path, "joint_pos", data["joint_pos"], 7 + j, f"root xyz, root quat w x y z, {j} joints"
    )
    qvel = columns(path, "joint_vel", data["joint_vel"], 6 + j, f"root 6, {j} joints")
    if qvel.shape[0] != qpos.shape[0]:
        raise ClipError(
            f"{path}: joint_vel: expected {qpos.shape[0]} frames (joint_pos), got {qvel.shape[0]}"
        )
    root_quat = qpos[:, 3:7]
    unit_quaternions(path, "joint_pos", root_quat)
    body_pos = np.asarray(data["body_pos_w"], dtype=float)
    body_quat = np.asarray(data["body_quat_w"], dtype=float)
    expected = (qpos.shape[0], len(body_names))
    if body_pos.shape != expected + (3,):
        raise ClipError(
            f"{path}: body_pos_w: expected {expected + (3,)} (frames, body_names), got "
            f"{body_pos.shape}"
        )
    if body_quat.shape != expected + (4,):
        raise ClipError(
            f"{path}: body_quat_w: expected {expected + (4,)} (w x y z per body), got "
            f"{body_quat.shape}"
        )
    keep = [i for i, n in enumerate(body_names) if n != WORLD]
    unit_quaternions(path, "body_quat_w", body_quat[:, keep])
    order = by_robot_order(path, "joint_names", names, robot_joints)
    return MotionClip(
        source=path,
        fps=fps,
        joint_names=tuple(names[i] for i in order),
        joint_pos=qpos[:, 7:][:, order],
        joint_vel=qvel[:, 6:][:, order],
        root_pos=qpos[:, :3],
        root_quat=root_quat,
        body_names=tuple(body_names[i] for i in keep),
        body_pos_w=body_pos[:, keep],
        body_quat_w=body_quat[:, keep],
    )
