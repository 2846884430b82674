"""robot-import's flags and files on a small URDF written as ROS exporters write one (links with
``<collision>`` meshes placed by ``<origin xyz rpy>``, continuous joints): one box per collision
mesh, missing meshes, motors from a user's TOML file, shell patterns in ``--limit``, and an
``--out`` whose parent folders do not exist yet."""

from __future__ import annotations

import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim2real.deploy.cli.robot_import import main
from sim2real.robots import load_robot
from sim2real.robots.importer.pipeline import EXIT_REFUSED, import_robot
from sim2real.robots.loading import MOTORS_DIR

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

pytest.importorskip("coal")

URDF = """<?xml version="1.0"?>
<robot name="two_link">
  <link name="base_link">
    <inertial><mass value="2"/>
      <inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><geometry><cylinder radius="0.05" length="0.1"/></geometry></collision>
  </link>
  <link name="upper_arm">
    <inertial><origin xyz="0 0 0.15"/><mass value="1"/>
      <inertia ixx="0.008" iyy="0.008" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="meshes/visual.obj"/></geometry></visual>
    <collision><origin xyz="0 0 0.1" rpy="0 0 0"/>
      <geometry><mesh filename="meshes/rod.obj"/></geometry></collision>
    <collision><origin xyz="0 0 0.3" rpy="{rpy}"/>
      <geometry><mesh filename="meshes/knob.obj"/></geometry></collision>
  </link>
  <link name="forearm">
    <inertial><origin xyz="0 0 0.1"/><mass value="0.5"/>
      <inertia ixx="0.002" iyy="0.002" izz="0.0005" ixy="0" ixz="0" iyz="0"/></inertial>
    <collision><origin xyz="0 0 0.1"/>
      <geometry><box size="0.04 0.04 0.2"/></geometry></collision>
  </link>
  <joint name="joint1" type="continuous"><parent link="base_link"/><child link="upper_arm"/>
    <origin xyz="0 0 0.05"/><axis xyz="0 0 1"/><limit effort="3" velocity="4"/></joint>
  <joint name="joint2" type="continuous"><parent link="upper_arm"/><child link="forearm"/>
    <origin xyz="0 0 0.4"/><axis xyz="0 1 0"/><limit effort="3" velocity="4"/></joint>
</robot>
"""
#: Mesh half sizes (m), each centred at its file's origin.
ROD, KNOB = (0.02, 0.02, 0.1), (0.05, 0.01, 0.02)


def write_obj(path: Path, half) -> None:
    """A cuboid mesh centred at the origin (OBJ)."""
    signs = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    lines = [
        "v " + " ".join(repr(s * h) for s, h in zip(sign, half, strict=True)) for sign in signs
    ]
    faces = [
        (1, 2, 4), (1, 4, 3), (5, 7, 8), (5, 8, 6), (1, 5, 6), (1, 6, 2),
        (3, 4, 8), (3, 8, 7), (1, 3, 7), (1, 7, 5), (2, 6, 8), (2, 8, 4),
    ]  # fmt: skip
    path.write_text("\n".join(lines + [f"f {a} {b} {c}" for a, b, c in faces]) + "\n")


def write_urdf(folder: Path, rpy: str = "0 0 0.5", meshes=("rod", "knob", "visual")) -> Path:
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    for name, half in (("rod", ROD), ("knob", KNOB), ("visual", (0.05, 0.05, 0.2))):
        if name in meshes:
            write_obj(folder / "meshes" / f"{name}.obj", half)
    path = folder / "two_link.urdf"
    path.write_text(URDF.format(rpy=rpy))
    return path


def quiet(*_args) -> None:
    pass


