"""robot-import of robot files laid out the way other stacks write theirs (our own small files,
built from reading theirs; none of their text is copied):

- MuJoCo Menagerie's Cassie (``agility_cassie/cassie.xml``): every geom ``contype = conaffinity =
  0`` by default, the left leg's collision class ``contype 2 conaffinity 4``, the right's ``4 /
  2``, and a scene file whose floor has ``conaffinity 15``: the importer's floor must touch the
  feet whatever their bits.
- holosoma's G1 (``data/robots/g1/g1_29dof.xml``): a massless fixed body ``*_foot_contact_point``
  under each ankle link, and a site named after the foot beside it.
- MuJoCo Playground's G1 (``locomotion/g1/xmls``): ``<position>`` actuators whose ``kp`` and
  ``dampratio`` come from default classes, keyframes ``knees_bent`` and ``home``: the gains and
  home pose come from them, each source printed.
- Unitree's H1 (unitree_rl_gym ``resources/robots/h1/h1.xml``): the legs collide as meshes; the
  guard and the plant must see the file's own shapes, not fatter capsules.
- holosoma_inference's shipped G1 ONNX: ``dof_names``, ``kp``, ``kd``, ``command_ranges`` and no
  ``experiment_config``: ``--drive-from`` reads what is there and says what is not.
"""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim2real.deploy.cli.robot_import import main
from sim2real.robots import load_robot
from sim2real.robots.importer.leg_hulls import HULL_TOLERANCE, reduced_vertices, sphere_directions
from sim2real.robots.importer.pipeline import EXIT_REFUSED
from sim2real.robots.packages import resolved_mjcf
from tests.test_import_humanoid import MOTORS, write_humanoid, write_obj

pytest.importorskip("coal")

#: The motors of the test humanoid's imports (the catalog's H1 actuators: velocity limits the
#: files lack), and of the Cassie-like biped's.
MOTOR_FLAGS = [a for m in MOTORS for a in ("--motor", m)]
CASSIE_MOTORS = ["--motor", "*=h1_hip"]

CASSIE = """<mujoco model="cassie_like">
  <compiler eulerseq="zyx" autolimits="true"/>
  <default>
    <geom contype="0" conaffinity="0" condim="1" solref="0.005 1"/>
    <default class="cassie"><geom group="2"/></default>
    <default class="collision">
      <geom contype="1" group="3" type="capsule"/>
      <default class="collision-left"><geom contype="2" conaffinity="4"/></default>
      <default class="collision-right"><geom contype="4" conaffinity="2"/></default>
    </default>
  </default>
  <worldbody>
    <body name="cassie-pelvis" pos="0 0 1.1" childclass="cassie">
      <inertial pos="0 0 0" mass="10" diaginertia="0.08 0.05 0.08"/>
      <freejoint/>
      <geom type="ellipsoid" size="0.15 0.12 0.13" class="collision"/>
      <site name="imu" size="0.01"/>
{legs}
    </body>
  </worldbody>
  <actuator>
{motors}
  </actuator>
</mujoco>
"""
CASSIE_LEG = """      <body name="{s}-hip-pitch" pos="0 {y} -0.1">
        <inertial pos="0 0 -0.2" mass="4" diaginertia="0.03 0.03 0.005"/>
        <joint name="{s}-hip-pitch" type="hinge" axis="0 1 0" range="-50 80" damping="1"/>
        <geom size="0.06" fromto="0 0 0 0 0 -0.2" class="collision"/>
        <body name="{s}-knee" pos="0 0 -0.4">
          <inertial pos="0 0 -0.2" mass="1" diaginertia="0.01 0.01 0.001"/>
          <joint name="{s}-knee" type="hinge" axis="0 1 0" range="-60 5" damping="1"/>
          <geom size="0.03" fromto="0 0 -0.05 0 0 -0.38" class="collision-{s}"/>
          <body name="{s}-foot" pos="0 0 -0.42">
            <inertial pos="0 0 0" mass="0.15" diaginertia="1e-4 1e-4 1e-4"/>
            <joint name="{s}-foot" type="hinge" axis="0 1 0" range="-40 40" damping="1"/>
            <geom size="0.02" fromto="-0.06 0 0 0.09 0 0" class="collision-{s}"/>
          </body>
        </body>
      </body>"""
