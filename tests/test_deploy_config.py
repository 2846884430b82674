"""``policy-export --from-config``: a legged_gym / unitree_rl_gym deploy config (YAML) becomes the
PolicySpec, and the observation it describes is the one unitree_rl_gym's
``deploy/deploy_mujoco/deploy_mujoco.py`` builds.

The config is written the way unitree_rl_gym's ``deploy/deploy_mujoco/configs/<robot>.yaml`` are
(kps, kds, default_angles in the MJCF's joint order, the scales, num_actions, num_obs, the
control decimation and physics step, cmd_init), here for the shipped go2 (its joint order, its
kp 20 / kd 0.5 and home pose). :func:`deploy_mujoco_observation` is our numpy re-implementation
of deploy_mujoco's formula; the spec's observation must equal it.
"""

from __future__ import annotations

import copy
import shutil
from functools import partial
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from helpers_policies import LeggedGymLstm, folder
from torch import nn

from sim2real.deploy.cli.policy_export import main
from sim2real.deploy.core.attitude import projected_gravity
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.export.deploy_config import GAIT_PERIOD, spec_and_robot
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.policy.onnx_spec import spec_differences
from sim2real.deploy.spec.reference import observation_reference
from sim2real.robots import load_robot

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:FutureWarning")
REPO = Path(__file__).resolve().parent.parent
GO2 = REPO / "sim2real" / "robots" / "go2"


def go2_config(go2, **changes) -> dict:
    """A deploy config for go2 as unitree_rl_gym writes one (their go2/h1 values)."""
    n = go2.n_joints
    cfg = {
        "policy_path": "{LEGGED_GYM_ROOT_DIR}/deploy/pre_train/go2/motion.pt",
        "xml_path": "{LEGGED_GYM_ROOT_DIR}/resources/robots/go2/scene.xml",
        "simulation_duration": 60.0,
        "simulation_dt": 0.002,
        "control_decimation": 10,
        "kps": [20] * n,
        "kds": [0.5] * n,
        "default_angles": [float(a) for a in go2.home],
        "ang_vel_scale": 0.25,
        "dof_pos_scale": 1.0,
        "dof_vel_scale": 0.05,
        "action_scale": 0.25,
        "cmd_scale": [2.0, 2.0, 0.25],
        "num_actions": n,
        "num_obs": 9 + 3 * n + 2,
        "cmd_init": [0.5, 0, 0],
    }
    cfg.update(changes)
    return cfg


def write_config(path: Path, cfg: dict) -> Path:
    path.write_text(yaml.safe_dump(cfg))
    return path


def deploy_mujoco_observation(cfg: dict, qj, dqj, quat, omega, cmd, action, t) -> np.ndarray:
    """deploy_mujoco.py's observation, re-implemented from its formula (float32 (num_obs,)):
    qj, dqj = qpos[7:], qvel[6:]; quat = qpos[3:7] (w, x, y, z); omega = qvel[3:6] (base
    frame); t = counter * simulation_dt."""
    n = cfg["num_actions"]
    qw, qx, qy, qz = quat
    gravity = np.array(
        [2 * (-qz * qx + qw * qy), -2 * (qz * qy + qw * qx), 1 - 2 * (qw * qw + qz * qz)]
    )
    phase = t % 0.8 / 0.8
    obs = np.zeros(cfg["num_obs"], dtype=np.float32)
    obs[:3] = omega * cfg["ang_vel_scale"]
    obs[3:6] = gravity
    obs[6:9] = cmd * np.array(cfg["cmd_scale"], dtype=np.float32)
    obs[9 : 9 + n] = (qj - np.array(cfg["default_angles"])) * cfg["dof_pos_scale"]
    obs[9 + n : 9 + 2 * n] = dqj * cfg["dof_vel_scale"]
    obs[9 + 2 * n : 9 + 3 * n] = action
    obs[9 + 3 * n : 9 + 3 * n + 2] = np.array(
        [np.sin(2 * np.pi * phase), np.cos(2 * np.pi * phase)]
    )
    return obs


