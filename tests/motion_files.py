"""rl_sar's dance_102 folder and unitree_mujoco's G1, copied out of their checkouts for the motion
tests (fan-ziqi/rl_sar at e384912: ``policy/g1/whole_body_tracking/dance_102`` and
``policy/g1/base.yaml``; unitreerobotics/unitree_mujoco ``unitree_robots/g1``), through the
``stacks`` fixture (:mod:`tests.stacks`: ``SIM2REAL_STACKS``); tests that need them skip, naming
that variable, without it."""

from __future__ import annotations

from pathlib import Path

from tests.stacks import Stacks

DANCE = "policy/g1/whole_body_tracking/dance_102"
FILES = (
    "policy/g1/base.yaml",
    f"{DANCE}/config.yaml",
    f"{DANCE}/policy.pt",
    f"{DANCE}/G1_Take_102.bvh_60hz.csv",
)
CLIP = "G1_Take_102.bvh_60hz.csv"
#: robot-import's robot-level flags for unitree_mujoco's g1_29dof.xml (motors by the G1's catalog)
G1_FLAGS = [
    "--floating-base", "--foot", "left_ankle_roll_link", "--foot", "right_ankle_roll_link",
    "--imu", "imu", "--unitree", "unitree_hg", "--unitree-damping-kd", "8",
    "--motor", "*=g1_5020", "--motor", "*_hip_pitch_joint=g1_7520_14",
    "--motor", "*_hip_yaw_joint=g1_7520_14", "--motor", "waist_yaw_joint=g1_7520_14",
    "--motor", "*_hip_roll_joint=g1_7520_22", "--motor", "*_knee_joint=g1_7520_22",
    "--motor", "*_ankle_*_joint=g1_5020_x2", "--motor", "waist_roll_joint=g1_5020_x2",
    "--motor", "waist_pitch_joint=g1_5020_x2", "--motor", "*_wrist_pitch_joint=g1_4010",
    "--motor", "*_wrist_yaw_joint=g1_4010",
]  # fmt: skip


def dance_folder(stacks: Stacks, root: Path) -> Path:
    """rl_sar's ``policy/`` tree with dance_102 and g1's base.yaml under ``root``; returns the
    dance folder. Skips without rl_sar's checkout."""
    for name in FILES:
        out = root / name
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(stacks.read("rl_sar", name))
    return root / DANCE


def g1_xml(stacks: Stacks, root: Path) -> Path:
    """unitree_mujoco's ``unitree_robots/g1`` under ``root``; returns ``g1_29dof.xml``. Skips
    without unitree_mujoco's checkout."""
    stacks.copy("unitree_mujoco", ["unitree_robots/g1"], root)
    return root / "unitree_robots" / "g1" / "g1_29dof.xml"