CASSIE_SCENE = """<mujoco model="cassie_like scene">
  <include file="cassie_like.xml"/>
  <worldbody>
    <geom name="floor" size="0 0 .125" type="plane" conaffinity="15" condim="3"/>
  </worldbody>
</mujoco>
"""


def write_cassie(folder: Path) -> Path:
    """The Cassie-like biped and its scene file in ``folder``; returns the robot file."""
    legs = "\n".join(CASSIE_LEG.format(s=s, y=y) for s, y in (("left", 0.13), ("right", -0.13)))
    joints = [f"{s}-{j}" for s in ("left", "right") for j in ("hip-pitch", "knee", "foot")]
    motors = "\n".join(
        f'    <motor name="{j}" joint="{j}" gear="16" ctrlrange="-12.2 12.2"/>' for j in joints
    )
    (folder / "scene.xml").write_text(CASSIE_SCENE)
    path = folder / "cassie_like.xml"
    path.write_text(CASSIE.format(legs=legs, motors=motors))
    return path


def floor_contacts(robot, drop: float) -> set[str]:
    """Bodies touching the floor with the robot upright at home, ``drop`` m lower than its
    standing height (the feet pressed into the floor)."""
    model, data = robot.mj_model, mujoco.MjData(robot.mj_model)
    height = robot.config.base.standing_height - drop
    data.qpos[:] = np.concatenate([[0.0, 0.0, height, 1.0, 0.0, 0.0, 0.0], robot.home])
    mujoco.mj_forward(model, data)
    floor = model.geom("floor").id
    return {
        model.body(model.geom_bodyid[c.geom1 if c.geom2 == floor else c.geom2]).name
        for c in data.contact[: data.ncon]
        if floor in (c.geom1, c.geom2)
    }


def test_the_floor_touches_feet_whose_contact_bits_are_not_menagerie_defaults(tmp_path, capsys):
    """Cassie's feet (contype 2 / conaffinity 4, and 4 / 2) touch no floor of MuJoCo's default
    bits (1, 1): the importer widens its floor by the feet's bits, says so naming the feet, and
    the robot stands on it; imported from its scene file, the floor keeps the scene's own bits."""
    source = write_cassie(tmp_path)
    out = tmp_path / "robots" / "cassie"
    assert main([str(source), "--out", str(out), "--floating-base", *CASSIE_MOTORS]) == 0
    printed = capsys.readouterr().out
    robot = load_robot(out)
    assert robot.foot_sites == ("left-foot", "right-foot")
    assert floor_contacts(robot, 0.005) == {"left-foot", "right-foot"}
    assert "floor contype/conaffinity (1, 1)" in printed and "foot left-foot's geoms" in printed
    floor = robot.mj_model.geom("floor").id
    assert robot.mj_model.geom_conaffinity[floor] & 2 and robot.mj_model.geom_conaffinity[floor] & 4

    scene = tmp_path / "robots" / "cassie_scene"
    assert main([str(tmp_path / "scene.xml"), "--out", str(scene), "--floating-base",
                 *CASSIE_MOTORS]) == 0  # fmt: skip
    robot = load_robot(scene)
    floor = robot.mj_model.geom("floor").id
    assert (robot.mj_model.geom_contype[floor], robot.mj_model.geom_conaffinity[floor]) == (0, 15)
    assert floor_contacts(robot, 0.005) == {"left-foot", "right-foot"}


def test_a_foot_whose_geoms_touch_nothing_is_refused_naming_it(tmp_path, capsys):
    source = write_cassie(tmp_path)
    text = source.read_text().replace('contype="2" conaffinity="4"', 'contype="0" conaffinity="0"')
    source.write_text(text)
    code = main([str(source), "--out", str(tmp_path / "r"), "--floating-base", *CASSIE_MOTORS])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_REFUSED and "\n" not in err
    assert "foot left-foot" in err and "touches nothing" in err


