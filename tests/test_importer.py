"""robot-import: fixed-base arms of example-robot-data import, load and run the adversarial policy;
every bad input is a one-line error with exit code 3 and no output folder."""

from __future__ import annotations

from pathlib import Path

import pytest

from deploy.acceptance import check_adversarial
from robots import load_robot
from robots.importer import EXIT_REFUSED, import_robot, main, resolve_source

pytest.importorskip("coal")
try:
    resolve_source("example-robot-data:so_arm_description/urdf/so101.urdf")
except Exception:  # pragma: no cover
    pytest.skip("example-robot-data is not installed", allow_module_level=True)

ERD = "example-robot-data:"
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
    result = check_adversarial(robot, "position", 60.0, workdir=tmp_path)
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
    assert code == EXIT_REFUSED and "legged robots are a later issue" in err
    assert not out.exists()


def test_resolve_source_names_the_package_file():
    path = resolve_source(ERD + "so_arm_description/urdf/so101.urdf")
    assert isinstance(path, Path) and path.name == "so101.urdf"
