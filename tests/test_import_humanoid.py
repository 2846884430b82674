"""robot-import of a humanoid MJCF written the way Unitree writes its H1 / H1-2 (unitree_rl_gym
resources/robots/h1/h1.xml): a pelvis with a free joint carrying the torso's and arms' meshes,
each mesh twice (a visual copy with contype = conaffinity = 0 in group 1, and the collision
copy), legs of hinge joints with ``actuatorfrcrange``, flat feet made of four small contact
spheres, ``<motor>`` actuators. It imports as a floating base, keeps the feet and each collision
mesh's own shape (MuJoCo and the guard's coal model alike), and stands on its four-sphere feet;
missing mesh files are refused or dropped on request."""

from __future__ import annotations

import math
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim2real.deploy.cli.robot_import import main
from sim2real.deploy.smoothing import CommandSmoother
from sim2real.robots import load_robot
from sim2real.robots.importer.pipeline import EXIT_REFUSED, import_robot

pytest.importorskip("coal")

#: Collision meshes: name -> (half sizes, centre in the mesh file's frame), m. A cuboid written as
#: an OBJ file (CAD exports place a link's mesh in the link frame, off its origin).
MESHES = {
    "pelvis": ((0.05, 0.14, 0.04), (0.0, 0.0, 0.0)),
    "torso": ((0.06, 0.12, 0.15), (0.0, 0.0, 0.2)),
    "arm": ((0.03, 0.03, 0.15), (0.0, 0.0, 0.0)),
    "thigh": ((0.03, 0.03, 0.13), (0.0, 0.0, -0.15)),
    "shank": ((0.025, 0.025, 0.12), (0.0, 0.0, -0.15)),
}
#: Joints of each leg, in order.
JOINTS = ("hip_roll", "hip_pitch", "knee", "ankle")
#: Foot contact spheres (radius 5 mm) at the corners of a 17 x 6 cm sole, ankle frame, m.
FOOT = [(x, y, -0.045) for x in (-0.065, 0.105) for y in (-0.03, 0.03)]
FOOT_RADIUS = 0.005

HUMANOID = """<mujoco model="tiny_humanoid">
  <compiler angle="radian" meshdir="meshes/"/>
  <default>
    <joint damping="0.001" armature="0.01" frictionloss="0.1"/>
  </default>
  <asset>
{assets}
  </asset>
  <worldbody>
    <body name="pelvis" pos="0 0 0.8">
      <inertial pos="0 0 0.1" mass="12" diaginertia="0.3 0.25 0.1"/>
      <joint name="floating_base_joint" type="free" limited="false" actuatorfrclimited="false"/>
{pelvis_geoms}
{legs}
    </body>
  </worldbody>
  <actuator>
{motors}
  </actuator>
</mujoco>
"""

LEG = """      <body name="{s}_hip_roll_link" pos="0 {y} -0.07">
        <inertial pos="0 0 0" mass="1" diaginertia="0.002 0.002 0.002"/>
        <joint name="{s}_hip_roll_joint" pos="0 0 0" axis="1 0 0" range="-0.43 0.43"
               actuatorfrcrange="-200 200"/>
      <body name="{s}_hip_pitch_link">
        <inertial pos="0 0 -0.15" mass="2" diaginertia="0.02 0.02 0.003"/>
        <joint name="{s}_hip_pitch_joint" pos="0 0 0" axis="0 1 0" range="-1.57 1.57"
               actuatorfrcrange="-200 200"/>
{thigh}
        <body name="{s}_knee_link" pos="0 0 -0.3">
          <inertial pos="0 0 -0.15" mass="1.5" diaginertia="0.015 0.015 0.002"/>
          <joint name="{s}_knee_joint" pos="0 0 0" axis="0 1 0" range="-0.26 2.05"
                 actuatorfrcrange="-300 300"/>
{shank}
          <body name="{s}_ankle_link" pos="0 0 -0.3">
            <inertial pos="0.02 0 -0.03" mass="0.6" diaginertia="0.002 0.002 0.0005"/>
            <joint name="{s}_ankle_joint" pos="0 0 0" axis="0 1 0" range="-0.87 0.52"
                   actuatorfrcrange="-40 40"/>
{spheres}
          </body>
        </body>
      </body>
      </body>"""


