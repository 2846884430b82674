"""rl_sar's dance_102 folder and unitree_mujoco's G1, copied out of their mirrors for the motion
tests (fan-ziqi/rl_sar at e384912: ``policy/g1/whole_body_tracking/dance_102`` and
``policy/g1/base.yaml``; unitreerobotics/unitree_mujoco ``unitree_robots/g1``). Tests that need them
skip with the reason when a mirror is absent (``SIM2REAL_RL_SAR_MIRROR``,
``SIM2REAL_UNITREE_MUJOCO_MIRROR`` point elsewhere)."""

from __future__ import annotations

import io
import os
import subprocess
import tarfile
from pathlib import Path

import pytest

RL_SAR = Path(os.environ.get("SIM2REAL_RL_SAR_MIRROR", "/work/.mirror/fan-ziqi+rl_sar/repo"))
UNITREE_MUJOCO = Path(
    os.environ.get(
        "SIM2REAL_UNITREE_MUJOCO_MIRROR", "/work/.mirror/unitreerobotics+unitree_mujoco/repo"
    )
)
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


def _git(repo: Path, *args: str) -> bytes:
    return subprocess.run(["git", "-C", str(repo), *args], check=True, capture_output=True).stdout


def dance_folder(root: Path) -> Path:
    """rl_sar's ``policy/`` tree with dance_102 and g1's base.yaml under ``root``; returns the
    dance folder. Skips without the mirror."""
    if not RL_SAR.exists():
        pytest.skip(f"rl_sar mirror absent ({RL_SAR}): set SIM2REAL_RL_SAR_MIRROR")
    for name in FILES:
        out = root / name
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(_git(RL_SAR, "show", f"HEAD:{name}"))
    return root / DANCE


def g1_xml(root: Path) -> Path:
    """unitree_mujoco's ``unitree_robots/g1`` under ``root``; returns ``g1_29dof.xml``. Skips
    without the mirror."""
    if not UNITREE_MUJOCO.exists():
        pytest.skip(f"unitree_mujoco mirror absent ({UNITREE_MUJOCO})")
    data = _git(UNITREE_MUJOCO, "archive", "HEAD", "unitree_robots/g1")
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(root, filter="data")
    return root / "unitree_robots" / "g1" / "g1_29dof.xml"
