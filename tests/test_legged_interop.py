"""Acceptance for legged robots: a legged_gym-style policy exported from TorchScript with a user spec runs
on a floating-base robot with the IMU blocks.

The actor is a small seeded MLP (48 -> 128 -> 64 -> 12, ELU) whose observation is legged_gym's
go2 layout (``LeggedRobot.compute_observations``): ``base_lin_vel * 2.0``, ``base_ang_vel * 0.25``,
``projected_gravity``, ``commands[:3] * (2, 2, 0.25)``, ``(dof_pos - default) * 1.0``,
``dof_vel * 0.05``, ``actions``; its actions are position targets ``default + 0.25 * a`` clipped
at ``clip_actions`` 100. It is scripted and ``torch.jit.save``d (what legged_gym's exporter
writes), the spec is written by hand as a user would (shorthands, joints by name, no
``robot_hash``), ``policy-export`` turns the pair into an ONNX and ``deploy-run`` runs it on go2.
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
import torch
from torch import nn

from sim2real.deploy import export as export_mod
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.cli import deploy_run as cli
from sim2real.deploy.cli import policy_export
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Mode, Runtime

pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:FutureWarning")

COMMAND = (0.3, 0.0, 0.0)
#: legged_gym's go2 observation in this toolkit's terms (scale = 1 / obs_scales), the blocks
#: read from the floating base's IMU and estimator first.
IMU_BLOCKS = ("base_linear_velocity", "base_angular_velocity", "projected_gravity")


def legged_gym_actor(obs_dim: int, act_dim: int) -> nn.Module:
    """rsl_rl's ActorCritic actor shape (ELU MLP), random but seeded, weights scaled down so
    its actions stay moderate (a fraction of a unit: a few hundredths of a rad about home)."""
    torch.manual_seed(17)
    net = nn.Sequential(
        nn.Linear(obs_dim, 128),
        nn.ELU(),
        nn.Linear(128, 64),
        nn.ELU(),
        nn.Linear(64, act_dim),
    )
    with torch.no_grad():
        for p in net.parameters():
            p.mul_(0.1)
    return net.eval()


def user_spec(go2, first_block: str = "base_linear_velocity") -> dict:
    """The spec a user writes by hand for legged_gym's go2 policy: shorthands (one number for a
    scale, lists where the entries differ), joints by name, ``robot_hash`` left out."""
    names = list(go2.joint_names)
    home = [float(x) for x in go2.home]
    clip_obs = 100.0  # legged_gym normalization.clip_observations
    return {
        "format_version": 1,
        "robot": "go2",
        "joint_names": names,
        "control_rate": 50.0,
        "observation": [
            {"name": first_block, "scale": 0.5, "clip": clip_obs},  # lin_vel 2.0
            {"name": "base_angular_velocity", "scale": 4.0, "clip": clip_obs},  # ang_vel 0.25
            {"name": "projected_gravity", "clip": clip_obs},
            {"name": "velocity_command", "scale": [0.5, 0.5, 4.0], "clip": clip_obs},
            {
                "name": "joint_position",
                "joints": names,
                "offset": home,
                "scale": 1.0,
                "clip": clip_obs,
            },
            {"name": "joint_velocity", "joints": names, "scale": 20.0, "clip": clip_obs},
            {"name": "last_action", "clip": clip_obs},
        ],
        "action": {"mode": "position", "offset": home, "scale": 0.25, "clip": 100.0},
    }


@pytest.fixture(scope="module")
def exported(go2, tmp_path_factory):
    """(onnx path, policy-export's stdout) of the scripted actor with the hand-written spec."""
    folder = tmp_path_factory.mktemp("legged_gym")
    n = go2.n_joints
    obs_dim = 3 + 3 + 3 + 3 + n + n + n
    assert obs_dim == 48
    scripted = torch.jit.script(legged_gym_actor(obs_dim, n))
    source = folder / "policy_1.pt"
    torch.jit.save(scripted, str(source))
    spec_path = folder / "go2.spec.json"
    spec_path.write_text(json.dumps(user_spec(go2), indent=2))
    out = folder / "policy_1.onnx"
    return source, spec_path, out


@pytest.fixture(scope="module")
def export_run(exported):
    """policy-export run once for the module: (exit code, (stdout, stderr), onnx path)."""
    source, spec_path, out = exported
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = policy_export.main([str(source), "--spec", str(spec_path), "--robot", "go2"])
    return code, (stdout.getvalue(), stderr.getvalue()), out


def test_torchscript_policy_with_a_user_spec_exports_with_parity(go2, export_run):
    code, (stdout, stderr), out = export_run
    assert code == policy_export.EXIT_OK, stderr
    assert out.is_file()
    assert "parity: max |onnx - torch|" in stdout and "closed-loop replay" in stdout
    assert "(torchscript)" in stdout
    policy = OnnxPolicy(out, go2)
    spec = policy.spec
    assert spec.robot == "go2" and spec.robot_hash == ""  # left out: not checked
    assert spec.joint_names == tuple(go2.joint_names)
    assert tuple(b.name for b in spec.observation_blocks)[:3] == IMU_BLOCKS
    assert spec.obs_dim == 48 and spec.act_dim == 12
    np.testing.assert_allclose(spec.action.offset, go2.home)
    assert spec.action.scale == (0.25,) * 12 and spec.action.clip == 100.0
    s = spec.block_slices()
    assert s["velocity_command"] == slice(9, 12)
    parity = spec.parity
    assert parity["max_abs_error"] <= export_mod.TOLERANCE
    assert parity["replay_max_abs_error"] <= export_mod.TOLERANCE
    assert parity["samples"] >= 1000 and parity["replay_ticks"] == export_mod.REPLAY_TICKS
    assert spec.baked == {"observation_normalizer": False, "action_clip": True}


def test_exported_policy_runs_on_go2_with_the_imu_blocks(go2, export_run, tmp_path):
    code, _, out = export_run
    assert code == policy_export.EXIT_OK
    policy = OnnxPolicy(out, go2)

    # the observation the policy sees on the floating base: a runtime as deploy-run builds it
    plant = SimBackend(go2, "position", envs=1, seed=0)
    rt = Runtime(go2, policy, plant)
    rt.start()
    rt.velocity_command[:] = COMMAND
    rt.run(20)
    spec = policy.spec
    s = spec.block_slices()
    obs = spec.observation(rt.state, rt.goal)
    assert obs.shape == (1, 48) and np.isfinite(obs).all()
    # upright at the start: gravity straight down in the base frame (the attitude estimate)
    np.testing.assert_allclose(obs[0, s["projected_gravity"]], [0.0, 0.0, -1.0], atol=0.2)
    np.testing.assert_allclose(
        obs[0, s["velocity_command"]], np.array(COMMAND) / [0.5, 0.5, 4.0], atol=1e-6
    )
    # the base velocities come from the estimator (standing still-ish: small), scaled 0.5 / 4
    np.testing.assert_allclose(
        obs[0, s["base_angular_velocity"]], rt.state.base.angular_velocity[0] / 4.0, atol=1e-6
    )
    np.testing.assert_allclose(
        obs[0, s["base_linear_velocity"]], rt.state.base.linear_velocity[0] / 0.5, atol=1e-6
    )
    assert np.abs(obs[0, s["base_linear_velocity"]]).max() < 5.0
    np.testing.assert_allclose(obs[0, s["joint_position"]], rt.state.q[0] - go2.home, atol=1e-6)

    # deploy-run, the command line, end to end
    report_path = tmp_path / "run.json"
    code = cli.deploy_run_main(
        [
            "--robot",
            "go2",
            "--policy",
            str(out),
            "--command",
            ",".join(str(c) for c in COMMAND),
            "--duration",
            "2",
            "--report",
            str(report_path),
        ]
    )
    # a random policy may stumble or fall (a fault): any documented outcome but bad input
    assert code in (cli.EXIT_CLEAN, cli.EXIT_HARD_VIOLATION, cli.EXIT_FAULT), code
    report = json.loads(report_path.read_text())
    assert report["exit_code"] == code and not report["diverged"]
    assert report["goals"] is None  # a legged robot follows a velocity command
    loco = report["locomotion"]
    assert loco is not None
    for key in ("distance_m", "falls", "tracking_success", "mean_forward_speed_m_s"):
        assert key in loco
    assert loco["command"] == [list(COMMAND)]
    assert loco["distance_m"] >= 0.0 and loco["falls"] >= 0
    assert loco["running_s"] > 0.0
    modes = {m.name for m in Mode}
    assert report["final_state"] and set(report["final_state"]) <= modes
    assert report["faults"]["non_finite_actions"] == 0


def test_legged_gym_block_name_is_refused_naming_ours(go2, exported, tmp_path, capsys):
    source, _, _ = exported
    spec_path = tmp_path / "legged_gym_names.spec.json"
    spec_path.write_text(json.dumps(user_spec(go2, first_block="base_lin_vel"), indent=2))
    out = tmp_path / "refused.onnx"
    code = policy_export.main(
        [str(source), "--spec", str(spec_path), "--robot", "go2", "--out", str(out)]
    )
    err = capsys.readouterr().err
    assert code == policy_export.EXIT_BAD_INPUT
    assert str(spec_path) in err
    assert "'base_lin_vel'" in err
    assert "this toolkit calls it 'base_linear_velocity'" in err
    assert not out.exists()
