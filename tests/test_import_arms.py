"""Every fixed-base arm of example-robot-data that robot-import accepts runs through deploy-run
(the adversarial policy, a few seconds, the goal sampler included); the descriptions it refuses
are refused in one line. The six arms of tests/test_importer.py (ARMS: so100, so101, ur5,
panda, z1, kinova) run there, 60 s each, under stricter checks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim2real.deploy.cli.deploy_run import deploy_run_main
from sim2real.deploy.cli.robot_import import main
from sim2real.deploy.tasks.goals import sample_goal
from sim2real.robots import load_robot
from sim2real.robots.importer.pipeline import EXIT_REFUSED, import_robot
from tests.import_fixtures import ERD, require_example_robot_data
from tests.runtime_fixtures import adversarial_onnx

require_example_robot_data("double_pendulum_description/urdf/double_pendulum.urdf")

UR = ["*=ec90flat_hd101", "wrist_*=ec45flat_hd101"]
PANDA = ["*=ec90flat_hd101", "panda_joint[5-7]=ec45flat_hd101"]
DP = "double_pendulum_description/urdf/"
#: (name, URDF, SRDF or None, --motor, --limit, why it cannot hold itself up or None).
ACCEPTED = [
    ("double_pendulum", DP + "double_pendulum.urdf", None, ["*=xm430_w350"], ["*=-3.1:3.1"], None),
    ("dp_simple", DP + "double_pendulum_simple.urdf", None, ["*=xm430_w350"], ["*=-3.1:3.1"], None),
    (
        "dp_continuous",
        DP + "double_pendulum_continuous.urdf",
        None,
        ["*=xm430_w350"],
        ["joint*=-3.1:3.1"],
        None,
    ),
    (
        "xarm7",
        "xarm_description/urdf/xarm7.urdf",
        "xarm_description/srdf/xarm7.srdf",
        ["*=ec45flat_hd101"],
        [],
        None,
    ),
    ("ur3", "ur_description/urdf/ur3_robot.urdf", None, UR, [], None),
    (
        "ur3_gripper",
        "ur_description/urdf/ur3_gripper.urdf",
        "ur_description/srdf/ur3_gripper.srdf",
        UR,
        [],
        None,
    ),
    (
        "ur5_gripper",
        "ur_description/urdf/ur5_gripper.urdf",
        "ur_description/srdf/ur5_gripper.srdf",
        UR,
        [],
        None,
    ),
    (
        "ur5_joint_limited",
        "ur_description/urdf/ur5_joint_limited_robot.urdf",
        "ur_description/srdf/ur5_joint_limited_robot.srdf",
        UR,
        [],
        None,
    ),
    (
        "panda_collision",
        "panda_description/urdf/panda_collision.urdf",
        "panda_description/srdf/panda.srdf",
        PANDA,
        [],
        None,
    ),
    (
        "ur10",
        "ur_description/urdf/ur10_robot.urdf",
        None,
        UR,
        [],
        "its shoulder needs the URDF's 330 N m; the catalog's largest motor gives 150 N m",
    ),
    (
        "baxter",
        "baxter_description/urdf/baxter.urdf",
        "baxter_description/srdf/baxter_manipulation.srdf",
        ["*=ec90flat_hd101", "*_w?=ec45flat_hd101"],
        [],
        "the URDF's 50 N m at s1 cannot hold an arm held out (the real Baxter's springs do)",
    ),
]
#: (URDF, extra flags, what the one-line refusal names): descriptions the importer refuses.
REFUSED = [
    ("finger_edu_description/robots/finger_edu.urdf", [], "zero inertia"),
    ("allegro_hand_description/urdf/allegro_right_hand.urdf", [], "several legs leave the root"),
    ("tiago_description/robots/tiago.urdf", [], "'wheel_right_joint' type='continuous'"),
    (
        "tiago_description/robots/tiago.urdf",
        ["--limit", "*=-3:3"],
        "MuJoCo's URDF compiler refuses it: Error: error 'inertia must have positive eigenvalues'",
    ),
    ("asr_twodof_description/urdf/TwoDofs.urdf", [], "MuJoCo and Pinocchio disagree"),
]


@pytest.mark.parametrize(
    "name,urdf,srdf,motors,limits,sags", ACCEPTED, ids=[a[0] for a in ACCEPTED]
)
def test_an_accepted_arm_runs_through_deploy_run(tmp_path, name, urdf, srdf, motors, limits, sags):
    out = tmp_path / name
    import_robot(
        ERD + urdf,
        out,
        srdf=ERD + srdf if srdf else None,
        motors=motors,
        limits=limits,
        log=lambda *a: None,
    )
    robot = load_robot(out)
    task = robot.config.task
    rng = np.random.default_rng(0)
    goals = np.array([sample_goal(robot, rng) for _ in range(20)])
    assert np.all((goals >= task.box_min) & (goals <= task.box_max))

    report = tmp_path / "run.json"
    policy = adversarial_onnx(tmp_path, robot, "position")
    code = deploy_run_main(
        ["--robot", str(out), "--policy", str(policy), "--duration", "3", "--report", str(report)]
    )
    run = json.loads(report.read_text())
    violated = {k for k, v in run["violations"]["by_type"].items() if v}
    if sags is None:
        assert code == 0 and not violated & {"hard_limit", "velocity", "self_collision"}, run
    else:  # the arm sinks below its workspace under gravity; nothing else fails
        assert code == 1 and violated <= {"workspace", "soft_limit"}, (sags, run)


@pytest.mark.parametrize(
    "urdf,flags,expected", REFUSED, ids=[f"{r[0].split('/')[0]}{len(r[1])}" for r in REFUSED]
)
def test_a_refused_description_is_one_line(tmp_path, capsys, urdf, flags, expected):
    out = tmp_path / "out"
    code = main([ERD + urdf, "--out", str(out), "--motor", "*=ec45flat_hd101", *flags])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_REFUSED and "\n" not in err and expected in err, err
    assert not out.exists()


def test_a_joint_at_its_servos_no_load_speed_is_not_carried_past_it(tmp_path):
    """The double pendulum with catalog Dynamixels, its velocity limit the servos' no-load speed
    (the URDF gives none), under the uniform adversarial policy in position mode for 40 s: the
    shoulder's commands stay where its motor still holds the arm against gravity
    (sim2real.robots.chain_bounds.holding_command_limit), so gravity never carries it past its
    no-load speed behind a command it could not follow (0 true velocity ticks)."""
    from sim2real.robots.chain_bounds import holding_speed

    out = tmp_path / "double_pendulum"
    import_robot(
        ERD + DP + "double_pendulum.urdf",
        out,
        motors=["*=xm430_w350"],
        limits=["*=-3.1:3.1"],
        log=lambda *a: None,
    )
    robot = load_robot(out)
    assert robot.velocity_limit.tolist() == [4.82, 4.82]
    assert robot.command_velocity_limit[0] == holding_speed(robot)[0] < 4.0
    report = tmp_path / "run.json"
    policy = adversarial_onnx(tmp_path, robot, "position", nan_probability=0.02)
    deploy_run_main(
        ["--robot", str(out), "--policy", str(policy), "--duration", "40", "--seed", "0"]
        + ["--report", str(report)]
    )
    run = json.loads(report.read_text())
    assert run["violations"]["by_type"]["velocity"] == 0, run["violations"]