#: holosoma's auxiliary body under each ankle link (a massless fixed body for height sampling).
CONTACT_POINT = """
            <site name="{side}_foot" rgba="1 0 0 1"/>
            <body name="{side}_foot_contact_point" pos="0 0 -0.037">
              <inertial pos="0 0 0" mass="0.001" diaginertia="0.000001 0.000001 0.000001"/>
            </body>"""
#: The last foot sphere of each ankle of the test humanoid.
LAST_SPHERE = '<geom size="0.005" pos="0.105 0.03 -0.045" rgba="0.1 0.1 0.1 1"/>'


def write_holosoma_feet(folder: Path) -> Path:
    """The test humanoid with holosoma's ``*_foot_contact_point`` body and foot site under each
    ankle link."""
    source = write_humanoid(folder)
    head, left, right = source.read_text().split(LAST_SPHERE)
    source.write_text(
        head + LAST_SPHERE + CONTACT_POINT.format(side="left") + left + LAST_SPHERE
        + CONTACT_POINT.format(side="right") + right
    )  # fmt: skip
    return source


def test_a_fixed_body_under_the_foot_neither_breaks_the_frames_nor_takes_the_foot(tmp_path, capsys):
    """holosoma's ``*_foot_contact_point`` under each ankle link: with the ankle links named as
    feet the robot loads and its base locks (Pinocchio's reduction found two frames named like
    the ankle, its body and the foot site, and refused: "Several frames match the filter"), each
    name's body and site frames still found by type; chosen by default, the massless contact
    point hands the foot to the ankle link it is fixed to, and says so."""
    import pinocchio as pin

    source = write_holosoma_feet(tmp_path)
    flags = ["--floating-base", *MOTOR_FLAGS]
    out = tmp_path / "robots" / "holo"
    feet = ["--foot", "left_ankle_link", "--foot", "right_ankle_link"]
    assert main([str(source), "--out", str(out), *flags, *feet]) == 0
    robot = load_robot(out)
    fixed = robot.fixed_base_model  # the guard's and the fall detector's model
    for foot, frame in zip(robot.foot_sites, robot.foot_frame_ids, strict=True):
        assert fixed.getFrameId(foot, pin.FrameType.OP_FRAME) < fixed.nframes
        assert fixed.getFrameId(foot, pin.FrameType.BODY) < fixed.nframes
        assert robot.pin_model.frames[frame].type == pin.FrameType.OP_FRAME
    q = np.asarray(robot.home)
    data = fixed.createData()
    pin.framesForwardKinematics(fixed, data, q)
    in_fixed = [data.oMf[fixed.getFrameId(f, pin.FrameType.OP_FRAME)].translation
                for f in robot.foot_sites]  # fmt: skip
    np.testing.assert_allclose(in_fixed, robot.foot_positions(q), atol=1e-9)

    capsys.readouterr()
    default = tmp_path / "robots" / "holo_default"
    assert main([str(source), "--out", str(default), *flags]) == 0
    assert load_robot(default).foot_sites == ("left_ankle_link", "right_ankle_link")
    assert "foot left_foot_contact_point has no collision geometry" in capsys.readouterr().out


#: Playground's G1 defaults: every joint a ``<position>`` servo of kp 75 critically damped
#: (``dampratio``), the ankles kp 20, the target range the joint's (``inheritrange``).
PLAYGROUND_DEFAULTS = """    <default class="g1">
      <position inheritrange="1" kp="75" dampratio="1"/>
      <default class="ankle"><position kp="20"/></default>
    </default>
"""
#: Keyframes as Playground writes them (``knees_bent`` first), base pose then the joints.
KNEES_BENT = [0.0, -0.3, 0.6, -0.3]
HOME = [0.05, -0.1, 0.3, -0.2]


def write_playground(folder: Path) -> Path:
    """The test humanoid with Playground's ``<position>`` actuators and keyframes."""
    source = write_humanoid(folder)
    text = source.read_text().replace("  </default>", PLAYGROUND_DEFAULTS + "  </default>", 1)
    for side in ("left", "right"):
        for j in ("hip_roll", "hip_pitch", "knee", "ankle"):
            name = f"{side}_{j}_joint"
            cls = "ankle" if j == "ankle" else "g1"
            text = text.replace(
                f'<motor name="{name}" joint="{name}"/>',
                f'<position class="{cls}" name="{name}" joint="{name}"/>',
            )

    def key(name, pose):
        q = " ".join(str(v) for v in [0, 0, 0.8, 1, 0, 0, 0, *pose, *pose])
        return f'    <key name="{name}" qpos="{q}"/>'

    keys = f"  <keyframe>\n{key('knees_bent', KNEES_BENT)}\n{key('home', HOME)}\n  </keyframe>\n"
    source.write_text(text.replace("</mujoco>", keys + "</mujoco>"))
    return source


