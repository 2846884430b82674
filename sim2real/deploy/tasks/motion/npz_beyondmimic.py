"""BeyondMimic's motion NPZ (HybridRobotics/whole_body_tracking) read into a :class:`MotionClip`.

Its ``scripts/csv_to_npz.py`` replays a CSV clip (root xyz, root quaternion x y z w, joints) in
Isaac Lab at ``--output_fps`` (default 50: joints lerped, the root slerped from the CSV's
``--input_fps``) and saves, per frame, what the articulation reports:

- ``fps``: ``[output_fps]``;
- ``joint_pos``, ``joint_vel``: (T, J) in the **articulation's joint order** (``robot.data``;
  ``joint_vel`` is ``torch.gradient`` of the resampled joints), rad, rad/s;
- ``body_pos_w``, ``body_quat_w`` (and ``body_lin_vel_w``, ``body_ang_vel_w``): (T, B, ...) for
  **every body of the articulation** in its body order, quaternions Isaac Lab's ``w x y z``; body 0
  is the articulation's root (the pelvis), whose pose the replay wrote.

The archive names neither joints nor bodies. The joint names come from the policy beside it (its
ONNX metadata ``joint_names``, Isaac Lab's ``robot.data.joint_names``: the same articulation order)
or, for the G1, :data:`BEYONDMIMIC_G1_JOINTS`; they are never assumed. Its ``MotionLoader``
(``tasks/tracking/mdp/commands.py``) reads these keys as they are, one frame per policy step.
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

KEYS = ("fps", "joint_pos", "joint_vel", "body_pos_w", "body_quat_w")

#: Isaac Lab's joint order of BeyondMimic's G1 (``robots/g1.py`` ``G1_CYLINDER_CFG``, 29 dof), as
#: its policies list their joints: rl_sar's BeyondMimic-trained ``whole_body_tracking/dance_102``
#: (``joint_mapping`` into ``policy/g1/base.yaml``'s ``joint_names``, fan-ziqi/rl_sar e384912).
BEYONDMIMIC_G1_JOINTS = tuple(
    f"{name}_joint"
    for name in (
        *("left_hip_pitch", "right_hip_pitch", "waist_yaw", "left_hip_roll", "right_hip_roll"),
        *("waist_roll", "left_hip_yaw", "right_hip_yaw", "waist_pitch", "left_knee"),
        *("right_knee", "left_shoulder_pitch", "right_shoulder_pitch", "left_ankle_pitch"),
        *("right_ankle_pitch", "left_shoulder_roll", "right_shoulder_roll", "left_ankle_roll"),
        *("right_ankle_roll", "left_shoulder_yaw", "right_shoulder_yaw", "left_elbow"),
        *("right_elbow", "left_wrist_roll", "right_wrist_roll", "left_wrist_pitch"),
        *("right_wrist_pitch", "left_wrist_yaw", "right_wrist_yaw"),
    )
)


def read_beyondmimic_npz(
    path,
    joint_names: Sequence[str],
    robot_joints: Sequence[str] | None = None,
    body_names: Sequence[str] | None = None,
) -> MotionClip:
    """The clip of BeyondMimic's motion NPZ at ``path``.

    Args:
        path: the ``.npz`` written by ``csv_to_npz.py``.
        joint_names: (J,) the joint of each ``joint_pos`` column (the articulation's order).
        robot_joints: the robot's joints in the order the clip should carry them (each one
            must have a column, and no column may name another joint); None keeps the file's.
        body_names: (B,) the articulation's bodies, body 0 the root; None: the clip carries no
            bodies (the root pose is read from body 0 either way).

    Returns:
        A :class:`MotionClip` at the file's ``fps``: ``joint_pos``/``joint_vel`` (T, J) rad,
        rad/s; ``root_pos`` (T, 3) m and ``root_quat`` (T, 4) ``w x y z`` of body 0.

    Raises:
        ClipError: one line naming the file and field: a missing key, an ``fps`` that is not a
            positive number, a column count other than ``len(joint_names)``, a robot joint
            without a column, quaternions that are not unit, shapes that disagree.
    """
    path = Path(path)
    data = load_npz(path, KEYS, "BeyondMimic")
    fps = read_fps(path, data["fps"])
    names = read_names(path, "joint_names", np.asarray(list(joint_names), dtype=str))
    what = f"one column per joint_names entry, {len(names)}"
    joint_pos = columns(path, "joint_pos", data["joint_pos"], len(names), what)
    joint_vel = columns(path, "joint_vel", data["joint_vel"], len(names), what)
    body_pos = np.asarray(data["body_pos_w"], dtype=float)
    body_quat = np.asarray(data["body_quat_w"], dtype=float)
    frames = joint_pos.shape[0]
    if body_pos.ndim != 3 or body_pos.shape[0] != frames or body_pos.shape[2] != 3:
        raise ClipError(
            f"{path}: body_pos_w: expected (frames {frames}, bodies, 3), got {body_pos.shape}"
        )
    if body_quat.shape != body_pos.shape[:2] + (4,):
        raise ClipError(
            f"{path}: body_quat_w: expected {body_pos.shape[:2] + (4,)} (w x y z per body), got "
            f"{body_quat.shape}"
        )
    unit_quaternions(path, "body_quat_w", body_quat)
    order = by_robot_order(path, "joint_names", names, robot_joints)
    bodies: dict = {}
    if body_names is not None:
        bodies["body_names"] = read_names(path, "body_names", np.asarray(list(body_names), str))
        if len(bodies["body_names"]) != body_pos.shape[1]:
            raise ClipError(
                f"{path}: body_pos_w: expected {len(bodies['body_names'])} bodies (body_names), "
                f"got {body_pos.shape[1]}"
            )
        bodies |= {"body_pos_w": body_pos, "body_quat_w": body_quat}
    return MotionClip(
        source=path,
        fps=fps,
        joint_names=tuple(names[i] for i in order),
        joint_pos=joint_pos[:, order],
        joint_vel=joint_vel[:, order],
        root_pos=body_pos[:, 0],
        root_quat=body_quat[:, 0],
        **bodies,
    )
