"""The fourth built-in robot kind, a legged robot carrying an arm (``legged_arm``,
:mod:`sim2real.deploy.kinds.legged_arm`): go2 with a two-joint arm on its back, built here (MJCF
and robot.toml), run through deploy-run and a short soak with a constant policy that stands on
the legs' home pose and drives the arm past its range. Its legs' PD targets pass unbounded, its
arm's targets are clamped to the arm's soft limits: what no flag of a kind could say."""

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from onnx import helper

from sim2real.deploy.cli.deploy_run import deploy_run_main
from sim2real.deploy.spec.policy_spec import PolicySpec
from tests.runtime_fixtures import linear_onnx

REPO = Path(__file__).resolve().parent.parent

#: The arm on go2's back: a yaw shoulder and a pitch elbow, light links that touch nothing
#: (contype 0), each joint's range +-0.2 rad (soft +-0.18 rad): the policy's 0.19 rad (an action
#: of 0.76 at the legged action scale 0.25) lies between.
ARM_MJCF = """
      <body name="arm_link1" pos="0.1 0 0.1">
        <joint name="arm_shoulder" axis="0 0 1" range="-0.2 0.2" armature="0.01" />
        <inertial pos="0 0 0.04" mass="0.3" diaginertia="0.0003 0.0003 0.0001" />
        <geom name="arm_link1" type="box" size="0.02 0.02 0.04" pos="0 0 0.04" contype="0" conaffinity="0" />
        <body name="arm_link2" pos="0 0 0.08">
          <joint name="arm_elbow" axis="0 1 0" range="-0.2 0.2" armature="0.01" />
          <inertial pos="0.06 0 0" mass="0.2" diaginertia="0.0001 0.0004 0.0004" />
          <geom name="arm_link2" type="box" size="0.06 0.015 0.015" pos="0.06 0 0" contype="0" conaffinity="0" />
        </body>
      </body>"""

ARM_JOINT = """
[[joints]]
name = "{name}"
position_limit = [-0.2, 0.2]
velocity_limit = 10.0
acceleration_limit = 100.0
jerk_limit = 2000.0
effort_limit = 23.7
soft_limit_fraction = 0.9
motor = "go_m8010_6"
kp = 60.0
kd = 1.5
"""


def legged_arm_robot(folder: Path) -> Path:
    """go2 with the arm (``ARM_MJCF``, ``ARM_JOINT``) in ``folder``, robot.toml naming the kind
    ``legged_arm``; returns the folder."""
    shutil.copytree(REPO / "sim2real" / "robots" / "go2", folder)
    xml = folder / "go2.xml"
    text = xml.read_text()
    after_legs = '      <body name="imu" pos="-0.02557 0 0.04232">'  # the joints in order
    assert after_legs in text
    xml.write_text(text.replace(after_legs, ARM_MJCF.lstrip("\n") + "\n" + after_legs, 1))
    toml = folder / "robot.toml"
    text = toml.read_text()
    text = text[: text.index("# deploy-run --backend unitree")]  # the Unitree slots: 12 motors
    text = text.replace('name = "go2"', 'name = "go2_arm"\nkind = "legged_arm"', 1)
    text = re.sub(r"(home = \[[^\]]*)\]", r"\1, 0.0, 0.0]", text, count=1)
    joints = "".join(ARM_JOINT.format(name=n) for n in ("arm_shoulder", "arm_elbow"))
    text = text.replace("\n[sensors]", joints + "\n[sensors]", 1)
    toml.write_text(text)
    return folder


@pytest.fixture(scope="module")
def go2_arm(tmp_path_factory):
    """``(folder, robot, policy)``: the robot and a constant policy: the legs at home (action
    0), the arm's joints at 0.76 (0.19 rad asked: past their soft limit, inside the hard one)."""
    from sim2real.robots import load_robot

    tmp = tmp_path_factory.mktemp("legged_arm")
    folder = legged_arm_robot(tmp / "go2_arm")
    robot = load_robot(str(folder))
    spec = PolicySpec.for_robot(robot, mode="position")
    bias = np.zeros((1, spec.act_dim), np.float32)
    bias[0, -2:] = 0.76  # the arm's joints, last in robot.toml
    nodes = [
        helper.make_node("MatMul", ["obs", "w"], ["zero"]),
        helper.make_node("Add", ["zero", "bias"], ["action"]),
    ]
    weights = {"w": np.zeros((spec.obs_dim, spec.act_dim), np.float32), "bias": bias}
    policy = linear_onnx(spec, tmp / "go2_arm.onnx", nodes, weights, name="go2_arm")
    return folder, robot, policy