def test_gains_and_home_come_from_the_files_position_actuators_and_keyframe(tmp_path, capsys):
    """No flag and no policy give the gains or the home pose: they are the file's ``<position>``
    servos' (classes resolved, ``dampratio`` as MuJoCo compiles it) and its ``home`` key, each
    source printed and written beside the joint; ``--keyframe`` takes another key, and a key the
    file lacks is refused naming its keys; a ``--kp`` flag still wins."""
    source = write_playground(tmp_path)
    own = mujoco.MjModel.from_xml_path(str(source))
    kv = {own.actuator(a).name: -own.actuator_biasprm[a, 2] for a in range(own.nu)}
    out = tmp_path / "robots" / "g1"
    flags = ["--floating-base", *MOTOR_FLAGS]
    assert main([str(source), "--out", str(out), *flags, "--kp", "left_knee_joint=200"]) == 0
    printed = capsys.readouterr().out
    robot = load_robot(out)
    for joint in robot.config.joints:
        expected = 200.0 if joint.name == "left_knee_joint" else (
            20.0 if "ankle" in joint.name else 75.0)  # fmt: skip
        assert joint.kp == pytest.approx(expected)
        assert joint.kd == pytest.approx(kv[joint.name], rel=1e-6)
    np.testing.assert_allclose(robot.home, HOME * 2)
    assert "kd: MJCF <position> kv (every joint)" in printed
    assert "home: MJCF <key name='home'> (every joint)" in printed
    assert "keys ['knees_bent', 'home']" in printed
    toml = (out / "robot.toml").read_text()
    assert "kp = 20.0  # N m/rad, MJCF <position name='left_ankle_joint'> kp" in toml

    bent = tmp_path / "robots" / "bent"
    assert main([str(source), "--out", str(bent), *flags, "--keyframe", "knees_bent"]) == 0
    np.testing.assert_allclose(load_robot(bent).home, KNEES_BENT * 2)
    capsys.readouterr()
    code = main([str(source), "--out", str(tmp_path / "x"), *flags, "--keyframe", "stand"])
    err = capsys.readouterr().err.strip()
    assert code == EXIT_REFUSED and "\n" not in err and "['knees_bent', 'home']" in err


#: A shank mesh as CAD exports a link's: a thin slab leaning 35 degrees in the mesh's own frame
#: (its bounding box, and a capsule fitted to the box, are far fatter than the slab).
SLAB_HALF, SLAB_LEAN = (0.02, 0.015, 0.14), np.radians(35.0)


def write_slanted_shanks(folder: Path) -> Path:
    """The test humanoid whose shank collision meshes are slabs leaning outward."""
    source = write_humanoid(folder)
    signs = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    c, s = np.cos(SLAB_LEAN), np.sin(SLAB_LEAN)
    lean = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    corners = [lean @ (np.array(sign) * SLAB_HALF) + [0, 0, -0.15] for sign in signs]
    write_obj(folder / "meshes" / "shank.obj", (0, 0, 0), (0, 0, 0))  # replaced below
    lines = ["v " + " ".join(repr(float(v)) for v in p) for p in corners]
    faces = (folder / "meshes" / "shank.obj").read_text().splitlines()[8:]
    (folder / "meshes" / "shank.obj").write_text("\n".join(lines + faces) + "\n")
    return source