def random_states(go2, rng, count: int):
    """(state, deploy_mujoco's inputs) pairs: the same robot state in both forms."""
    n = go2.n_joints
    for _ in range(count):
        qj = rng.uniform(go2.position_lower, go2.position_upper)
        dqj = rng.normal(0.0, 5.0, n)
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        omega = rng.normal(0.0, 2.0, 3)
        cmd = rng.uniform(-1.0, 1.0, 3)
        action = rng.normal(0.0, 2.0, n)
        t = rng.uniform(0.0, 120.0)
        state = RobotState.legged(1, n, go2.n_feet)
        state.q[0], state.dq[0], state.last_action[0] = qj, dqj, action
        state.base.orientation[0] = quat
        state.base.projected_gravity[0] = projected_gravity(quat)  # the estimator's convention
        state.base.angular_velocity[0] = omega
        state.command[0], state.clock[0] = cmd, t
        yield state, (qj, dqj, quat, omega, cmd, action, t)


def test_the_spec_from_a_config_computes_deploy_mujocos_observation(go2, tmp_path):
    cfg = go2_config(go2)
    spec, robot, notes = spec_and_robot(write_config(tmp_path / "go2.yaml", cfg), go2)
    assert robot is go2 and notes == []  # gains and home as robot.toml's: nothing written
    n = go2.n_joints
    assert [(b.name, b.size) for b in spec.observation_blocks] == [
        ("base_angular_velocity", 3),
        ("projected_gravity", 3),
        ("velocity_command", 3),
        ("joint_position", n),
        ("joint_velocity", n),
        ("last_action", n),
        ("gait_phase", 2),
    ]
    b = {blk.name: blk for blk in spec.observation_blocks}
    assert b["base_angular_velocity"].scale == (4.0,) * 3
    assert b["velocity_command"].scale == (0.5, 0.5, 4.0)
    assert b["joint_position"].offset == tuple(cfg["default_angles"])
    assert b["joint_position"].joints == tuple(range(n))
    assert b["joint_velocity"].scale == (20.0,) * n
    assert b["gait_phase"].period == GAIT_PERIOD == 0.8
    assert spec.obs_dim == cfg["num_obs"] and spec.joint_names == go2.joint_names
    a = spec.action
    assert (a.mode, a.scale, a.offset) == ("position", (0.25,) * n, tuple(cfg["default_angles"]))
    assert spec.control_rate == 50.0 and spec.robot_hash == ""
    assert spec.plan.compiled  # every block runs in the compiled kernel
    rng = np.random.default_rng(11)
    for state, inputs in random_states(go2, rng, 200):
        theirs = deploy_mujoco_observation(cfg, *inputs)
        for observe in (spec.observation, partial(observation_reference, spec)):
            ours = observe(state, np.zeros((1, 3)))[0]
            np.testing.assert_allclose(ours, theirs, rtol=2e-6, atol=2e-6)


def mlp_policy(obs_dim: int, act_dim: int) -> nn.Module:
    torch.manual_seed(5)
    net = nn.Sequential(nn.Linear(obs_dim, 64), nn.ELU(), nn.Linear(64, act_dim))
    with torch.no_grad():
        for p in net.parameters():
            p.mul_(0.1)
    return net.eval()


