"""A plant motors file (sim2real.robots.plant_motors): the motors as the plant simulates them, for an
emulated robot whose motors differ from its description; the robot's contract stays."""

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.robots.plant_motors import load_plant_motors
from sim2real.robots.robot import RobotSpecError
from tests.runtime_fixtures import shipped_onnx

WORN = """
source = "a worn SO-101: 0.02 N m of friction, armature x2, a 20 % weaker line, 8 ms delay"
[motors.sts3215]
command_delay = 0.008
max_velocity = 3.77
[joints."*"]
friction = 0.02
armature_scale = 2.0
[joints.gripper]
friction_scale = 0.5
"""


def test_the_file_changes_the_plant_and_not_the_contract(so101, tmp_path):
    path = tmp_path / "worn.toml"
    path.write_text(WORN)
    plant = load_plant_motors(path, so101)
    assert plant.robot.description_hash == so101.description_hash
    assert plant.robot.motors[0].max_velocity == 3.77 and so101.motors[0].max_velocity == 4.71
    nominal, worn = so101.plant_model("position"), plant.apply(so101.plant_model("position"))
    dofs = [nominal.jnt_dofadr[nominal.joint(n).id] for n in so101.joint_names]
    expected = np.full(so101.n_joints, 0.02)  # a value: the nominal SO-101 has none
    expected[so101.joint_names.index("gripper")] = 0.01  # a later table's factor multiplies
    np.testing.assert_allclose(worn.dof_frictionloss[dofs], expected)
    np.testing.assert_allclose(worn.dof_armature[dofs], 2.0 * nominal.dof_armature[dofs])
    backend = SimBackend(plant.robot, mode="position", models=[worn])
    assert (backend.actuators.delay_steps == round(0.008 / so101.physics_timestep)).all()
    np.testing.assert_allclose(backend.actuators.envelope.no_load_speed, 3.77)


@pytest.mark.parametrize(
    "text, message",
    [
        ('source = "too short"', r"field 'source'"),
        (
            'source = "a long enough source"\n[motors.xm430_w350]\nmax_velocity = 3.0',
            r"field 'motors.xm430_w350': the robot so101 uses no motor",
        ),
        (
            'source = "a long enough source"\n[motors.sts3215]\nmax_velocity = -3.0',
            r"field 'motors.sts3215.max_velocity'",
        ),
        (
            'source = "a long enough source"\n[joints."knee*"]\nfriction = 2.0',
            r"field 'joints.knee\*': matches no joint",
        ),
        (
            'source = "a long enough source"\n[joints."*"]\nstiction = 2.0',
            r"field 'joints.\*.stiction'",
        ),
    ],
)
def test_a_bad_file_names_the_file_and_the_field(so101, tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(RobotSpecError, match=rf"{path}: {message}"):
        load_plant_motors(path, so101)


def test_deploy_run_and_the_soak_run_on_the_plant_motors(so101, tmp_path):
    import json

    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.eval.soak.campaign import run_campaign
    from sim2real.eval.soak.session import SessionConfig

    onnx = str(shipped_onnx("so101", tmp_path))
    worn = tmp_path / "worn.toml"
    worn.write_text(WORN)
    report = tmp_path / "run.json"
    argv = ["--robot", "so101", "--policy", onnx, "--duration", "3", "--report", str(report)]
    assert deploy_run_main([*argv, "--plant-motors", str(worn)]) == 0
    slow = json.loads(report.read_text())
    assert deploy_run_main(argv) == 0
    nominal = json.loads(report.read_text())
    assert slow["goals"]["issued"] == nominal["goals"]["issued"]
    # the same goals on other motors: the run's motion differs (the file reached the plant)
    assert slow["max_joint_speed_rad_s"] != nominal["max_joint_speed_rad_s"]
    config = SessionConfig(robot="so101", policy=onnx, seed=0, hours=0.005, plant_motors=str(worn))
    (result,) = run_campaign(config, 1, tmp_path / "soak", progress=False)
    assert result["options"]["plant_motors"] == str(worn)


def test_the_emulated_robots_run_on_a_plant_motors_file(tmp_path):
    """The servo-bus and Unitree emulators take ``plant_motors`` (``--plant-motors``): the motors
    behind the wire protocol are the file's, which the host's description does not know."""
    from sim2real.deploy.backends.emulator.bus import ServoBusEmulator

    worn = tmp_path / "worn.toml"
    worn.write_text(WORN)
    bus = ServoBusEmulator("so101", "feetech", plant_motors=str(worn))
    assert (bus.plant.actuators.delay_steps == 4).all()
    np.testing.assert_allclose(bus.plant.models[0].dof_frictionloss[:3], 0.02)
    pytest.importorskip("cyclonedds")
    from sim2real.deploy.backends.unitree.emulator.robot import UnitreeEmulator

    legs = tmp_path / "legs.toml"
    legs.write_text(
        'source = "a Go2 with 5 ms of delay"\n[motors.go_m8010_6]\ncommand_delay = 0.005\n'
    )
    robot = UnitreeEmulator("go2", plant_motors=str(legs))
    try:
        assert robot.plant.actuators.delay_steps.max() > 0
    finally:
        robot.stop()