def shank_distance(model: mujoco.MjModel, q: np.ndarray) -> float:
    """Distance (m) between the left and right knee links' collision geoms at joint angles ``q``
    (base upright, far above any floor)."""
    data = mujoco.MjData(model)
    data.qpos[:] = np.concatenate([[0, 0, 5, 1, 0, 0, 0], q])
    mujoco.mj_kinematics(model, data)

    def geoms(body):
        b = model.body(body).id
        return [g for g in range(model.ngeom)
                if model.geom_bodyid[g] == b and (model.geom_contype[g] or model.geom_conaffinity[g])]  # fmt: skip

    return min(
        mujoco.mj_geomDistance(model, data, a, b, 1.0, None)
        for a in geoms("left_knee_link")
        for b in geoms("right_knee_link")
    )


def test_leg_links_collide_as_the_files_own_meshes_not_fatter_capsules(tmp_path):
    """A leg's collision mesh stays (within the hull tolerance) the shape MuJoCo collides it as,
    its convex hull: the shanks of the imported robot are as far apart as the file's own at
    every pose."""
    source = write_slanted_shanks(tmp_path)
    out = tmp_path / "robots" / "h1like"
    assert main([str(source), "--out", str(out), "--floating-base", *MOTOR_FLAGS]) == 0
    robot = load_robot(out)
    own = mujoco.MjModel.from_xml_path(str(source))
    imported = mujoco.MjModel.from_xml_path(str(resolved_mjcf(out / "h1like.xml")))
    for roll in (0.0, 0.2, 0.43):
        q = np.array([roll, 0.3, 0.6, -0.3, -roll, 0.3, 0.6, -0.3])
        assert robot.joint_names[0] == "left_hip_roll_joint"
        expected = shank_distance(own, q)
        assert expected <= shank_distance(imported, q) <= expected + 2 * HULL_TOLERANCE + 1e-6


def test_a_reduced_hull_stays_inside_the_full_one_within_the_tolerance():
    """A CAD-like hull of 3,000 vertices (an ellipsoid's surface with a thin spike no coarse
    direction sees) keeps a few dozen: every direction's reach within the tolerance of the full
    hull's, never beyond it, and the spike's tip kept."""
    rng = np.random.default_rng(0)
    unit = rng.normal(size=(3000, 3))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    points = unit * [0.05, 0.04, 0.2]
    points[0] = [0.09, 0.0, 0.05]  # a spike 4 cm out of the surface
    keep = reduced_vertices(points)
    assert len(keep) < 150 and 0 in keep
    dirs = sphere_directions(20000)
    gap = (points @ dirs.T).max(axis=0) - (points[keep] @ dirs.T).max(axis=0)
    assert gap.min() >= 0.0 and gap.max() <= HULL_TOLERANCE + 5e-4