class LstmPolicy(LeggedGymLstm):
    """legged_gym's PolicyExporterLSTM layout (``export_policy_as_jit``): an LSTM ``memory``
    whose state lives in the ``hidden_state``/``cell_state`` buffers, then an ``actor`` MLP."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int = 16):
        torch.manual_seed(6)
        memory = nn.LSTM(obs_dim, hidden)
        actor = nn.Sequential(nn.Linear(hidden, 32), nn.ELU(), nn.Linear(32, act_dim))
        super().__init__(memory, actor)


@pytest.mark.parametrize("kind", ["mlp", "lstm"])
def test_policy_export_from_config_stores_that_spec_and_acts_like_the_source(
    go2, tmp_path, capsys, kind
):
    cfg = go2_config(go2)
    config = write_config(tmp_path / "go2.yaml", cfg)
    n, d = go2.n_joints, cfg["num_obs"]
    net = mlp_policy(d, n) if kind == "mlp" else LstmPolicy(d, n)
    src = tmp_path / "motion.pt"
    torch.jit.script(copy.deepcopy(net)).save(str(src))
    out = tmp_path / "motion.onnx"
    code = main([str(src), "--from-config", str(config), "--robot", str(GO2), "--out", str(out)])
    stdout, stderr = capsys.readouterr()
    assert code == 0, stderr
    assert f"spec from {config}" in stdout and "--command 0.5,0,0" in stdout
    policy = OnnxPolicy(out, go2)
    expected, _, _ = spec_and_robot(config, go2)
    assert spec_differences(policy.spec, expected) == []
    # deploy_mujoco's observation through the ONNX policy: the source's action
    scripted = torch.jit.load(str(src))
    policy.reset(np.ones(1, dtype=bool))
    for state, inputs in random_states(go2, np.random.default_rng(2), 20):
        theirs = deploy_mujoco_observation(cfg, *inputs)[None]
        ours = policy.spec.observation(state, np.zeros((1, 3)))
        with torch.no_grad():
            action = scripted(torch.from_numpy(theirs)).numpy()
        np.testing.assert_allclose(policy(ours), action, rtol=0, atol=1e-4)


def _refused(tmp_path, capsys, args: list[str]) -> str:
    before = folder(tmp_path)
    assert main(args) == 2
    assert folder(tmp_path) == before  # nothing written
    return capsys.readouterr().err


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"num_actions": 10}, "field 'num_actions': expected a list|field 'kps': expected a list"),
        ({"num_obs": 48}, "field 'num_obs': expected 47 (deploy_mujoco's layout"),
        ({"kps": None}, "field 'kps': expected a list of 12 positive numbers, got None"),
        ({"cmd_scale": [2.0, 2.0]}, "field 'cmd_scale': expected a list of 3 positive numbers"),
        ({"dof_vel_scale": "0.05"}, "field 'dof_vel_scale': expected a number > 0"),
        ({"control_decimation": 4}, "a control rate of 125 Hz, the robot 'go2'"),
        ({"default_angles": [0.0] * 12}, "'default_angles'[2] = 0 rad is outside the limits"),
    ],
)
def test_a_config_that_does_not_fit_is_refused_naming_the_field(
    go2, tmp_path, capsys, changes, message
):
    cfg = go2_config(go2, **changes)
    config = write_config(tmp_path / "go2.yaml", cfg)
    src = tmp_path / "motion.pt"
    torch.jit.script(mlp_policy(47, 12)).save(str(src))
    err = _refused(tmp_path, capsys, [str(src), "--from-config", str(config), "--robot", str(GO2)])
    assert str(config) in err
    assert any(m in err for m in message.split("|")), err


def test_a_config_for_another_joint_count_is_refused(go2, tmp_path, capsys):
    cfg = go2_config(go2, num_actions=10, num_obs=41)
    for key in ("kps", "kds", "default_angles"):
        cfg[key] = cfg[key][:10]
    config = write_config(tmp_path / "h1.yaml", cfg)
    src = tmp_path / "motion.pt"
    torch.jit.script(mlp_policy(41, 10)).save(str(src))
    err = _refused(tmp_path, capsys, [str(src), "--from-config", str(config), "--robot", str(GO2)])
    assert "field 'num_actions': 10 joints, the robot 'go2'" in err and "has 12" in err


def test_flags_that_do_not_go_together_are_refused(go2, tmp_path, capsys):
    config = write_config(tmp_path / "go2.yaml", go2_config(go2))
    src = tmp_path / "motion.pt"
    torch.jit.script(mlp_policy(47, 12)).save(str(src))
    spec = tmp_path / "spec.json"
    spec.write_text("{}")
    base = [str(src), "--from-config", str(config)]
    assert "needs --robot DIR" in _refused(tmp_path, capsys, base)
    assert "pass one of them" in _refused(
        tmp_path, capsys, [*base, "--robot", str(GO2), "--spec", str(spec)]
    )
    assert "--write-robot goes with --from-config" in _refused(
        tmp_path, capsys, [str(src), "--spec", str(spec), "--write-robot"]
    )


@pytest.fixture
def go2_copy(tmp_path) -> Path:
    """A copy of the shipped go2 folder to rewrite."""
    dst = tmp_path / "robots" / "go2"
    shutil.copytree(GO2, dst)
    return dst


def test_gains_that_differ_are_refused_and_written_with_write_robot(
    go2, go2_copy, tmp_path, capsys
):
    n = go2.n_joints
    kps = [20.0] * n
    kps[2] = 40.0  # FL_calf_joint
    home = [float(a) for a in go2.home]
    home[0] = 0.05
    cfg = go2_config(go2, kps=kps, default_angles=home)
    config = write_config(tmp_path / "go2.yaml", cfg)
    src = tmp_path / "motion.pt"
    torch.jit.script(mlp_policy(47, 12)).save(str(src))
    toml = go2_copy / "robot.toml"
    before = toml.read_text()
    err = _refused(
        tmp_path, capsys, [str(src), "--from-config", str(config), "--robot", str(go2_copy)]
    )
    assert "FL_hip_joint home 0.1 in robot.toml, 0.05 wanted" in err
    assert "FL_calf_joint kp 20 in robot.toml, 40 wanted" in err and "--write-robot" in err
    assert toml.read_text() == before

    spec, robot, notes = spec_and_robot(config, go2_copy, write_robot=True)
    assert notes == [f"wrote home, kp of 2 joint(s) into {toml} from go2.yaml"]
    again = load_robot(go2_copy)
    assert [j.kp for j in again.config.joints] == kps
    assert [j.kd for j in again.config.joints] == [0.5] * n
    np.testing.assert_array_equal(again.home, home)
    np.testing.assert_array_equal(robot.home, home)
    assert spec.joint_names == again.joint_names
    changed = [
        (a, b)
        for a, b in zip(before.splitlines(), toml.read_text().splitlines(), strict=True)
        if a != b
    ]
    assert len(changed) == 2  # the home line and FL_calf_joint's kp; every other line kept
    assert all("go2.yaml (policy-export --from-config --write-robot)" in b for _, b in changed)
    # written once: the same config now fits
    assert spec_and_robot(config, go2_copy)[2] == []


def deploy_real_config(go2, **changes) -> dict:
    """unitree_rl_gym's hardware config form (deploy_real/configs/g1.yaml): ``control_dt``, the
    policy's joints as motor slots (``leg_joint2motor_idx``) and the held ones (``arm_waist_*``),
    here a policy over the Go2's front legs (Unitree slots 0-5: FR, then FL) holding the rear."""
    slots, held = [0, 1, 2, 3, 4, 5], [6, 7, 8, 9, 10, 11]
    joint_of = {s: i for i, s in enumerate(go2.config.unitree.motor_index)}
    cfg = {
        "control_dt": 0.02,
        "msg_type": "go",
        "leg_joint2motor_idx": slots,
        "kps": [20] * 6,
        "kds": [0.5] * 6,
        "default_angles": [float(go2.home[joint_of[s]]) for s in slots],
        "arm_waist_joint2motor_idx": held,
        "arm_waist_kps": [20] * 6,
        "arm_waist_kds": [0.5] * 6,
        "arm_waist_target": [float(go2.home[joint_of[s]]) for s in held],
        "ang_vel_scale": 0.25,
        "dof_pos_scale": 1.0,
        "dof_vel_scale": 0.05,
        "action_scale": 0.25,
        "cmd_scale": [2.0, 2.0, 0.25],
        "num_actions": 6,
        "num_obs": 9 + 3 * 6 + 2,
        "max_cmd": [0.8, 0.5, 1.57],
    }
    cfg.update(changes)
    return cfg


