"""A small rl_sar whole-body-tracking folder written the way rl_sar ships its G1 dances
(fan-ziqi/rl_sar e384912 ``policy/g1/base.yaml`` and ``policy/g1/whole_body_tracking/dance_102``):
``base.yaml`` under the robot's key, ``config.yaml`` under the nested key
``g1/whole_body_tracking/<name>``, the actor saved by ``torch.jit.save``, and a clip CSV of root
position, root quaternion x y z w and the 29 joints in ``base.yaml``'s ``joint_names`` order, one
frame a line. The values are made up (a seeded linear actor, a smooth clip); the layout, keys and
sizes are rl_sar's, so the readers run on CI without rl_sar's checkout (:mod:`tests.stacks`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

#: The G1's 29 joints in unitree's motor order (rl_sar's ``policy/g1/base.yaml`` ``joint_names``).
G1_JOINTS = [
    f"{side}_{j}_joint"
    for side in ("left", "right")
    for j in ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll")
] + ["waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint"] + [
    f"{side}_{j}_joint"
    for side in ("left", "right")
    for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "wrist_roll",
              "wrist_pitch", "wrist_yaw")
]  # fmt: skip
#: dance_102's ``joint_mapping`` (its policy's joint order, as unitree motor indices).
MAPPING = [0, 6, 12, 1, 7, 13, 2, 8, 14, 3, 9, 15, 22, 4, 10, 16, 23, 5, 11, 17, 24, 18, 25, 19,
           26, 20, 27, 21, 28]  # fmt: skip
#: dance_102's observation terms, 154 values for 29 joints.
TERMS = ["whole_body_tracking/motion_command", "whole_body_tracking/motion_anchor_ori_b",
         "ang_vel", "dof_pos", "dof_vel", "actions"]  # fmt: skip
CLIP = "clip_60hz.csv"


def write_g1_base(robot: Path, default_dof_pos: list, **extra) -> None:
    """rl_sar's ``policy/g1/base.yaml`` in ``robot`` (the ``g1`` folder): the G1's 29 joints in
    their own order, at ``default_dof_pos``; ``extra``: keys added (as rl_sar's base files carry
    ``joint_controller_names``)."""
    n = len(G1_JOINTS)
    base = {
        "dt": 0.005,
        "decimation": 4,
        "fixed_kp": [100.0] * n,
        "fixed_kd": [2.0] * n,
        "num_of_dofs": n,
        "wheel_indices": [],
        "torque_limits": [300.0] * n,
        "default_dof_pos": default_dof_pos,
        "joint_names": G1_JOINTS,
        **extra,
        "joint_mapping": list(range(n)),
    }
    (robot / "base.yaml").write_text(yaml.safe_dump({"g1": base}, sort_keys=False))


def write_tracking_folder(root: Path, name: str = "dance_small", frames: int = 181) -> Path:
    """rl_sar's ``policy/`` tree under ``root`` with ``g1/base.yaml`` and the tracking folder
    ``g1/whole_body_tracking/<name>`` (config.yaml, policy.pt, the clip); returns that folder."""
    import torch

    n = len(G1_JOINTS)
    robot = root / "policy" / "g1"
    folder = robot / "whole_body_tracking" / name
    folder.mkdir(parents=True, exist_ok=True)
    write_g1_base(
        robot,
        [0.0] * n,
        joint_controller_names=[j.replace("_joint", "_controller") for j in G1_JOINTS],
    )
    config = {
        "model_name": "policy.pt",
        "num_observations": 58 + 6 + 3 + 3 * n,
        "observations": TERMS,
        "observations_history": [],
        "observations_history_priority": "time",
        "clip_obs": 100.0,
        "clip_actions_lower": [-100.0] * n,
        "clip_actions_upper": [100.0] * n,
        "rl_kp": [40.0] * n,
        "rl_kd": [2.5] * n,
        "fixed_kp": [40.0] * n,
        "fixed_kd": [2.5] * n,
        "num_of_dofs": n,
        "action_scale": [0.25] * n,
        "wheel_indices": [],
        "lin_vel_scale": 1.0,
        "ang_vel_scale": 1.0,
        "dof_pos_scale": 1.0,
        "dof_vel_scale": 1.0,
        "commands_scale": [1.0, 1.0, 1.0],
        "torque_limits": [88.0] * n,
        "default_dof_pos": [0.1 if "knee" in j else 0.0 for j in G1_JOINTS],
        "joint_mapping": MAPPING,
        "waist_joint_indices": [12, 13, 14],
        "motion_file": CLIP,
    }
    key = f"g1/whole_body_tracking/{name}"
    (folder / "config.yaml").write_text(yaml.safe_dump({key: config}, sort_keys=False))
    torch.manual_seed(0)
    actor = torch.nn.Sequential(torch.nn.Linear(config["num_observations"], n), torch.nn.Tanh())
    torch.jit.save(torch.jit.script(actor.eval()), str(folder / "policy.pt"))
    t = np.arange(frames)[:, None] / 60.0
    joints = 0.2 * np.sin(2.0 * t + np.linspace(0.0, 3.0, n))
    half = 0.1 * np.sin(t)
    root_pos = np.hstack([0.05 * t, 0.0 * t, 0.78 + 0.0 * t])
    quat_xyzw = np.hstack([0.0 * t, 0.0 * t, np.sin(half), np.cos(half)])
    rows = np.hstack([root_pos, quat_xyzw, joints])
    (folder / CLIP).write_text("\n".join(",".join(f"{v:.6f}" for v in r) for r in rows) + "\n")
    return folder