def test_its_legs_take_pd_targets_and_its_arm_commanded_ones(go2_arm):
    from sim2real.deploy.kinds import LEGGED_ARM, robot_kind
    from sim2real.deploy.kinds.legged_arm import leg_joints
    from sim2real.deploy.safety.guard import SafetyGuard

    _, robot, _ = go2_arm
    assert robot_kind(robot) is LEGGED_ARM
    legs = leg_joints(robot)
    assert legs.sum() == 12 and not legs[-2:].any()  # go2's legs; the arm on no foot's chain
    guard = SafetyGuard(robot, 1, "position")
    assert np.array_equal(guard.targets.pd, legs)
    # a leg's target is unbounded (a torque request), an arm's bounded by its hard limits
    assert np.isinf(guard._target_lower[legs]).all()
    assert np.isfinite(guard._target_lower[~legs]).all()
    assert guard.envelope is None  # a moving base: no certified motion
    # the guard's position-mode filter: the arm's target clamped into its soft limits, the
    # legs' passed unchanged (a legged robot's every joint would pass)
    target = robot.home[None, :].copy()
    target[0, legs] += 0.05
    target[0, -2:] = 0.19  # past the soft limit (0.18), inside the hard one (0.2)
    state = LEGGED_ARM.state(robot, 1)
    state.q[:] = robot.home
    out = guard.filter(target.copy(), state)
    assert np.allclose(out[0, -2:], robot.soft_upper[-2:])
    assert np.allclose(out[0, legs], target[0, legs])
    assert not guard.hard_violation.any()
    # past a hard limit: a leg's target passes (the PD barrier judges its motion), an arm's
    # target there is a hard violation (the runtime's safe stop), as an arm's is
    past = robot.home[None, :].copy()
    past[0, 1] = robot.position_upper[1] + 0.3
    guard.filter(past, state)
    assert not guard.hard_violation.any()
    past[0, -1] = robot.position_upper[-1] + 0.3
    guard.filter(past, state)
    assert guard.hard_violation.all()


def test_robot_toml_legged_arm_needs_an_arm(tmp_path):
    from sim2real.deploy.kinds import robot_kind
    from sim2real.robots import load_robot

    folder = tmp_path / "go2"
    shutil.copytree(REPO / "sim2real" / "robots" / "go2", folder)
    toml = folder / "robot.toml"
    toml.write_text(toml.read_text().replace('name = "go2"', 'name = "go2"\nkind = "legged_arm"'))
    with pytest.raises(ValueError, match=r"kind = 'legged_arm' needs an arm"):
        robot_kind(load_robot(str(folder)))


def test_a_legged_arm_runs_in_deploy_run_and_its_arm_is_held_in_its_range(go2_arm, tmp_path):
    folder, robot, policy = go2_arm
    report = tmp_path / "run.json"
    argv = ["--backend", "sim", "--robot", str(folder), "--policy", str(policy)]
    argv += ["--command", "0,0,0", "--duration", "3", "--report", str(report)]
    assert deploy_run_main(argv) == 0
    run = json.loads(report.read_text())
    assert run["estimation"] is not None  # a legged robot's base estimate, judged
    assert run["locomotion"] is not None
    # the arm asked past its soft limit every tick: the soft-limit check clamped it
    assert run["interventions"]["checks"]["soft_limit"]["count"] > 0, run["interventions"]
    assert run["exit_code"] == 0 and run["faults"]["safe_stops"] == 0


def test_a_short_legged_arm_soak_reports_a_verdict(go2_arm, tmp_path):
    from sim2real.eval.cli import main

    folder, _, policy = go2_arm
    out = tmp_path / "soak"
    argv = ["--robot", str(folder), "--policy", str(policy), "--hours", "0.01"]
    argv += ["--sessions", "1", "--seed", "0", "--out", str(out), "--no-progress", "--no-film"]
    argv += ["--fault-interval", "6"]  # 36 s with faults in it (a push and a dropout)
    code = main(argv)
    report = json.loads((out / "report.json").read_text())
    assert report["exit_code"] == code and isinstance(report["passed"], bool)  # a verdict
    s = report["sessions"][0]
    assert s["status"] == "complete" and s["simulated_s"] == pytest.approx(36.0)
    assert s["locomotion"] is not None  # a legged robot's session: falls, tracking
    events = s["faults"]["events"]
    assert events and all(e["kind"] != "cable" for e in events)  # its soak world's faults
    assert s["base_estimate"]["ticks"] > 0  # a legged robot's base estimate, judged
    # its arm clamped into its soft limits every tick, as in deploy-run; its legs never stopped
    assert s["interventions"]["checks"]["soft_limit"]["count"] == s["interventions"]["ticks"]
    assert s["interventions"]["checks"]["hard_limit"]["count"] == 0