def test_each_collision_mesh_becomes_its_own_box_in_its_frame(tmp_path):
    source = write_urdf(tmp_path)
    out = tmp_path / "two_link"
    import_robot(source, out, motors=["*=xm430_w350"], limits=["joint*=-3:3"], log=quiet)
    model = load_robot(out).mj_model
    arm = model.body("upper_arm").id
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == arm]
    assert [model.geom_type[g] for g in geoms] == [mujoco.mjtGeom.mjGEOM_BOX] * 2
    np.testing.assert_allclose(model.geom_size[geoms], [ROD, KNOB], atol=1e-9)
    np.testing.assert_allclose(model.geom_pos[geoms], [(0, 0, 0.1), (0, 0, 0.3)], atol=1e-9)
    # the knob's box turns with its <origin rpy>: 0.5 rad about z
    quat = np.zeros(4)
    mujoco.mju_axisAngle2Quat(quat, np.array([0.0, 0.0, 1.0]), 0.5)
    np.testing.assert_allclose(np.abs(model.geom_quat[geoms[1]]), np.abs(quat), atol=1e-6)
    # primitives stay as written
    forearm = [g for g in range(model.ngeom) if model.geom_bodyid[g] == model.body("forearm").id]
    np.testing.assert_allclose(model.geom_size[forearm[0]], [0.02, 0.02, 0.1])

    coarse = tmp_path / "coarse"
    import_robot(
        source,
        coarse,
        motors=["*=xm430_w350"],
        limits=["joint*=-3:3"],
        link_boxes=True,
        log=quiet,
    )
    model = load_robot(coarse).mj_model
    geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == model.body("upper_arm").id]
    assert len(geoms) == 1  # one box around the rod and the turned knob


def test_a_missing_urdf_mesh_is_refused_or_dropped(tmp_path, capsys):
    source = write_urdf(tmp_path, meshes=("rod", "visual"))
    out = tmp_path / "two_link"
    argv = [str(source), "--out", str(out), "--motor", "*=xm430_w350", "--limit", "*=-3:3"]
    assert main(argv) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "two_link.urdf" in err
    assert "<link name='upper_arm'><collision><mesh filename='meshes/knob.obj'>" in err
    assert "--drop-missing-meshes" in err and not out.exists()
    assert main([*argv, "--drop-missing-meshes"]) == 0
    printed = capsys.readouterr().out
    assert "link upper_arm: <collision> mesh 'meshes/knob.obj' missing: dropped" in printed
    model = load_robot(out).mj_model
    arm = [g for g in range(model.ngeom) if model.geom_bodyid[g] == model.body("upper_arm").id]
    assert len(arm) == 1


def test_a_motor_from_the_users_toml_file(tmp_path, capsys):
    """--motor '*=/path/my.toml': the catalog's schema, held in robot.toml as [motors.my]."""
    table = (MOTORS_DIR / "xm430_w350.toml").read_text()
    mine = tmp_path / "elsewhere" / "my_servo.toml"
    mine.parent.mkdir()
    mine.write_text(table.replace("peak_torque = 4.1", "peak_torque = 2.5"))
    source = write_urdf(tmp_path)
    out = tmp_path / "two_link"
    argv = [str(source), "--out", str(out), "--limit", "*=-3:3", "--motor", f"*={mine}"]
    assert main(argv) == 0
    written = tomllib.loads((out / "robot.toml").read_text())
    assert written["motors"]["my_servo"]["peak_torque"] == 2.5
    assert [j["motor"] for j in written["joints"]] == ["my_servo"] * 2
    robot = load_robot(out)
    np.testing.assert_array_equal(robot.effort_limit, 2.5)

    mine.write_text(table.replace("gear_ratio", "gear_ration"))
    assert main([*argv[:2], str(tmp_path / "bad"), *argv[3:]]) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "my_servo.toml" in err and "field 'gear_ratio': missing" in err
    other = str(tmp_path / "other")
    assert main([*argv[:2], other, *argv[3:-1], "*=my_servo"]) == EXIT_REFUSED  # no such model
    err = capsys.readouterr().err
    assert "not in the catalog" in err and "path of a motor TOML file" in err