def test_a_hardware_config_names_the_policys_joints_by_motor_slot_and_holds_the_rest(go2, tmp_path):
    """deploy_real's form: the spec's joints are the Go2 joints of slots 0-5 in slot order (FR
    hip, thigh, calf, then FL), the rate is control_dt's, and the held joints' gains and target
    are checked like the policy's: a different arm_waist_target is refused, naming the joint."""
    path = write_config(tmp_path / "real.yaml", deploy_real_config(go2))
    spec, _, notes = spec_and_robot(path, go2)
    assert notes == []
    assert spec.joint_names == (
        "FR_hip_joint",
        "FR_thigh_joint",
        "FR_calf_joint",
        "FL_hip_joint",
        "FL_thigh_joint",
        "FL_calf_joint",
    )
    assert spec.control_rate == pytest.approx(50.0)
    wide = spec.on_robot(go2)
    assert wide.joint_names == go2.joint_names and wide.obs_dim == spec.obs_dim
    cfg = deploy_real_config(go2)
    cfg["arm_waist_target"][0] += 0.1  # slot 6: RR_hip_joint
    with pytest.raises(Exception, match="RR_hip_joint home"):
        spec_and_robot(write_config(tmp_path / "other.yaml", cfg), go2)


def test_a_config_over_part_of_the_robot_without_motor_slots_is_refused_naming_the_field(
    go2, tmp_path
):
    cfg = go2_config(go2, num_actions=6, num_obs=9 + 18 + 2)
    for key in ("kps", "kds", "default_angles"):
        cfg[key] = cfg[key][:6]
    with pytest.raises(Exception, match="leg_joint2motor_idx"):
        spec_and_robot(write_config(tmp_path / "six.yaml", cfg), go2)
