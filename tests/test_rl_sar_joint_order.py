"""rl_sar's joint order read by its names, never by a fallback to the robot's joint order.

rl_sar (fan-ziqi/rl_sar e384912) gives each policy joint a motor slot (``joint_mapping``) and
names the slots (``base.yaml`` ``joint_names``, Unitree's leg order FR, FL, RR, RL); its HIMLoco
Go2 (``policy/go2/himloco/config.yaml``) reads the legs in legged_gym's order FL, FR, RL, RR
(``joint_mapping: [3, 4, 5, 0, 1, 2, 9, 10, 11, 6, 7, 8]``) with a pose that tells left from
right (hips +-0.1 rad, rear thighs 1.0 rad). unitree_mujoco's ``go2.xml`` lists its legs FL, FR,
RL, RR: imported without ``--unitree`` it has no motor slots, and the slots read as indices of
its joints would swap every left leg with its right one. The folders here carry those files'
values; the description is go2.xml's layout (tests/go2_layout.py).
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from sim2real.deploy.cli.robot_import import main as robot_import
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.robots import load_robot
from tests import foreign_stacks as fs
from tests.go2_layout import write_go2

pytest.importorskip("torch")

SLOT_NAMES = [
    f"{leg}_{p}_joint" for leg in ("FR", "FL", "RR", "RL") for p in ("hip", "thigh", "calf")
]
#: policy/go2/himloco/config.yaml: legged_gym's FL, FR, RL, RR by rl_sar's slots.
HIMLOCO_MAPPING = [3, 4, 5, 0, 1, 2, 9, 10, 11, 6, 7, 8]
HIMLOCO_DEFAULT = [0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5]
#: The same pose by joint name (legged_gym's go2 default_joint_angles).
POSE = {"FL_hip_joint": 0.1, "FR_hip_joint": -0.1, "RL_hip_joint": 0.1, "RR_hip_joint": -0.1}
POSE |= {"FL_thigh_joint": 0.8, "FR_thigh_joint": 0.8, "RL_thigh_joint": 1.0}
POSE |= {"RR_thigh_joint": 1.0} | {f"{leg}_calf_joint": -1.5 for leg in ("FL", "FR", "RL", "RR")}


def write_himloco(tmp_path, names=True, mapping=HIMLOCO_MAPPING):
    """rl_sar's ``policy/go2/base.yaml`` and ``policy/go2/himloco/config.yaml`` (their values;
    a 6-frame history of 45 entries, commands first) beside a bare ONNX graph."""
    folder = tmp_path / "policy" / "go2"
    (folder / "himloco").mkdir(parents=True)
    base = {"dt": 0.005, "decimation": 4, "num_of_dofs": 12, "wheel_indices": []}
    base |= {"default_dof_pos": [0.0, 0.8, -1.5] * 4, "joint_mapping": list(range(12))}
    if names:
        base["joint_names"] = SLOT_NAMES
    cfg = {
        "model_name": "himloco.pt",
        "num_observations": 45,
        "observations": ["commands", "ang_vel", "gravity_vec", "dof_pos", "dof_vel", "actions"],
        "observations_history": [0, 1, 2, 3, 4, 5],
        "observations_history_priority": "time",
        "clip_obs": 100.0,
        "rl_kp": [40.0] * 12,
        "rl_kd": [1.0] * 12,
        "action_scale": [0.25] * 12,
        "wheel_indices": [],
        "ang_vel_scale": 0.25,
        "dof_pos_scale": 1.0,
        "dof_vel_scale": 0.05,
        "commands_scale": [2.0, 2.0, 0.25],
        "default_dof_pos": HIMLOCO_DEFAULT,
        "joint_mapping": mapping,
    }
    (folder / "base.yaml").write_text(yaml.safe_dump({"go2": base}, default_flow_style=None))
    text = yaml.safe_dump({"go2/himloco": cfg}, default_flow_style=None)
    (folder / "himloco" / "config.yaml").write_text(text)
    actor = fs.Actor(270, 12, 1, 1e-3)
    return fs._export(actor, 270, folder / "himloco" / "policy.onnx", 11, ["obs"], ["actions"])


def driven(robot, spec) -> list[str]:
    """The robot joint each graph output drives (``action.joints`` empty: the robot's order)."""
    return [robot.joint_names[i] for i in (spec.action.joints or range(robot.n_joints))]


def import_go2(tmp_path, capsys, *flags):
    """unitree_mujoco's go2.xml layout imported without --unitree: (exit code, out, stderr)."""
    source = write_go2(tmp_path)
    out = tmp_path / "robots" / "go2"
    args = [str(source), "--out", str(out), "--floating-base", "--motor", "*=go_m8010_6"]
    code = robot_import([*args, *flags])
    return code, out, capsys.readouterr().err


def test_a_robot_without_motor_slots_takes_rl_sars_legs_by_their_names(tmp_path, capsys):
    """No motor slots on the robot: rl_sar's joint_names decide, so the home written by
    ``--drive-from`` and the spec's joint map are the legs rl_sar means (before: FR took FL's
    hip of +0.1 rad and output 0 drove FL_hip_joint)."""
    policy = write_himloco(tmp_path)
    code, out, err = import_go2(tmp_path, capsys, "--drive-from", str(policy))
    assert code == 0, err
    robot = load_robot(out)
    assert getattr(robot.config, "unitree", None) is None  # no motor slots
    home = dict(zip(robot.joint_names, np.asarray(robot.home, float), strict=True))
    assert home == pytest.approx(POSE)
    spec = OnnxPolicy(policy, robot).spec
    assert driven(robot, spec) == [SLOT_NAMES[s] for s in HIMLOCO_MAPPING]  # FL, FR, RL, RR
    pose = dict(zip(robot.joint_names, spec.drive.default_pose, strict=True))
    assert pose == pytest.approx(POSE)


def test_no_names_and_no_slots_is_refused_in_one_line(tmp_path, capsys):
    """A folder without joint_names on a robot without motor slots has no joint order: the
    importer and the runtime refuse in one line saying how to give the robot its slots."""
    policy = write_himloco(tmp_path, names=False)
    code, out, err = import_go2(tmp_path, capsys, "--drive-from", str(policy))
    assert code != 0
    line = err.strip().splitlines()[-1]
    assert "names no joints" in line and "--unitree" in line, err
    (tmp_path / "again").mkdir()
    code, out, err = import_go2(tmp_path / "again", capsys)
    assert code == 0, err
    with pytest.raises(PolicyLoadError, match="names no joints.*--unitree FAMILY"):
        OnnxPolicy(policy, load_robot(out))


def test_names_that_disagree_with_the_robots_slots_are_refused_naming_both_orders(tmp_path, capsys):
    """Imported with --unitree, the robot's slots and rl_sar's names must give the same legs;
    a mapping that the names contradict (slot 0 named FR_hip_joint, the slot table's FR...)
    is refused with both orders, and agreeing ones map as the names say."""
    (tmp_path / "a").mkdir()
    policy = write_himloco(tmp_path / "a")
    code, out, err = import_go2(
        tmp_path,
        capsys,
        "--unitree",
        "unitree_go",
        "--unitree-damping-kd",
        "1",
        "--control-rate",
        "50",
    )
    assert code == 0, err
    robot = load_robot(out)
    spec = OnnxPolicy(policy, robot).spec
    assert driven(robot, spec) == [SLOT_NAMES[s] for s in HIMLOCO_MAPPING]
    names = tmp_path / "a" / "policy" / "go2" / "base.yaml"
    doc = yaml.safe_load(names.read_text())
    doc["go2"]["joint_names"] = SLOT_NAMES[3:6] + SLOT_NAMES[:3] + SLOT_NAMES[6:]  # FL first
    names.write_text(yaml.safe_dump(doc, default_flow_style=None))
    with pytest.raises(PolicyLoadError, match="disagree: by name .* by 'go2''s motor slots"):
        OnnxPolicy(policy, robot)
