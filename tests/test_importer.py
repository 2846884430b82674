"""robot-import: fixed-base arms of example-robot-data import, load and run the adversarial policy;
MJCF input (arm3 round trip, an MJCF MuJoCo wrote from a URDF, in degrees) does the same; every
bad input is a one-line error with exit code 3 and no output folder."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim2real.deploy.cli.acceptance import check_adversarial
from sim2real.deploy.cli.robot_import import main
from sim2real.robots import load_robot
from sim2real.robots.importer.pipeline import EXIT_REFUSED, import_robot, resolve_source
from sim2real.robots.loading import ROBOTS_DIR
from sim2real.robots.packages import package_root
from tests.import_fixtures import ERD, require_example_robot_data

require_example_robot_data("so_arm_description/urdf/so101.urdf")

#: Every fixed-base arm of example-robot-data: (name, URDF, SRDF or None, --motor flags).
ARMS = [
    ("so100", "so_arm_description/urdf/so100.urdf", None, ["*=sts3215"]),
    ("so101", "so_arm_description/urdf/so101.urdf", None, ["*=sts3215"]),
    (
        "ur5",
        "ur_description/urdf/ur5_robot.urdf",
        "ur_description/srdf/ur5.srdf",
        ["*=ec90flat_hd101", "wrist_*=ec45flat_hd101"],
    ),
    (
        "panda",
        "panda_description/urdf/panda.urdf",
        "panda_description/srdf/panda.srdf",
        ["*=ec90flat_hd101", "panda_joint[5-7]=ec45flat_hd101"],
    ),
    ("z1", "z1_description/urdf/z1.urdf", "z1_description/srdf/z1.srdf", ["*=ec45flat_hd101"]),
    (
        "kinova",
        "kinova_description/robots/kinova.urdf",
        "kinova_description/srdf/kinova.srdf",
        ["*=ec45flat_hd101"],
    ),
]


@pytest.mark.parametrize("name,urdf,srdf,motors", ARMS, ids=[a[0] for a in ARMS])
def test_arm_imports_loads_and_survives_the_adversarial_policy(tmp_path, name, urdf, srdf, motors):
    out = tmp_path / name
    report = import_robot(
        ERD + urdf, out, srdf=ERD + srdf if srdf else None, motors=motors, log=lambda *a: None
    )
    robot = load_robot(out)
    assert robot.joint_names == tuple(report.joints) or set(robot.joint_names) == set(report.joints)
    # 20 s: each arm reaches its binding limits (acceleration and jerk 1.0) and ends as at 60 s,
    # but the ur5, whose random torques heat a wrist into an over-temperature stop between 20
    # and 60 s (the acceptance's thermal branch): 60 s for it
    result = check_adversarial(robot, "position", 60.0 if name == "ur5" else 20.0, workdir=tmp_path)
    assert result.non_finite_actions > 0
    assert result.max_overshoot == 0.0
    assert result.passed, result.failures


def test_so101_limits_lowered_to_the_motor(tmp_path):
    report = import_robot(
        ERD + ARMS[1][1], tmp_path / "so101", motors=["*=sts3215"], log=lambda *a: None
    )
    lowered = {(j, q): (a, b) for j, q, a, b, _ in report.lowered}
    assert lowered[("shoulder_pan", "effort")] == (10.0, 2.94)
    assert lowered[("gripper", "velocity")] == (10.0, 4.71)


# ---------------------------------------------------------------- bad input
ARM = """<robot name="bad">
  <link name="base"><inertial><mass value="1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <link name="l1"><inertial><mass value="{mass}"/>
    <inertia ixx="{i}" iyy="{i}" izz="{i}" ixy="0" ixz="0" iyz="0"/></inertial>{geom}</link>
  <link name="l2"><inertial><mass value="1"/>
    <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="j1" type="{kind}"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    {limit}</joint>
  <joint name="{j2}" type="revolute"><parent link="l1"/><child link="l2"/><axis xyz="0 1 0"/>
    <origin xyz="0 0 0.3"/><limit lower="-1" upper="1" effort="5" velocity="2"/></joint>
