"""robot-import keeps each collision mesh as its convex hull (MuJoCo's own hull of the mesh,
written into the MJCF), so two links whose meshes pass close are neither counted as touching nor
dropped from the checked pairs, as their bounding boxes would be."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim2real.robots import load_robot
from sim2real.robots.importer import mjcf_geoms
from sim2real.robots.importer.pipeline import import_robot

pytest.importorskip("coal")

#: A wedge (right triangular prism): legs L along x and H along z, width 2 W along y, m.
L, H, W = 0.2, 0.1, 0.03
#: Gap between the two wedges' slanted faces, m.
GAP = 0.01

WEDGES = """<mujoco model="wedges">
  <compiler angle="radian" meshdir="meshes/"/>
  <asset>
    <mesh name="front" file="front.obj"/>
    <mesh name="back" file="back.obj"/>
  </asset>
  <worldbody>
    <body name="base">
      <geom type="cylinder" size="0.02 0.01" pos="0 0 -0.3"/>
      <body name="a">
        <joint name="j1" axis="0 0 1" range="-1 1"/>
        <inertial pos="0.05 0 0.03" mass="0.5" diaginertia="0.001 0.001 0.001"/>
        <geom type="mesh" mesh="front"/>
      </body>
      <body name="b">
        <joint name="j2" axis="0 1 0" range="-1 1"/>
        <inertial pos="0.15 0 0.07" mass="0.5" diaginertia="0.001 0.001 0.001"/>
        <geom type="mesh" mesh="back"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor joint="j1" ctrlrange="-1 1"/>
    <motor joint="j2" ctrlrange="-1 1"/>
  </actuator>
</mujoco>
"""


def _write_prism(path: Path, triangle: np.ndarray) -> None:
    """An OBJ prism: ``triangle`` (3, 2) (x, z) m extruded over y in [-W, W]."""
    v = [(x, y, z) for y in (-W, W) for x, z in triangle]
    faces = [(1, 2, 3), (4, 6, 5), (1, 4, 5), (1, 5, 2), (2, 5, 6), (2, 6, 3), (3, 6, 4), (3, 4, 1)]
    lines = [f"v {x} {y} {z}" for x, y, z in v] + [f"f {a} {b} {c}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture
def wedges(tmp_path) -> Path:
    """Two wedges on sibling links whose slanted faces are GAP apart: their bounding boxes
    overlap by most of their volume, their hulls do not touch."""
    (tmp_path / "meshes").mkdir()
    front = np.array([(0.0, 0.0), (L, 0.0), (0.0, H)])
    normal = np.array([H, L]) / np.hypot(H, L)  # the slanted face's outward normal (x, z)
    back = np.array([(L, H), (0.0, H), (L, 0.0)]) + GAP * normal
    _write_prism(tmp_path / "meshes" / "front.obj", front)
    _write_prism(tmp_path / "meshes" / "back.obj", back)
    path = tmp_path / "wedges.xml"
    path.write_text(WEDGES)
    return path


def _import(source: Path, out: Path, **kwargs):
    import_robot(source, out, motors=["*=xm430_w350"], log=lambda *a: None, **kwargs)
    return load_robot(out)


def test_collision_meshes_become_their_hulls_and_close_links_stay_checked_and_apart(
    wedges, tmp_path
):
    from sim2real.deploy.safety.collision import collision_model, collision_query

    robot = _import(wedges, tmp_path / "hull")
    model = robot.mj_model
    for body in ("a", "b"):
        (g,) = [g for g in range(model.ngeom) if model.geom_bodyid[g] == model.body(body).id]
        assert model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
        assert model.mesh_vertnum[model.geom_dataid[g]] == 6  # the prism's corners, no more
    written = robot.mjcf_path.read_text()
    assert "vertex=" in written and ".obj" not in written  # no mesh file to ship
    pairs = {frozenset(p) for p in robot.config.safety.collision_pairs}
    assert frozenset(("a", "b")) in pairs, pairs  # checked: apart at home
    geom_model, geom_data = collision_model(robot)
    import coal

    kinds = {o.name: type(o.geometry) for o in geom_model.geometryObjects}
    assert sum(k is coal.Convex for k in kinds.values()) == 2, kinds
    fixed = robot.fixed_base_model
    distances = np.zeros(len(geom_model.collisionPairs))
    assert not collision_query(
        fixed, fixed.createData(), geom_model, geom_data, np.zeros(2), distances
    )
    assert distances.min() == pytest.approx(GAP, abs=1e-4)
    # b tilted about y by 0.1 rad: its slanted face turns into a's wedge, the pair touches
    assert collision_query(fixed, fixed.createData(), geom_model, geom_data, np.array([0, 0.1]))
    assert not collision_query(
        fixed, fixed.createData(), geom_model, geom_data, np.array([0, -0.1])
    )


def test_bounding_boxes_would_drop_the_pair_as_touching_at_home(wedges, tmp_path):
    """The previous collision geometry (--mesh-boxes): the boxes overlap, so the import drops
    the pair and the guard never checks it: what the hull fixes."""
    robot = _import(wedges, tmp_path / "box", mesh_boxes=True)
    assert mjcf_geoms.MESH_COLLISION == "hull"  # the default again after the import
    model = robot.mj_model
    assert mujoco.mjtGeom.mjGEOM_BOX in set(model.geom_type)
    pairs = {frozenset(p) for p in robot.config.safety.collision_pairs}
    assert frozenset(("a", "b")) not in pairs


@pytest.mark.parametrize("engine", ["mujoco", "pybullet"])
def test_hull_links_collide_as_hulls_on_either_engine(wedges, tmp_path, engine):
    """An imported robot's hull meshes are its contact geometry on both plants: turned one way,
    wedge b runs into wedge a and stops short of its command; turned the other way it reaches
    it (pybullet builds each hull from the compiled mesh)."""
    pytest.importorskip("pybullet")
    from sim2real.deploy.backends.sim.engines import make_plant

    robot = _import(wedges, tmp_path / "hull")
    reached = {}
    for turn in (0.2, -0.2):
        plant = make_plant(engine, robot, mode="position")
        command = np.array([[0.0, turn]])
        for _ in range(int(round(1.0 / robot.control_period))):
            plant.write(command)
            plant.advance()
        reached[turn] = plant.true_position()[0, 1]
    assert reached[-0.2] < -0.15  # free (the servo sags under gravity)
    assert reached[0.2] < 0.1  # blocked by the other wedge (touching at about 0.05 rad)


def test_reimporting_an_imported_mjcf_keeps_its_hulls(tmp_path, capsys):
    """The repository's own go2w.xml (a robot-import output: its hulls already inline meshes
    named ``<body>_<k>_hull``, its floor, light, free joint and sites) imports again: exit 0,
    one-line notes, the same hull names (before: ``ValueError: repeated name
    'FL_wheel_link_0_hull' in mesh``, a traceback, exit 1)."""
    from sim2real.deploy.cli.robot_import import main
    from sim2real.robots.loading import ROBOTS_DIR

    source = ROBOTS_DIR / "go2w" / "go2w.xml"
    out = tmp_path / "go2w"
    assert main([str(source), "--out", str(out), "--floating-base", "--motor", "*=go_m8010_6"]) == 0
    assert "Traceback" not in capsys.readouterr().err

    def names(path: Path) -> list[str]:
        return sorted(m.split('"')[0] for m in path.read_text().split('<mesh name="')[1:])

    assert names(out / "go2w.xml") == names(source)
    robot = load_robot(out)
    assert robot.mj_model.nmesh == 8


CLASH = """<mujoco model="clash">
  <asset>
    <mesh name="a_0_hull" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1"/>
    <mesh name="a_1_hull" vertex="0 0 0.2  0.1 0 0.2  0 0.1 0.2  0 0 0.3"/>
  </asset>
  <worldbody>
    <body name="base">
      <geom type="cylinder" size="0.02 0.01" pos="0 0 -0.3"/>
      <body name="a">
        <joint name="j1" axis="0 0 1" range="-1 1"/>
        <inertial pos="0 0 0" mass="0.5" diaginertia="0.001 0.001 0.001"/>
        <geom name="g0" type="mesh" mesh="a_1_hull"/>
        <geom name="g1" type="mesh" mesh="a_0_hull"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def test_hull_names_taken_by_another_geoms_mesh_get_a_free_name(tmp_path):
    """Body a's geom 0 uses the inline mesh named as geom 1's hull would be, and the reverse:
    each hull takes a free name and keeps its own geom's shape (before: a repeated-name
    traceback)."""
    source = tmp_path / "clash.xml"
    source.write_text(CLASH)
    model = _import(source, tmp_path / "out").mj_model
    assert model.nmesh == 2
    # the importer names a body's geoms <body>_<k>: g0 is a_0, g1 is a_1
    top = {n: model.geom_pos[model.geom(n).id][2] for n in ("a_0", "a_1")}
    assert top["a_0"] > top["a_1"] + 0.1  # a_0 (g0) kept the upper tetrahedron


