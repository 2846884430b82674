"""rl_sar's policy folder as a policy's contract (sim2real/deploy/spec/foreign/rl_sar.py), built
from its own layout: ``policy/go2w/base.yaml`` (key ``go2w``) and
``policy/go2w/robot_lab/config.yaml`` (key ``go2w/robot_lab``) beside the policy, the values of
fan-ziqi/rl_sar's Go2-W files (its order FR, FL, RR, RL and wheels named ``*_foot_joint``), on
sim2real/robots/go2w (order FL, FR, RL, RR, wheels ``*_wheel_joint``; the motor slots of its
``[unitree]`` table join the two)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from sim2real.deploy.cli.deploy_run import deploy_run_main
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.robots import load_robot
from tests import foreign_stacks as fs

LEGS = ("FR", "FL", "RR", "RL")
NAMES = [f"{leg}_{p}_joint" for leg in LEGS for p in ("hip", "thigh", "calf")]
NAMES += [f"{leg}_foot_joint" for leg in LEGS]
DEFAULT = [0.0, 0.5, -1.5] * 2 + [0.0, 0.8, -1.5] * 2 + [0.0] * 4
SCALE = [0.125, 0.25, 0.25] * 4 + [5.0] * 4
WHEELS = [12, 13, 14, 15]


def base_yaml() -> dict:
    return {
        "go2w": {
            "dt": 0.005,
            "decimation": 4,
            "num_of_dofs": 16,
            "wheel_indices": WHEELS,
            "torque_limits": [23.5] * 16,
            "default_dof_pos": [0.0, 0.8, -1.5] * 4 + [0.0] * 4,
            "joint_names": NAMES,
            "joint_mapping": list(range(16)),
        }
    }


def config_yaml(**changes) -> dict:
    cfg = {
        "model_name": "policy.pt",
        "num_observations": 57,
        "observations": ["ang_vel", "gravity_vec", "commands", "dof_pos", "dof_vel", "actions"],
        "observations_history": [],
        "observations_history_priority": "time",
        "clip_obs": 100.0,
        "clip_actions_lower": [-100.0] * 16,
        "clip_actions_upper": [100.0] * 16,
        "rl_kp": [20.0] * 12 + [0.0] * 4,
        "rl_kd": [0.5] * 16,
        "num_of_dofs": 16,
        "action_scale": SCALE,
        "wheel_indices": WHEELS,
        "lin_vel_scale": 2.0,
        "ang_vel_scale": 0.25,
        "dof_pos_scale": 1.0,
        "dof_vel_scale": 0.05,
        "commands_scale": [1.0, 1.0, 1.0],
        "torque_limits": [23.5] * 16,
        "default_dof_pos": DEFAULT,
        "joint_mapping": list(range(16)),
    }
    return {"go2w/robot_lab": {**cfg, **changes}}


def write(tmp_path, obs_dim=57, bias=None, **changes):
    folder = tmp_path / "policy" / "go2w"
    (folder / "robot_lab").mkdir(parents=True)
    (folder / "base.yaml").write_text(yaml.safe_dump(base_yaml(), default_flow_style=None))
    cfg = config_yaml(**changes)
    (folder / "robot_lab" / "config.yaml").write_text(yaml.safe_dump(cfg, default_flow_style=None))
    path = folder / "robot_lab" / "policy.onnx"
    actor = fs.Actor(obs_dim, 16, 1, 1e-3, bias=bias)
    return fs._export(actor, obs_dim, path, 11, ["obs"], ["actions"])


@pytest.fixture(scope="module")
def go2w():
    return load_robot("go2w")


def robot_index(go2w) -> list[int]:
    """The robot joint of each rl_sar joint: ``*_foot_joint`` is the robot's ``*_wheel_joint``."""
    return [go2w.joint_names.index(n.replace("_foot_", "_wheel_")) for n in NAMES]


def test_rl_sar_folder_is_the_go2w_contract_wheels_by_speed_their_angle_unseen(go2w, tmp_path):
    policy = OnnxPolicy(write(tmp_path), go2w)
    assert policy.foreign.format == "rl_sar"
    spec, idx = policy.spec, robot_index(go2w)
    assert spec.control_rate == pytest.approx(50.0)
    wheel = np.zeros(16, bool)
    wheel[[idx[i] for i in WHEELS]] = True
    assert list(spec.drive.kinds) == ["velocity" if w else "position" for w in wheel]
    np.testing.assert_allclose(np.array(spec.drive.kp)[idx], [20.0] * 12 + [0.0] * 4)
    np.testing.assert_allclose(np.array(spec.drive.default_pose)[idx], DEFAULT)

    rng = np.random.default_rng(0)
    state = RobotState.legged(1, 16, go2w.n_feet)
    state.q[:] = rng.uniform(-0.3, 0.3, (1, 16))
    state.q[0, wheel] = [40.0, -7.0, 123.0, 3.0]  # wheels turned many times over
    state.dq[:] = rng.uniform(-3, 3, (1, 16))
    state.last_action[:] = rng.uniform(-1, 1, (1, 16))
    state.base.angular_velocity[:] = [[0.3, -0.2, 0.7]]
    g = np.array([0.1, -0.05, -1.0])
    state.base.projected_gravity[:] = g / np.linalg.norm(g)
    state.command[:] = [[1.0, 0.0, 0.2]]
    dof_pos = state.q[0, idx] - DEFAULT
    dof_pos[WHEELS] = 0.0  # rl_sar's ComputeObservation: wheel_indices read 0
    expected = np.concatenate(
        [
            0.25 * state.base.angular_velocity[0],
            state.base.projected_gravity[0],
            state.command[0],
            dof_pos,
            0.05 * state.dq[0, idx],
            state.last_action[0, idx],
        ]
    )
    obs = spec.observation(state, np.zeros((1, 3)))[0]
    np.testing.assert_allclose(obs, expected, rtol=0, atol=2e-6)

    action = rng.uniform(-2, 2, (1, 16))  # in the graph's (rl_sar's) order
    ours = np.zeros((1, 16))
    ours[0, idx] = action[0]
    target = spec.action_to_target(ours, state)[0]
    expected = np.array(DEFAULT) + np.array(SCALE) * action[0]
    expected[WHEELS] = 5.0 * action[0, WHEELS]  # rad/s about 0
    np.testing.assert_allclose(target[idx], expected, atol=1e-12)