</robot>"""
GOOD = dict(
    mass=1,
    i=0.01,
    geom="",
    kind="revolute",
    limit='<limit lower="-1" upper="1" effort="5" velocity="2"/>',
    j2="j2",
)


def run_cli(tmp_path, capsys, extra=(), srdf=None, **changes):
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM.format(**{**GOOD, **changes}))
    out = tmp_path / "out"
    argv = [str(urdf), "--out", str(out), *extra]
    if srdf is not None:
        (tmp_path / "arm.srdf").write_text(srdf)
        argv += ["--srdf", str(tmp_path / "arm.srdf")]
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out-")]
    return code, err


def test_good_input_imports(tmp_path, capsys):
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(ARM.format(**GOOD))
    assert main([str(urdf), "--out", str(tmp_path / "arm"), "--motor", "*=sts3215"]) == 0
    assert load_robot(tmp_path / "arm").joint_names == ("j1", "j2")


@pytest.mark.parametrize(
    "changes,expected",
    [
        (dict(kind="continuous", limit=""), r"<joint name='j1' type='continuous'>: no position"),
        (
            dict(
                geom='<collision><geometry><mesh filename="package://nope/x.stl"/></geometry>'
                "</collision>"
            ),
            r"<mesh filename='package://nope/x.stl'>: does not resolve",
        ),
        (dict(i=0.0), r"<link name='l1'><inertial> .*zero inertia"),
        (dict(mass=0.0), r"<link name='l1'><inertial> .*zero inertia"),
        (dict(j2="j1"), r"<joint name='j1'>: duplicate joint name"),
    ],
    ids=["continuous-no-limit", "mesh-uri", "zero-inertia", "zero-mass", "duplicate-joint"],
)
def test_bad_urdf_is_one_line_exit_3_and_no_folder(tmp_path, capsys, changes, expected):
    import re

    code, err = run_cli(tmp_path, capsys, ["--motor", "*=sts3215"], **changes)
    assert code == EXIT_REFUSED
    assert "\n" not in err and "arm.urdf" in err
    assert re.search(expected, err), err


def test_srdf_naming_an_unknown_link(tmp_path, capsys):
    srdf = (
        '<robot name="bad"><disable_collisions link1="base" link2="ghost" reason="Never"/></robot>'
    )
    code, err = run_cli(tmp_path, capsys, ["--motor", "*=sts3215"], srdf=srdf)
    assert code == EXIT_REFUSED and "arm.srdf" in err and "'ghost' is not in the URDF" in err


def test_motor_not_in_the_catalog(tmp_path, capsys):
    code, err = run_cli(tmp_path, capsys, ["--motor", "*=sts9999"])
    assert code == EXIT_REFUSED and "--motor '*=sts9999'" in err and "not in the catalog" in err


def test_joint_without_a_motor(tmp_path, capsys):
    code, err = run_cli(tmp_path, capsys, ["--motor", "j1=sts3215"])
    assert code == EXIT_REFUSED and "<joint name='j2'>" in err and "--motor j2=MODEL" in err


def test_floating_base_robot_is_refused(tmp_path, capsys):
    out = tmp_path / "go2"
    code = main(
        [ERD + "go2_description/urdf/go2.urdf", "--out", str(out), "--motor", "*=go_m8010_6"]
    )
    err = capsys.readouterr().err
    assert code == EXIT_REFUSED and "or --floating-base, legged" in err
    assert not out.exists()


def test_resolve_source_names_the_package_file():
    path = resolve_source(ERD + "so_arm_description/urdf/so101.urdf")
    assert isinstance(path, Path) and path.name == "so101.urdf"


# ---------------------------------------------------------------- MJCF input
def test_mjcf_round_trip_of_arm3(tmp_path):
    out = tmp_path / "arm3_again"
    report = import_robot(
        ROBOTS_DIR / "arm3" / "arm3.xml",
        out,
        motors=["*=ec45flat70_gp42c"],
        velocities=["*=3.14"],  # MJCF has no velocity limit, and this motor gives none
        log=lambda *a: None,
    )
    arm3, again = load_robot("arm3"), load_robot(out)
    assert again.joint_names == arm3.joint_names == tuple(report.joints)
    np.testing.assert_array_equal(again.position_lower, arm3.position_lower)
    np.testing.assert_array_equal(again.position_upper, arm3.position_upper)
    np.testing.assert_array_equal(again.effort_limit, arm3.effort_limit)
    np.testing.assert_array_equal(again.velocity_limit, arm3.velocity_limit)
    rng = np.random.default_rng(0)
    for q in [
        np.zeros(3),
        arm3.home,
        *rng.uniform(arm3.position_lower, arm3.position_upper, (3, 3)),
    ]:
        # the written MJCF keeps 6 significant digits (0.0528409091 m -> 0.0528409 m)
        np.testing.assert_allclose(again.gravity_torque(q), arm3.gravity_torque(q), atol=1e-6)
        # arm3's own 'ee' site is the default end effector
        np.testing.assert_allclose(
            again.forward_kinematics(q), arm3.forward_kinematics(q), atol=1e-9
        )


def mjcf_from_urdf(tmp_path: Path, urdf: str, degrees: bool) -> Path:
    """The MJCF MuJoCo writes from an example-robot-data URDF (meshes by absolute path),
    rewritten in degrees when asked."""
    root = package_root("example-robot-data").as_posix()
    text = (
        resolve_source(ERD + urdf).read_text().replace("package://example-robot-data/", root + "/")
    )
    xml = ET.fromstring(mujoco.MjSpec.from_string(text).to_xml())
    if degrees:
        xml.find("compiler").set("angle", "degree")
        for joint in xml.iter("joint"):
            for attr in ("range", "ref", "springref"):
                if joint.get(attr):
                    values = [math.degrees(float(x)) for x in joint.get(attr).split()]
                    joint.set(attr, " ".join(repr(v) for v in values))
    path = tmp_path / (Path(urdf).stem + ".xml")
    ET.ElementTree(xml).write(path)
    return path


def test_mjcf_in_degrees_imports_and_survives_the_adversarial_policy(tmp_path):
    mjcf = mjcf_from_urdf(tmp_path, ARMS[1][1], degrees=True)
    assert 'angle="degree"' in mjcf.read_text()
    out = tmp_path / "so101_mjcf"
    report = import_robot(mjcf, out, motors=["*=sts3215"], log=lambda *a: None)
    robot = load_robot(out)
    assert 'angle="radian"' in (out / "so101_mjcf.xml").read_text()
    urdf = ET.parse(resolve_source(ERD + ARMS[1][1])).getroot()
    limits = {
        j.get("name"): [float(j.find("limit").get(k)) for k in ("lower", "upper")]
        for j in urdf.iter("joint")
        if j.get("type") == "revolute"
    }
    assert set(robot.joint_names) == set(limits)
    # the ranges written in degrees come back in radians (6 significant digits)
    expected = np.array([limits[j] for j in robot.joint_names])
    np.testing.assert_allclose(robot.position_lower, expected[:, 0], rtol=1e-5)
    np.testing.assert_allclose(robot.position_upper, expected[:, 1], rtol=1e-5)
    # effort: the MJCF's actuatorfrcrange (the URDF's 10 N m) lowered to the motor's peak torque
    lowered = {(j, q): (a, b) for j, q, a, b, _ in report.lowered}
    assert lowered[("shoulder_pan", "effort")] == (10.0, 2.94)
    # velocity: MJCF has none, the motor sets it
    np.testing.assert_array_equal(robot.velocity_limit, 4.71)
    assert any("no-load speed" in n and "MJCF gives none" in n for n in report.notes)
    # the same arm imported from its URDF takes the adversarial policy above (its guard and
    # limits); here the MJCF's limits, in radians, hold under it for 20 s (the NaN path too)
    result = check_adversarial(robot, "position", 20.0, workdir=tmp_path)
    assert result.non_finite_actions > 0
    assert result.max_overshoot == 0.0
    assert result.passed, result.failures


SMALL = """<mujoco model="small">
  <compiler angle="radian"/>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="table" pos="1 1 0"><geom type="box" size="0.2 0.2 0.2"/></body>
    <body name="base">
      {free}
      <geom type="cylinder" size="0.05 0.05"/>
      <body name="l1" pos="0 0 0.1">
        <joint name="j1" axis="0 0 1" {limit}/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
        <body name="l2" pos="0.3 0 0">
          <joint name="j2" axis="0 1 0" range="-1 1"/>
          <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
          <body name="slider" pos="0.3 0 0">
            <joint name="s" type="slide" axis="1 0 0" range="0 0.05"/>
            <geom type="box" size="0.02 0.02 0.02"/>
            <body name="l3" pos="0.05 0 0">
              <joint name="j3" axis="0 1 0" range="-2 2"/>
              <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.02"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <contact><exclude body1="base" body2="l3"/></contact>
  <actuator>
    <position joint="j1" kp="10" forcerange="-4 4" gear="1.5"/>
    <motor joint="j2" ctrlrange="-1 1" gear="2"/>
    <motor joint="j3" ctrlrange="-1 1"/>
    <position joint="s" kp="10"/>
  </actuator>
  <sensor><jointpos joint="j1"/></sensor>
  <keyframe><key name="home" qpos="0.1 0.2 0.01 0.3"/></keyframe>