def test_a_model_mujoco_cannot_compile_is_one_line_not_a_traceback(tmp_path, monkeypatch, capsys):
    """Whatever MuJoCo's compiler refuses in the model an import builds (here a geom on a mesh
    it does not have) reaches the user as one line naming the source file, exit 3, not a
    traceback; other refusals are not labelled a compile error (next test)."""
    import mujoco

    import sim2real.deploy.cli.robot_import as cli
    from sim2real.robots.importer.source import compile_built

    spec = mujoco.MjSpec()  # a built model MuJoCo refuses: a geom on a mesh the import dropped
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="FL_wheel_link_0_hull")

    def compile_fails(*args, **kwargs):
        return compile_built(spec)

    monkeypatch.setattr(cli, "import_robot", compile_fails)
    code = cli.main(["robots/go2w/go2w.xml", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 3 and len(err) == 1
    assert err[0].startswith("robot-import: error: robots/go2w/go2w.xml: MuJoCo could not compile")
    assert "mesh 'FL_wheel_link_0_hull' not found in geom 0" in err[0]


def test_a_refusal_that_is_not_mujocos_is_not_called_a_compile_error(tmp_path, capsys, monkeypatch):
    """A refusal raised by the import's own checks (here a contract's) is printed as it is, not
    as "MuJoCo could not compile" (what every ValueError was once called)."""
    import sim2real.deploy.cli.robot_import as cli
    from sim2real.robots.importer.source import RobotImportError

    def refuses(*args, **kwargs):
        raise RobotImportError("robots/go2w/go2w.xml: joint 'FL_hip_joint': expected a limit")

    monkeypatch.setattr(cli, "import_robot", refuses)
    code = cli.main(["robots/go2w/go2w.xml", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 3 and err == [
        "robot-import: error: robots/go2w/go2w.xml: joint 'FL_hip_joint': expected a limit"
    ]