def mesh_geoms(mesh: str, indent: str, pos: str = "") -> str:
    """A mesh's visual copy and collision copy, as Unitree's MJCF lists them."""
    at = f' pos="{pos}"' if pos else ""
    return (
        f'{indent}<geom{at} type="mesh" contype="0" conaffinity="0" group="1" density="0" '
        f'rgba="0.1 0.1 0.1 1" mesh="{mesh}"/>\n'
        f'{indent}<geom{at} type="mesh" rgba="0.1 0.1 0.1 1" mesh="{mesh}"/>'
    )


def write_obj(path: Path, half, centre) -> None:
    """A cuboid mesh (OBJ: 8 vertices, 12 outward triangles)."""
    signs = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    lines = [
        "v " + " ".join(repr(c + s * h) for c, s, h in zip(centre, sign, half, strict=True))
        for sign in signs
    ]
    faces = [
        (1, 2, 4), (1, 4, 3), (5, 7, 8), (5, 8, 6), (1, 5, 6), (1, 6, 2),
        (3, 4, 8), (3, 8, 7), (1, 3, 7), (1, 7, 5), (2, 6, 8), (2, 8, 4),
    ]  # fmt: skip
    lines += [f"f {a} {b} {c}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def write_humanoid(folder: Path) -> Path:
    """The humanoid MJCF and its meshes in ``folder`` (meshes in ``folder/meshes``)."""
    (folder / "meshes").mkdir(parents=True, exist_ok=True)
    for name, (half, centre) in MESHES.items():
        write_obj(folder / "meshes" / f"{name}.obj", half, centre)
    assets = "\n".join(f'    <mesh name="{m}" file="{m}.obj"/>' for m in MESHES)
    pelvis = "\n".join(
        [
            mesh_geoms("pelvis", " " * 6),
            mesh_geoms("torso", " " * 6),
            mesh_geoms("arm", " " * 6, "0 0.2 0.05"),
            mesh_geoms("arm", " " * 6, "0 -0.2 0.05"),
        ]
    )
    legs = []
    for side, y in (("left", 0.1), ("right", -0.1)):
        spheres = "\n".join(
            f'            <geom size="{FOOT_RADIUS}" pos="{x} {fy} {z}" rgba="0.1 0.1 0.1 1"/>'
            for x, fy, z in FOOT
        )
        legs.append(
            LEG.format(
                s=side,
                y=y,
                thigh=mesh_geoms("thigh", " " * 8),
                shank=mesh_geoms("shank", " " * 10),
                spheres=spheres,
            )
        )
    joints = [f"{s}_{j}_joint" for s in ("left", "right") for j in JOINTS]
    motors = "\n".join(f'    <motor name="{j}" joint="{j}"/>' for j in joints)
    path = folder / "tiny_humanoid.xml"
    path.write_text(
        HUMANOID.format(assets=assets, pelvis_geoms=pelvis, legs="\n".join(legs), motors=motors)
    )
    return path


#: Unitree H1 actuators, and stiff PD gains that hold the robot standing without a policy.
MOTORS = ["*=h1_hip", "*_knee_joint=h1_knee", "*_ankle_joint=h1_ankle"]
KP, KD = ["*=300", "*_ankle_joint=100"], ["*=6"]
#: The command-line flags of every import here.
FLAGS = [
    "--floating-base",
    *[a for m in MOTORS for a in ("--motor", m)],
    *[a for k in KP for a in ("--kp", k)],
    *[a for k in KD for a in ("--kd", k)],
]


def qpos(robot, height: float) -> np.ndarray:
    """MuJoCo qpos: the base upright at ``height`` m, the joints at home."""
    return np.concatenate([[0.0, 0.0, height, 1.0, 0.0, 0.0, 0.0], robot.home])


@pytest.fixture(scope="module")
def humanoid(tmp_path_factory):
    """The imported humanoid: (robot, source folder, output folder)."""
    folder = tmp_path_factory.mktemp("humanoid")
    source = write_humanoid(folder)
    out = folder / "robots" / "tiny"
    assert main([str(source), "--out", str(out), *FLAGS]) == 0
    return load_robot(out), folder, out


def test_mjcf_with_a_free_joint_imports_as_a_floating_base(humanoid):
    robot, _, out = humanoid
    assert robot.floating_base and robot.base_body == "pelvis"
    assert robot.joint_names == tuple(f"{s}_{j}_joint" for s in ("left", "right") for j in JOINTS)
    assert robot.foot_sites == ("left_ankle_link", "right_ankle_link")
    model = robot.mj_model
    # the importer's own free joint replaces the MJCF's, on the same body
    assert model.joint(0).name == "root" and model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    assert model.body(model.jnt_bodyid[0]).name == "pelvis"
    assert "floating_base_joint" not in (out / "tiny.xml").read_text()
    # effort limits from the MJCF's actuatorfrcrange; velocity limits from the motors
    np.testing.assert_array_equal(robot.effort_limit, [200, 200, 300, 40] * 2)
    np.testing.assert_array_equal(robot.velocity_limit, [23, 23, 14, 9] * 2)
    # its IMU sends its own attitude, whose heading drifts as the MTi-3's (10 deg/h, 0.007
    # deg/s/sqrt(Hz)): the source of a tracking policy's anchor (docs/motion-tracking.md)
    imu = robot.config.sensors.imu
    assert imu.orientation_sigma > 0
    assert imu.heading_rate_sigma == pytest.approx(np.radians(10.0) / 3600, rel=0.01)
    assert imu.heading_walk == pytest.approx(np.radians(0.007), rel=0.01)


def test_the_imported_robot_toml_cites_no_document_the_reader_does_not_have(humanoid):
    """Every constant the importer writes names its source; none is a course document the
    reader of robot.toml does not have (the specification's sections)."""
    _, _, out = humanoid
    text = (out / "robot.toml").read_text().lower()
    assert "[sensors.imu]" in text
    assert not re.search(r"\bseed\s+sections?\b", text)


def test_feet_keep_their_four_contact_spheres_and_touch_the_floor_at_home(humanoid):
    robot, _, _ = humanoid
    model, data = robot.mj_model, mujoco.MjData(robot.mj_model)
    for foot in robot.foot_sites:
        body = model.body(foot).id
        geoms = [g for g in range(model.ngeom) if model.geom_bodyid[g] == body]
        assert [model.geom_type[g] for g in geoms] == [mujoco.mjtGeom.mjGEOM_SPHERE] * 4
        np.testing.assert_allclose(model.geom_size[geoms, 0], FOOT_RADIUS)
        np.testing.assert_allclose(sorted(model.geom_pos[geoms].tolist()), sorted(FOOT))
    data.qpos[:] = qpos(robot, robot.config.base.standing_height)
    mujoco.mj_kinematics(model, data)
    spheres = [g for g in range(model.ngeom) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE]
    bottoms = data.geom_xpos[spheres, 2] - FOOT_RADIUS
    np.testing.assert_allclose(bottoms, 0.0, atol=1e-4)


def test_it_stands_on_its_four_sphere_feet_and_the_feet_sense_its_weight(humanoid):
    """Two seconds holding home with the plant's PD servos: upright, at its standing height, its
    weight on the touch sensors (two single balls would leave it a line of support to tip
    over)."""
    robot, _, _ = humanoid
    model = robot.plant_model("position")
    data = mujoco.MjData(model)
    data.qpos[:] = qpos(robot, robot.config.base.standing_height)
    data.ctrl[:] = robot.home
    mujoco.mj_forward(model, data)
    for _ in range(int(2.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
    up = data.xmat[model.body("pelvis").id].reshape(3, 3)[:, 2]
    assert math.degrees(math.acos(min(1.0, up[2]))) < 1.0
    assert abs(data.qpos[2] - robot.config.base.standing_height) < 0.01
    weight = float(model.body_subtreemass[0]) * 9.81
    touch = [data.sensor(f"{f}_touch").data[0] for f in robot.foot_sites]
    assert sum(touch) == pytest.approx(weight, rel=0.05)
    assert min(touch) > 0.3 * weight


def test_each_collision_mesh_is_its_own_hull_in_mujoco_and_the_guard(humanoid):
    """The pelvis carries four collision meshes (pelvis, torso, two arms): four convex hulls of
    the meshes' own shapes (cuboids here: their eight corners), not one shape around the arms;
    the visual copies are gone; the arms and the thighs, 4 cm apart, are pairs the guard checks,
    apart in a forward stride too."""
    import coal

    from sim2real.deploy.safety.collision import collision_model, collision_query

    robot, _, _ = humanoid
    model = robot.mj_model
    pelvis = [g for g in range(model.ngeom) if model.geom_bodyid[g] == model.body("pelvis").id]
    assert [model.geom_type[g] for g in pelvis] == [mujoco.mjtGeom.mjGEOM_MESH] * 4
    halves = {name: np.array(half) for name, (half, _) in MESHES.items()}
    expected = [halves["pelvis"], halves["torso"], halves["arm"], halves["arm"]]
    centres = np.array([(0, 0, 0), (0, 0, 0.2), (0, 0.2, 0.05), (0, -0.2, 0.05)])
    for g, half, centre in zip(pelvis, expected, centres, strict=True):
        mesh = model.geom_dataid[g]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.geom_quat[g])
        body = model.geom_pos[g] + model.mesh_vert[start : start + count] @ rot.reshape(3, 3).T
        assert count == 8
        np.testing.assert_allclose(body.min(axis=0), centre - half, atol=1e-6)
        np.testing.assert_allclose(body.max(axis=0), centre + half, atol=1e-6)

    geom_model, geom_data = collision_model(robot)
    hulls = {g.name: g for g in geom_model.geometryObjects}
    for g, half, centre in zip(pelvis, expected, centres, strict=True):
        obj = hulls[model.geom(g).name]
        assert isinstance(obj.geometry, coal.Convex)
        pts = np.asarray(obj.geometry.points())
        body = obj.placement.translation + pts @ obj.placement.rotation.T
        np.testing.assert_allclose(body.min(axis=0), centre - half, atol=1e-6)
        np.testing.assert_allclose(body.max(axis=0), centre + half, atol=1e-6)
    pairs = {frozenset(p) for p in robot.config.safety.collision_pairs}
    left_arm, left_thigh = model.geom(pelvis[2]).name, "left_hip_pitch_link"
    assert frozenset((left_arm, left_thigh)) in pairs
    stride = np.array(robot.home)
    stride[robot.joint_names.index("left_hip_pitch_joint")] = -1.0
    stride[robot.joint_names.index("right_hip_pitch_joint")] = 0.6
    fixed = robot.fixed_base_model
    assert not collision_query(fixed, fixed.createData(), geom_model, geom_data, stride)


def test_link_boxes_puts_one_box_around_the_arms(humanoid, tmp_path):
    """--link-boxes: the coarse geometry (one box per body): the pelvis box encloses the arms
    and reaches the thighs at home, so those pairs go unchecked."""
    _, folder, _ = humanoid
    out = tmp_path / "coarse"
    source = folder / "tiny_humanoid.xml"
    assert main([str(source), "--out", str(out), "--link-boxes", *FLAGS]) == 0
    robot = load_robot(out)
    model = robot.mj_model
    pelvis = [g for g in range(model.ngeom) if model.geom_bodyid[g] == model.body("pelvis").id]
    assert len(pelvis) == 1
    np.testing.assert_allclose(model.geom_size[pelvis[0]][1], 0.23, atol=1e-9)
    pairs = robot.config.safety.collision_pairs
    assert not any("pelvis" in p[0] and "hip_pitch" in p[1] for p in pairs)


def test_a_missing_mesh_is_refused_or_its_geoms_dropped(humanoid, tmp_path, capsys):
    _, folder, _ = humanoid
    source = tmp_path / "tiny_humanoid.xml"
    source.write_text((folder / "tiny_humanoid.xml").read_text())
    (tmp_path / "meshes").mkdir()
    for name in MESHES:
        if name != "arm":
            (tmp_path / "meshes" / f"{name}.obj").write_bytes(
                (folder / "meshes" / f"{name}.obj").read_bytes()
            )
    out = tmp_path / "tiny"
    assert main([str(source), "--out", str(out), *FLAGS]) == EXIT_REFUSED
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "tiny_humanoid.xml" in err
    assert "<mesh name='arm'>" in err and "arm.obj does not exist" in err
    assert "--drop-missing-meshes" in err and not out.exists()

    report = import_robot(
        source,
        out,
        motors=MOTORS,
        floating_base=True,
        kp=KP,
        kd=KD,
        drop_missing_meshes=True,
        log=lambda *a: None,
    )
    dropped = [n for n in report.notes if "mesh 'arm'" in n]
    assert len(dropped) == 1 and "missing" in dropped[0] and "dropped" in dropped[0]
    model = load_robot(out).mj_model
    pelvis = [g for g in range(model.ngeom) if model.geom_bodyid[g] == model.body("pelvis").id]
    assert len(pelvis) == 2  # pelvis and torso: both arm geoms (and their visual copies) gone


def test_the_imu_rides_on_the_base(humanoid, tmp_path, capsys):
    """--imu names an MJCF site (the H1-2's ``imu`` on its torso): on the base it carries the
    IMU there; on a link a joint moves it is refused (the runtime estimates the base from it)."""
    _, folder, _ = humanoid
    text = (folder / "tiny_humanoid.xml").read_text()
    text = text.replace(
        '<joint name="floating_base_joint"',
        '<site name="imu" pos="-0.04 0.02 0.25"/>\n      <joint name="floating_base_joint"',
    )
    text = text.replace(
        '<joint name="left_knee_joint"',
        '<site name="shin_imu"/>\n          <joint name="left_knee_joint"',
    )
    source = folder / "with_imu.xml"
    source.write_text(text)
    out = tmp_path / "with_imu"
    assert main([str(source), "--out", str(out), *FLAGS, "--imu", "imu"]) == 0
    robot = load_robot(out)
    site = robot.mj_model.site(robot.imu_site_id)
    assert robot.mj_model.body(int(site.bodyid[0])).name == "pelvis"
    np.testing.assert_allclose(site.pos, [-0.04, 0.02, 0.25], atol=1e-9)

    code = main([str(source), "--out", str(tmp_path / "no"), *FLAGS, "--imu", "shin_imu"])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_REFUSED and "\n" not in err
    assert "--imu shin_imu: on link left_knee_link, which joint 'left_knee_joint' moves" in err


def test_pd_targets_may_step_as_far_as_the_full_torque_reaches_and_the_estimator_holds(humanoid):
    """A legged robot's smoother lets a PD target move, within one control period, as far as the
    drive's full torque reaches (effort / kp), as policies trained without a smoother step it; the
    joint estimator stays consistent at those limits (no re-initialization) on a standing run
    with encoder noise."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.estimation.joint_tuning import motion_acceleration
    from sim2real.deploy.estimation.joints import JointStateEstimator

    robot, _, _ = humanoid
    period = robot.control_period
    reach = robot.effort_limit / np.array([j.kp for j in robot.config.joints])
    assert (robot.acceleration_limit >= 4.0 * reach / period**2 * 0.98).all()  # 2 digits
    assert (robot.jerk_limit >= robot.acceleration_limit / (0.5 * period) * 0.98).all()
    assert (motion_acceleration(robot) <= 2.0 * robot.velocity_limit / period).all()
    # the smoother, not only its limits: a target step of the full reach toward the farther
    # hard limit is commanded within two periods (the motor's no-load speed on the target
    # held the H1-2's hips to 0.4 rad per period and its ankles to 0.16)
    smoother = CommandSmoother(robot, 1, "position")
    home = robot.home[None, :]
    smoother.reset(home, np.zeros_like(home))
    room_up, room_down = robot.position_upper - robot.home, robot.home - robot.position_lower
    step = np.where(room_up > room_down, 1.0, -1.0) * np.minimum(
        reach, 0.9 * np.maximum(room_up, room_down)
    )
    assert (np.abs(step) > 2.0 * period * robot.soft_velocity_limit).any()  # the old cap bites
    target = home + step
    for _ in range(2):
        command = smoother.step(target.copy())
    np.testing.assert_allclose(command, target, atol=1e-6)
    plant = SimBackend(robot, "position", envs=1, seed=0)
    estimator = JointStateEstimator(robot, 1, input_extrapolates=False)
    state = RobotState.zeros(1, robot.n_joints)
    estimator.reset(plant.true_position(), 0.0)
    for _ in range(100):
        plant.write(robot.home[None, :])
        plant.advance()
        estimator.update(plant.read(), state)
    assert estimator.reinitializations.tolist() == [0]
    assert np.abs(state.q - plant.true_position()).max() < 0.05


def test_default_classes_with_materials_and_a_root_childclass_import(tmp_path, capsys):
    """An MJCF as mjlab's asset zoo and MuJoCo Menagerie write their robots: a ``<default>``
    class whose geoms name a material, and ``childclass`` on the root body. MuJoCo loads it; the
    importer dropped the materials but not the class's name of one ("material 'silver' not
    found"), then wrote its free joint ``class="main"`` under the root's childclass, which
    Pinocchio's MJCF parser cannot read (a raw IndexError). Both import now."""
    source = write_humanoid(tmp_path)
    text = source.read_text()
    text = text.replace(
        "  <default>\n",
        '  <default>\n    <default class="robot">\n      <default class="visual">\n'
        '        <geom material="silver" contype="0" conaffinity="0" group="2"/>\n'
        "      </default>\n    </default>\n",
    )
    text = text.replace(
        "  <asset>\n", '  <asset>\n    <material name="silver" rgba=".7 .7 .7 1"/>\n'
    )
    text = text.replace(
        '<body name="pelvis" pos="0 0 0.8">',
        '<body name="pelvis" pos="0 0 0.8" childclass="robot">',
    )
    text = text.replace(
        '<geom type="mesh" contype="0" conaffinity="0" group="1"',
        '<geom class="visual" type="mesh"',
    )
    assert text.count('class="visual"') > 4 and 'childclass="robot"' in text
    source.write_text(text)
    mujoco.MjModel.from_xml_path(str(source))  # MuJoCo loads it
    out = tmp_path / "robots" / "styled"
    assert main([str(source), "--out", str(out), *FLAGS]) == 0, capsys.readouterr().err
    robot = load_robot(out)
    assert robot.floating_base and robot.pin_model.joints[1].shortname() == "JointModelFreeFlyer"
    assert robot.n_joints == 8


def test_a_robot_that_collides_only_through_contact_pairs_still_stands(tmp_path, capsys):
    """A scene whose robot collides only through ``<contact><pair>``s with its floor (every geom
    ``contype="0" conaffinity="0"``, as some published humanoids are written): the importer drops
    the pairs and the floor, and wrote a robot with no colliding geometry (exit 0, nothing said)
    that fell through the floor. The pairs are kept, on the importer's floor (named as the
    scene's), it says so, and the robot stands on its feet."""
    source = write_humanoid(tmp_path)
    text = source.read_text().replace(
        '<geom size="0.005"', '<geom contype="0" conaffinity="0" size="0.005"'
    )
    text = text.replace(
        '<geom type="mesh" rgba', '<geom type="mesh" contype="0" conaffinity="0" rgba'
    )
    feet = [f"{side}_foot{k}" for side in ("left", "right") for k in range(4)]
    for name in feet:  # name the spheres, in file order
        text = text.replace(
            '<geom contype="0" conaffinity="0" size',
            f'<geom name="{name}" contype="0" conaffinity="0" size',
            1,
        )
    pairs = "\n".join(f'    <pair geom1="floor" geom2="{g}"/>' for g in feet)
    text = text.replace(
        "  <worldbody>\n",
        '  <worldbody>\n    <geom name="floor" type="plane" size="5 5 0.1"/>\n',
    ).replace("  <actuator>", f"  <contact>\n{pairs}\n  </contact>\n  <actuator>")
    source.write_text(text)
    mujoco.MjModel.from_xml_path(str(source))  # MuJoCo loads the scene
    out = tmp_path / "robots" / "paired"
    assert main([str(source), "--out", str(out), *FLAGS]) == 0
    assert "8 <contact><pair>s kept" in capsys.readouterr().out
    robot = load_robot(out)
    model = robot.plant_model("position")
    data = mujoco.MjData(model)
    data.qpos[:] = qpos(robot, robot.config.base.standing_height)
    data.ctrl[:] = robot.home
    for _ in range(int(1.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
    assert abs(data.qpos[2] - robot.config.base.standing_height) < 0.02  # on its feet