</mujoco>"""


def test_mjcf_actuators_slide_joint_scenery_and_excludes(tmp_path):
    mjcf = tmp_path / "small.xml"
    mjcf.write_text(SMALL.format(free="", limit='range="-3 3"'))
    out = tmp_path / "small"
    report = import_robot(
        mjcf, out, motors=["*=xm430_w350"], velocities=["j3=2"], log=lambda *a: None
    )
    robot = load_robot(out)
    assert robot.joint_names == ("j1", "j2", "j3")  # the slide joint is frozen
    # effort: forcerange x gear, a motor's ctrlrange x gear x gain, capped by the motor (4.1 N m)
    np.testing.assert_array_equal(robot.effort_limit, [4.1, 2.0, 1.0])
    lowered = {(j, q): (a, b) for j, q, a, b, _ in report.lowered}
    assert lowered == {("j1", "effort"): (6.0, 4.1)}
    assert robot.velocity_limit[2] == 2.0  # --velocity, below the motor's 4.82 rad/s
    notes = " ".join(report.notes)
    assert "joint s (slide) frozen" in notes and "scenery" in notes and "floor" in notes
    written = (out / "small.xml").read_text()
    assert "<actuator" not in written and "<sensor" not in written and "<key" not in written
    pairs = [set(p) for p in robot.config.safety.collision_pairs]
    assert {"l1", "l3"} in pairs  # non-adjacent links apart at home are checked...
    assert {"base", "l3"} not in pairs  # ...unless the MJCF excludes them


# ---------------------------------------------------------------- bad MJCF input
@pytest.mark.parametrize(
    "changes,expected",
    [
        (
            dict(free='<freejoint name="floating"/>'),
            r"<body name='base'><joint name='floating' type='free'>: a floating-base robot.*legged",
        ),
        (
            dict(limit='limited="false"'),
            r"<joint name='j1'>: no position limits .*--limit j1=LOWER:UPPER",
        ),
        (dict(limit=""), r"<joint name='j1'>: no position limits .*--limit j1=LOWER:UPPER"),
    ],
    ids=["free-joint", "limited-false", "no-range"],
)
def test_bad_mjcf_is_one_line_exit_3_and_no_folder(tmp_path, capsys, changes, expected):
    import re

    mjcf = tmp_path / "arm.xml"
    mjcf.write_text(SMALL.format(**{**dict(free="", limit='range="-3 3"'), **changes}))
    out = tmp_path / "out"
    code = main([str(mjcf), "--out", str(out), "--motor", "*=sts3215"])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_REFUSED
    assert "\n" not in err and "arm.xml" in err
    assert re.search(expected, err), err
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out-")]