def test_drive_from_a_holosoma_export_without_experiment_config(tmp_path, capsys):
    """holosoma_inference's shipped G1 policies carry ``dof_names``, ``kp``, ``kd`` and
    ``command_ranges`` but no ``experiment_config``: ``--drive-from`` takes their gains by
    joint name and says what the file lacks (the default pose, the control rate, the
    observation terms); the runtime refuses to build a spec from it, naming what is missing."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.onnx_checks import PolicyLoadError
    from tests import foreign_stacks as fs

    source = write_humanoid(tmp_path)
    own = mujoco.MjModel.from_xml_path(str(source))
    joints = [own.joint(j).name for j in range(1, own.njnt)][::-1]  # another order than the file's
    kp = [40.0 + k for k in range(len(joints))]
    kd = [1.0 + 0.1 * k for k in range(len(joints))]
    policy = fs.write_holosoma_inference(tmp_path / "ppo_g1.onnx", joints, kp, kd, 30)
    out = tmp_path / "robots" / "holo"
    flags = ["--floating-base", *MOTOR_FLAGS, "--drive-from", str(policy), "--control-rate", "50"]
    assert main([str(source), "--out", str(out), *flags]) == 0
    printed = capsys.readouterr().out
    robot = load_robot(out)
    by_name = {j.name: j for j in robot.config.joints}
    for name, p, d in zip(joints, kp, kd, strict=True):
        assert (by_name[name].kp, by_name[name].kd) == (pytest.approx(p), pytest.approx(d))
    assert "kp, kd read; it does not record home, control rate" in printed
    assert "experiment_config" in printed and "observation terms" in printed
    assert "home: the importer's rule" in printed
    with pytest.raises(PolicyLoadError, match="observation terms are not recorded") as info:
        OnnxPolicy(policy, robot)
    assert "default pose" in str(info.value) and "--spec" in str(info.value)


def test_robot_toml_credits_only_the_sources_that_gave_a_value(tmp_path):
    """A ``<position>`` servo without ``kv`` (nor ``dampratio``) gives kd 0: robot.toml writes
    ``kd = 0.0`` (before: ``kd = -0.0``, MuJoCo's bias ``-kv`` negated); the control rate and the
    physics timestep no flag gave are credited to their real sources, not to ``--control-rate``
    and ``--physics-timestep`` (before: both flags credited though not given)."""
    source = write_playground(tmp_path)
    source.write_text(source.read_text().replace(' dampratio="1"', ""))
    out = tmp_path / "robots" / "g1"
    assert main([str(source), "--out", str(out), "--floating-base", *MOTOR_FLAGS]) == 0
    toml = (out / "robot.toml").read_text()
    assert not re.search(r"= -0\.0\b|\[-0\.0\b|, -0\.0\b", toml)
    assert "kd = 0.0  # N m s/rad, MJCF <position name='left_knee_joint'> kv" in toml
    assert [j.kd for j in load_robot(out).config.joints] == [0.0] * 8
    assert "--control-rate)" not in toml and "--physics-timestep)" not in toml
    assert "# Hz (robot-import's default; --control-rate sets it)" in toml
    given = tmp_path / "robots" / "given"
    flags = ["--control-rate", "50", "--physics-timestep", "0.004"]
    assert main([str(source), "--out", str(given), "--floating-base", *MOTOR_FLAGS, *flags]) == 0
    toml = (given / "robot.toml").read_text()
    assert "# Hz (robot-import --control-rate)" in toml
    assert "# s (robot-import --physics-timestep)" in toml


def test_robot_toml_says_the_files_contact_bits_decide_what_the_plant_collides(tmp_path):
    """Cassie's legs: contype 2 / conaffinity 4 on the left, 4 / 2 on the right, so a left link
    never touches another left link in MuJoCo. robot.toml's comment on ``collision_pairs`` says
    the plant collides them only where the bits let them and counts the pairs kept apart, as
    MuJoCo's own filter finds them (before: 'the plant checks contact only between these (and
    the floor)', whatever the bits)."""
    source = write_cassie(tmp_path)
    out = tmp_path / "robots" / "cassie"
    assert main([str(source), "--out", str(out), "--floating-base", *CASSIE_MOTORS]) == 0
    robot = load_robot(out)
    model = robot.mj_model
    ct, ca = model.geom_contype, model.geom_conaffinity
    apart = [
        (a, b)
        for a, b in robot.config.safety.collision_pairs
        if not (
            ct[model.geom(a).id] & ca[model.geom(b).id]
            or ct[model.geom(b).id] & ca[model.geom(a).id]
        )
    ]
    assert apart  # the left leg's own links: 2 & 4 = 0
    toml = (out / "robot.toml").read_text()
    assert "checks contact only between" not in toml
    assert "contype/conaffinity bits" in toml
    assert f" {len(apart)} of these pairs never touch there" in toml


def test_the_dropped_actuators_note_claims_position_gains_only_when_read(tmp_path, capsys):
    """The test humanoid drives its joints with ``<motor>`` (torque) actuators: the import's
    note on the dropped actuators says no gains were read (before: '<position> gains read'
    for torque actuators); with Playground's ``<position>`` servos it says how many were."""
    source = write_humanoid(tmp_path / "motor")
    assert main([str(source), "--out", str(tmp_path / "a"), "--floating-base", *MOTOR_FLAGS]) == 0
    (line,) = [x for x in capsys.readouterr().out.splitlines() if " actuators " in x]
    assert "<position> gains read" not in line and "no <position> servo)" in line
    source = write_playground(tmp_path / "servo")
    assert main([str(source), "--out", str(tmp_path / "b"), "--floating-base", *MOTOR_FLAGS]) == 0
    (line,) = [x for x in capsys.readouterr().out.splitlines() if " actuators " in x]
    assert "the gains of its 8 <position> servos read" in line