def test_a_robot_with_motor_files_is_named_after_its_folder_not_a_motor(tmp_path):
    """Motor files that sort after the robot's name ('zz_knee' > 'two_link') name no robot: the
    robot is named after --out, the name a spec gives and the errors print."""
    table = (MOTORS_DIR / "xm430_w350.toml").read_text()
    hip, knee = tmp_path / "aa_hip.toml", tmp_path / "zz_knee.toml"
    hip.write_text(table)
    knee.write_text(table.replace("peak_torque = 4.1", "peak_torque = 2.5"))
    source = write_urdf(tmp_path)
    out = tmp_path / "two_link"
    flags = ["--limit", "*=-3:3", "--motor", f"joint1={hip}", "--motor", f"joint2={knee}"]
    assert main([str(source), "--out", str(out), *flags]) == 0
    written = tomllib.loads((out / "robot.toml").read_text())
    assert written["name"] == "two_link"
    assert sorted(written["motors"]) == ["aa_hip", "zz_knee"]
    assert load_robot(out).name == "two_link"


def test_package_meshes_not_found_name_sim2real_package_path(tmp_path, capsys, monkeypatch):
    """A URDF inside its ROS package (``two_link_description/urdf/``) whose meshes are
    ``package://two_link_description/meshes/...``: the refusal names SIM2REAL_PACKAGE_PATH and
    the folder to set it to (the package folder's parent); set, the import goes through."""
    monkeypatch.delenv("SIM2REAL_PACKAGE_PATH", raising=False)
    package = tmp_path / "src" / "two_link_description"
    write_urdf(package)
    urdf = package / "urdf" / "two_link.urdf"
    urdf.parent.mkdir()
    text = (package / "two_link.urdf").read_text()
    urdf.write_text(text.replace('"meshes/', '"package://two_link_description/meshes/'))
    out = tmp_path / "two_link"
    argv = [str(urdf), "--out", str(out), "--limit", "*=-3:3", "--motor", "*=xm430_w350"]
    assert main(argv) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "package://two_link_description/meshes/" in err, err
    assert "package 'two_link_description' not found (SIM2REAL_PACKAGE_PATH is not set)" in err, err
    assert f"export SIM2REAL_PACKAGE_PATH={tmp_path / 'src'}" in err, err
    monkeypatch.setenv("SIM2REAL_PACKAGE_PATH", str(tmp_path / "src"))
    assert main(argv) == 0
    assert load_robot(out).joint_names == ("joint1", "joint2")


@pytest.mark.parametrize("kind", ["urdf", "mjcf"])
def test_limit_takes_the_patterns_motor_takes(tmp_path, capsys, kind):
    source = write_urdf(tmp_path)
    if kind == "mjcf":
        text = source.read_text().replace("meshes/", str(tmp_path / "meshes") + "/")
        xml = mujoco.MjSpec.from_string(text).to_xml()
        source = tmp_path / "two_link.xml"
        source.write_text(xml.replace('range="-1e+10 1e+10"', ""))
    out = tmp_path / "two_link"
    flags = ["--motor", "*=xm430_w350", "--velocity", "*=4"]
    argv = [str(source), "--out", str(out), *flags]
    assert main([*argv, "--limit", "joint*=-3:3", "--limit", "joint2=-1:1"]) == 0
    robot = load_robot(out)
    np.testing.assert_allclose(robot.position_lower, [-3, -1])
    np.testing.assert_allclose(robot.position_upper, [3, 1])
    capsys.readouterr()
    code = main([*argv, "--force", "--limit", "elbow*=-3:3"])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_REFUSED and "\n" not in err
    assert "--limit 'elbow*=-3:3': pattern 'elbow*' matches no joint" in err
    assert "['joint1', 'joint2']" in err


def test_out_parent_folders_are_created_and_removed_when_the_import_fails(tmp_path, capsys):
    source = write_urdf(tmp_path)
    out = tmp_path / "robots" / "mine" / "two_link"
    argv = [str(source), "--out", str(out), "--motor", "*=xm430_w350"]
    assert main([*argv, "--limit", "*=-3:3"]) == 0
    assert load_robot(out).joint_names == ("joint1", "joint2")

    deeper = tmp_path / "other" / "robots" / "two_link"
    assert main([str(source), "--out", str(deeper), "--motor", "*=xm430_w350"]) == EXIT_REFUSED
    assert "no position limits" in capsys.readouterr().err  # continuous joints, no --limit
    assert not (tmp_path / "other").exists()

    (tmp_path / "a_file").write_text("")
    assert main([*argv[:2], str(tmp_path / "a_file" / "x"), *argv[3:]]) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "a_file exists and is not a folder" in err