def test_rl_sar_history_and_clip_are_read_or_refused_in_one_line(go2w, tmp_path):
    policy = OnnxPolicy(write(tmp_path / "a", obs_dim=57 * 3, observations_history=[0, 1, 2]), go2w)
    h = policy.spec.history
    assert (h.length, h.order, h.layout) == (3, "newest_first", "per_frame")
    with pytest.raises(PolicyLoadError, match="clip_actions_lower"):
        OnnxPolicy(write(tmp_path / "b", clip_actions_lower=[-1.0] * 16), go2w)
    with pytest.raises(PolicyLoadError, match="observations_history"):
        OnnxPolicy(write(tmp_path / "c", observations_history=[0, 2]), go2w)


@pytest.mark.parametrize(
    "key, value", [("dt", 0), ("dt", 0.0), ("dt", -0.005), ("decimation", 0), ("decimation", -4)]
)
def test_a_control_period_of_zero_or_below_is_refused_naming_the_file_and_key(
    tmp_path, capsys, key, value
):
    """``dt`` x ``decimation`` is the control period and its inverse the rate: 0 was a
    ZeroDivisionError traceback and exit 1 (a hard violation's code), a negative one a spec error
    naming neither file nor key; now one line naming config.yaml and the key, exit code 3."""
    path = write(tmp_path, **{key: value})
    args = ["--robot", "go2w", "--policy", str(path), "--backend", "sim", "--duration", "0.1"]
    code = deploy_run_main(args)
    err = capsys.readouterr().err
    assert code == 3, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert f"config.yaml: '{key}': expected" in lines[0] and "> 0" in lines[0], lines[0]
    assert f"got {value!r}" in lines[0], lines[0]


def test_deploy_run_rolls_the_go2w_on_its_wheels_speed_targets_from_the_rl_sar_folder(
    tmp_path, capsys
):
    """No --spec: deploy-run reads the rl_sar folder; a policy holding its legs at the default
    pose and asking every wheel for 1.0 x 5 = 5 rad/s rolls the robot on (a wheel as a position
    drive would stop 5 rad on: 0.43 m
    on go2w.xml's 0.086 m wheels), its wheels past any angle without a violation."""
    bias = [0.0] * 12 + [1.0] * 4  # rl_sar's order: legs, then the wheels FR, FL, RR, RL
    path = write(tmp_path, bias=bias)
    report = tmp_path / "run.json"
    args = ["--robot", "go2w", "--policy", str(path), "--backend", "sim", "--duration", "6"]
    args += ["--command", "0,0,0", "--heading-hold", "0", "--report", str(report)]
    code = deploy_run_main(args)
    err = capsys.readouterr().err
    assert code == 0, err
    assert "rl_sar policy: spec built from" in err
    run = json.loads(report.read_text())
    assert run["violations"]["any"] == 0 and run["locomotion"]["falls"] == 0
    assert run["locomotion"]["distance_m"] > 1.0


def test_the_shipped_go2w_is_the_drive_rl_sars_contract_runs(go2w, tmp_path):
    """robots/go2w's wheels are what rl_sar's config.yaml drives (``rl_kp`` 0, ``rl_kd`` 0.5 on its
    ``wheel_indices``: speed targets), its legs kp 20, kd 0.5: the policy runs the robot as shipped,
    no drive of its own laid over robot.toml's."""
    from sim2real.deploy.spec.drive import drive_differences, drive_robot

    spec = OnnxPolicy(write(tmp_path), go2w).spec
    assert drive_differences(spec.drive, go2w) == {}
    assert drive_robot(go2w, spec)[0] is go2w
    wheels = [go2w.joint_names.index(n.replace("_foot_", "_wheel_")) for n in NAMES[12:]]
    assert np.flatnonzero(go2w.velocity_driven).tolist() == sorted(wheels)
    joints = go2w.config.joints
    assert [joints[i].kp for i in wheels] == [0.0] * 4
    assert [joints[i].kd for i in wheels] == [0.5] * 4
