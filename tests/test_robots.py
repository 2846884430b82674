"""robots.load_robot: validation, MuJoCo/Pinocchio agreement and clear errors."""

import dataclasses
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from sim2real.robots import RobotSpecError, load_robot
from sim2real.robots.loading import ROBOTS_DIR


@pytest.fixture
def arm3_copy(tmp_path: Path) -> Path:
    dst = tmp_path / "arm3"
    shutil.copytree(ROBOTS_DIR / "arm3", dst)
    return dst


def edit(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text()
    assert old in text, f"fixture text {old!r} not in {path}"
    path.write_text(text.replace(old, new, count))


def test_arm3_matches_the_seed_arm():
    arm = load_robot("arm3")
    assert arm.joint_names == ("shoulder", "elbow", "wrist")
    np.testing.assert_allclose(arm.position_lower, -1.57)
    np.testing.assert_allclose(arm.position_upper, 1.57)
    np.testing.assert_allclose(arm.velocity_limit, 3.14)
    np.testing.assert_allclose(arm.soft_upper, 0.9 * 1.57)
    assert arm.decimation == 5 and arm.control_period == pytest.approx(0.005)
    # stretched out along +X, three 0.3 m links, in a vertical plane with gravity along -Y
    np.testing.assert_allclose(arm.forward_kinematics(np.zeros(3)), [0.9, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(arm.forward_kinematics([np.pi / 2, 0, 0]), [0, 0.9, 0], atol=1e-3)
    np.testing.assert_allclose(arm.mj_model.opt.gravity, [0, -9.81, 0])
    # gravity loads every joint when stretched out horizontally, the shoulder most
    g = arm.gravity_torque(np.zeros(3))
    assert g[0] > g[1] > g[2] > 0


def test_arm3_motor_can_hold_the_arm_stretched_out():
    arm = load_robot("arm3")
    g = np.abs(arm.gravity_torque(np.zeros(3)))
    continuous = np.array([m.continuous_torque for m in arm.motors])
    assert np.all(g < continuous), (g, continuous)
    assert np.all(g < arm.effort_limit)
    assert all("maxon" in m.source for m in arm.motors)


def test_pinocchio_limits_come_from_robot_toml():
    arm = load_robot("arm3")
    np.testing.assert_array_equal(arm.pin_model.velocityLimit, arm.velocity_limit)
    np.testing.assert_array_equal(arm.pin_model.effortLimit, arm.effort_limit)
    np.testing.assert_array_equal(arm.pin_model.lowerPositionLimit, arm.position_lower)


def test_robot_is_frozen_and_its_arrays_read_only():
    arm = load_robot("arm3")
    with pytest.raises(dataclasses.FrozenInstanceError):
        arm.name = "other"
    with pytest.raises(ValueError):
        arm.position_upper[0] = 3.0


def test_load_by_folder_and_by_file(arm3_copy):
    assert load_robot(arm3_copy).name == "arm3"
    assert load_robot(arm3_copy / "robot.toml").n_joints == 3


def test_description_hash_changes_with_the_description(arm3_copy):
    before = load_robot(arm3_copy).description_hash
    assert before == load_robot("arm3").description_hash
    edit(arm3_copy / "robot.toml", "jerk_limit = 400.0", "jerk_limit = 300.0")
    assert load_robot(arm3_copy).description_hash != before


def test_plant_models_per_control_mode():
    arm = load_robot("arm3")
    for mode in ("position", "velocity", "torque"):
        m = arm.plant_model(mode)
        assert m.nu == 3 * arm.actuators_per_joint(mode)
        assert m.opt.disableflags & 65536  # mjDSBL_AUTORESET
        # the total actuator torque on each joint is limited to the effort limit
        assert m.jnt_actfrclimited.all()
        np.testing.assert_allclose(m.jnt_actfrcrange[:, 1], arm.effort_limit)
        np.testing.assert_allclose(m.jnt_actfrcrange[:, 0], -arm.effort_limit)
    with pytest.raises(RobotSpecError, match="control mode 'force' is unknown"):
        arm.mjspec("force")


@pytest.mark.parametrize(
    ("file", "old", "new", "pattern"),
    [
        (
            "arm3.xml",
            'angle="radian"',
            'angle="degree"',
            r"arm3\.xml: <compiler angle=\.\.\.> is 'degree'; expected angle=\"radian\"",
        ),
        (
            "arm3.xml",
            '<compiler angle="radian" autolimits="true"/>',
            "",
            r"arm3\.xml: <compiler angle=\.\.\.> is None",
        ),
        (
            "arm3.xml",
            '<joint name="wrist"/>',
            '<joint name="hand"/>',
            r"robot\.toml: field 'joints': names \['shoulder', 'elbow', 'wrist'\] differ from the MJCF joints \['shoulder', 'elbow', 'hand'\]",
        ),
        (
            "robot.toml",
            "velocity_limit = 3.14\n",
            "velocity_limit = -3.14\n",
            r"robot\.toml: field 'joints\[0\]\.velocity_limit': Input should be greater than 0 \(got -3\.14\)",
        ),
        (
            "robot.toml",
            "effort_limit = 22.5\n",
            "effort_limit = 0.0\n",
            r"field 'joints\[0\]\.effort_limit': Input should be greater than 0",
        ),
        (
            "robot.toml",
            "jerk_limit = 400.0\n",
            "",
            r"robot\.toml: field 'joints\[0\]\.jerk_limit': missing \(required\)",
        ),
        (
            "robot.toml",
            'mode = "velocity"',
            'mode = "impedance"',
            r"field 'control\.mode': Input should be 'position', 'velocity' or 'torque' \(got 'impedance'\)",
        ),
        (
            "robot.toml",
            'motor = "ec45flat70_gp42c"\n',
            'motor = "nema17"\n',
            r"joints\[0\]\.motor' \(joint 'shoulder'\): motor 'nema17' is neither a \[motors\.nema17\] "
            r"table in robot.toml nor a model of the catalog",
        ),
        (
            "robot.toml",
            "position_limit = [-1.57, 1.57]\n",
            "position_limit = [-1.5, 1.57]\n",
            r"field 'joints\[0\]\.position_limit' = \[-1\.5, 1\.57\] differs from the MJCF range of joint 'shoulder'",
        ),
        (
            "robot.toml",
            "control_rate = 200.0",
            "control_rate = 300.0",
            r"field 'control\.control_rate' = 300\.0 Hz is not an integer fraction",
        ),
        (
            "robot.toml",
            "home = [0.0, 0.5, 0.5]",
            "home = [0.0, 0.5]",
            r"control\.home has 2 values, expected one per joint \(3\)",
        ),
        (
            "robot.toml",
            'end_effector_site = "ee"',
            'end_effector_site = "tool"',
            r"field 'safety\.end_effector_site' = 'tool' is not a site",
        ),
        (
            "robot.toml",
            "[task]",
            "bogus = 1\n[task]",
            r"field 'safety\.bogus': Extra inputs are not permitted",
        ),
        (
            "robot.toml",
            'region = "planar_annulus"',
            'region = "planar_annulus"\njoint_fraction = 0.7',
            r"joint_fraction applies to region 'box', not 'planar_annulus'",
        ),
    ],
)
def test_bad_descriptions_name_file_and_field(arm3_copy, file, old, new, pattern):
    edit(arm3_copy / file, old, new)
    with pytest.raises(RobotSpecError, match=pattern) as info:
        load_robot(arm3_copy)
    assert str(arm3_copy) in str(info.value)


def test_invalid_toml_and_unknown_robot(arm3_copy):
    edit(arm3_copy / "robot.toml", 'name = "arm3"', 'name = "arm3')
    with pytest.raises(RobotSpecError, match=r"robot\.toml: not valid TOML"):
        load_robot(arm3_copy)
    with pytest.raises(RobotSpecError, match=re.escape("not a shipped robot (known: ['arm3'")):
        load_robot("arm99")


def test_disagreeing_dynamics_are_caught(arm3_copy):
    # Without an explicit <inertial>, MuJoCo derives the wrist link's mass from its geoms while
    # Pinocchio's MJCF parser does not: the two models would simulate different robots.
    text = (arm3_copy / "arm3.xml").read_text()
    lines = [ln for ln in text.splitlines() if not ("<inertial" in ln and "0.0528409091" in ln)]
    (arm3_copy / "arm3.xml").write_text("\n".join(lines))
    with pytest.raises(RobotSpecError, match=r"MuJoCo and Pinocchio disagree .* gravity torque"):
        load_robot(arm3_copy)


def test_arm6_is_a_ur5e_class_arm():
    arm = load_robot("arm6")
    assert arm.n_joints == 6
    assert arm.joint_names[0] == "shoulder_pan" and arm.joint_names[-1] == "wrist_3"
    np.testing.assert_allclose(arm.velocity_limit, np.pi)  # UR5e datasheet: 180 deg/s
    np.testing.assert_allclose(arm.effort_limit, [150, 150, 150, 28, 28, 28])
    assert arm.decimation == 2  # 500 Hz control on 1 kHz physics
    # UR5e reach: the flange of the stretched arm is d/a-sum away from the shoulder
    q = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    reach = np.linalg.norm(arm.forward_kinematics(q)[:2])
    assert 0.8 < reach < 0.95
    g = np.abs(arm.gravity_torque(arm.home))
    assert np.all(g < [m.continuous_torque for m in arm.motors])


def test_description_hash_ignores_the_task_region_and_comments(arm3_copy):
    """A policy stays valid when only where goals come from, or a comment, changes."""
    before = load_robot(arm3_copy).description_hash
    edit(arm3_copy / "robot.toml", "success_radius = 0.05", "success_radius = 0.02  # tighter")
    edit(arm3_copy / "robot.toml", "radius = [0.47, 0.85]", "radius = [0.5, 0.8]")
    # how sure the guard is of the link lengths is the guard's business, not the policy's
    edit(arm3_copy / "robot.toml", "link_length_tolerance = 0.10", "link_length_tolerance = 0.05")
    assert load_robot(arm3_copy).description_hash == before


# ---------------------------------------------------------------- motor catalog
#: Description hashes shipped policies record; moving the motors into sim2real/robots/motors/ keeps them.
SHIPPED_HASHES = {
    # the box's far faces moved from 0.92 to 1.0 m, past every arm within the link-length
    # tolerance (the shipped arm3 checkpoints were re-saved with this hash)
    "arm3": "a3b83fc44000adcd8a665ff63c585c97d2b0e390326e81bcb2d547de5245b4d1",
    "arm6": "a43fa5b5d3c5bf8666ef549744f7cf8ef0706d6d14d484d78c73015254c1384d",
}


@pytest.mark.parametrize("name", sorted(SHIPPED_HASHES))
def test_description_hash_unchanged_by_the_motor_catalog(name):
    assert load_robot(name).description_hash == SHIPPED_HASHES[name]


def test_every_catalog_motor_validates():
    from sim2real.robots.loading import load_motor, motor_catalog

    names = set(motor_catalog())
    assert {"sts3215", "xm430_w350", "xl430_w250", "go_m8010_6", "ec45flat70_gp42c"} <= names
    for name in names:
        assert len(load_motor(name).source) > 10


def test_unknown_motor_names_robot_toml_joint_and_catalog(tmp_path):
    import shutil

    shutil.copytree(ROBOTS_DIR / "arm3", tmp_path / "arm3")
    toml = tmp_path / "arm3" / "robot.toml"
    toml.write_text(toml.read_text().replace('motor = "ec45flat70_gp42c"', 'motor = "nope"', 1))
    with pytest.raises(
        RobotSpecError, match=r"robot.toml: field 'joints\[0\].motor' \(joint 'shoulder'\).*motors"
    ):
        load_robot(toml)


@pytest.mark.parametrize("name", ["so101", "ur5"])
def test_imported_robots_ship_and_load(name):
    robot = load_robot(name)
    assert robot.n_joints == 6 and robot.control_mode == "position"


def test_so101_goals_are_reachable_inside_its_task_box():
    """so101's [task] joint_fraction: every goal lies in the box and inverse kinematics within
    the soft limits reaches it (a uniform box goal is 3 cm or more from every such pose 4 % of
    the time: a miss that says nothing about a policy)."""
    from scipy.optimize import least_squares

    from sim2real.deploy.tasks.goals import sample_goal

    so101 = load_robot("so101")
    task = so101.config.task
    rng = np.random.default_rng(3)
    for _ in range(30):
        goal = sample_goal(so101, rng)
        assert (goal >= task.box_min).all() and (goal <= task.box_max).all()
        best = min(
            np.linalg.norm(
                least_squares(
                    lambda q, g=goal: so101.forward_kinematics(q) - g,
                    start,
                    bounds=(so101.soft_lower, so101.soft_upper),
                ).fun
            )
            for start in (so101.home, rng.uniform(so101.soft_lower, so101.soft_upper))
        )
        assert best < 0.2 * task.success_radius, goal


def test_an_end_effector_site_named_like_its_body_loads(tmp_path):
    """A site named like the body it sits on (published MJCFs do this: ``pelvis`` on ``pelvis``)
    is Pinocchio's OP_FRAME beside the body's BODY frame: the site's frame is found by type, not
    refused with Pinocchio's "Several frames match the filter"."""
    import pinocchio as pin

    from sim2real.robots.loading import load_robot

    shutil.copytree(ROBOTS_DIR / "arm3", tmp_path / "arm3")
    for name in ("arm3.xml", "robot.toml"):
        path = tmp_path / "arm3" / name
        text = path.read_text()
        text = text.replace('<site name="ee"', '<site name="link3"')
        text = text.replace('end_effector_site = "ee"', 'end_effector_site = "link3"')
        path.write_text(text)
    robot = load_robot(tmp_path / "arm3")
    frame = robot.pin_model.frames[robot.ee_frame_id]
    assert frame.name == "link3" and frame.type == pin.FrameType.OP_FRAME
    np.testing.assert_allclose(robot.forward_kinematics(np.zeros(3)), [0.9, 0.0, 0.0], atol=0.05)


def test_a_servo_is_commanded_no_faster_than_its_motor_holds_the_joint_against_gravity():
    """A servo commanded faster than its motor's torque-speed line still holds the joint up
    falls behind, then gravity and the full drive carry the joint past its no-load speed: the
    command velocity limit of a fixed base's joint with a no-load speed is the speed where its
    line gives the worst gravity torque, and a joint that gravity does not load (so101's pan, a
    vertical axis) or whose motor has no no-load speed (arm3) keeps the soft velocity limit."""
    from sim2real.robots.chain_bounds import gravity_bound, holding_speed
    from sim2real.robots.torque_speed import TorqueSpeedEnvelope

    so101 = load_robot("so101")
    bound = gravity_bound(so101)
    rng = np.random.default_rng(0)
    for q in rng.uniform(so101.position_lower, so101.position_upper, (300, so101.n_joints)):
        assert np.all(np.abs(so101.gravity_torque(q)) <= bound + 1e-9)
    assert bound[0] < 1e-5 and np.all(bound[1:3] > 0.1)  # the pan: rounding of its axis
    held = holding_speed(so101)
    cold = np.full(so101.n_joints, 25.0)
    upper = TorqueSpeedEnvelope(so101.motors).limits(held, so101.effort_limit, cold)[1]
    np.testing.assert_allclose(upper[1:3], bound[1:3], rtol=0.01)  # on the line at that speed
    np.testing.assert_allclose(
        so101.command_velocity_limit, np.minimum(so101.soft_velocity_limit, held)
    )
    assert np.all(so101.command_velocity_limit[1:3] < so101.soft_velocity_limit[1:3])
    assert so101.command_velocity_limit[0] == so101.soft_velocity_limit[0]
    arm3 = load_robot("arm3")
    np.testing.assert_array_equal(arm3.command_velocity_limit, arm3.soft_velocity_limit)
