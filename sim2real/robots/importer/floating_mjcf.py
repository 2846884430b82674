"""The MJCF of a floating-base (legged) robot: :func:`finish_floating_mjcf`.

A floating-base robot gets, in its MJCF:

- a MuJoCo free joint ``root`` on the root link (Pinocchio's MJCF parser reads it as its
  free-flyer root joint, ``pin.JointModelFreeFlyer``), the base placed so that the feet touch
  the floor at the home pose;
- a flat floor (a plane ``floor`` in the world body) and a light;
- a site ``imu`` at the IMU (``--imu LINK`` or an MJCF site, else a site or link named
  ``imu``, else the root link) with MuJoCo ``gyro`` and ``accelerometer`` sensors;
- per foot (leaf links at the end of the longest chains of movable joints, or ``--foot LINK``):
  its collision geometry, a site ``<foot>`` around its contact geometry and a MuJoCo ``touch``
  sensor on it (the normal force of the contacts inside the site: foot contact), all on the
  nearest body a joint moves (:mod:`sim2real.robots.importer.foot_sites`);
- on the other bodies a hinge moves, an MJCF mesh's convex hull keeps the fewest of its vertices
  that stay within ``HULL_TOLERANCE`` of it (:mod:`sim2real.robots.importer.leg_hulls`; a capsule
  around its box, what the importer wrote before, is far fatter than a leaning thigh); a box
  fitted to a mesh (a URDF's, ``--mesh-boxes``) becomes the capsule along its long axis
  (:func:`_box_to_capsule`); the description's own primitives stay.

"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from sim2real.robots.importer.foot_sites import (
    add_foot_site,
    geom_points,
    in_body_frame,
    moving_ancestor,
)
from sim2real.robots.importer.leg_hulls import reduce_hull
from sim2real.robots.importer.mjcf_geoms import drop_unused_meshes
from sim2real.robots.importer.model import _sig
from sim2real.robots.importer.source import PreparedSource, RobotImportError, compile_built

#: Name of the MuJoCo free joint of the base (Pinocchio names its free-flyer joint the same).
FREE_JOINT = "root"
#: Site of the IMU (its gyro and accelerometer sensors are ``imu_gyro``, ``imu_accelerometer``).
IMU_SITE = "imu"
#: ``(contype, conaffinity)`` of a plane that sets neither (MuJoCo's defaults): the floor of a
#: robot file without one, before the feet widen it (:func:`floor_contact_bits`).
DEFAULT_FLOOR_BITS = (1, 1)


def _box_to_capsule(geom) -> None:
    """Replace a leg link's box fitted to a mesh by the capsule along its long axis (radius: the
    mean of the two other half-sizes; legged_gym turns its legs' cylinders into capsules too):
    the corners of a calf's box reach below the foot once the calf leans (go2's front calves
    touched the floor standing), a thigh's below the knee."""
    size = np.asarray(geom.size, dtype=np.float64)
    axis = int(np.argmax(size))
    radius = float(np.mean(np.delete(size, axis)))
    half = max(float(size[axis]) - radius, 1e-4)
    # the capsule's axis is its local z: turn the box's long axis onto it
    to_z = {0: [0.5**0.5, 0.0, 0.5**0.5, 0.0], 1: [0.5**0.5, -(0.5**0.5), 0.0, 0.0]}
    quat = np.asarray(geom.quat, dtype=np.float64)
    if axis in to_z:
        out = np.zeros(4)
        mujoco.mju_mulQuat(out, quat, np.array(to_z[axis]))
        quat = out
    geom.type = mujoco.mjtGeom.mjGEOM_CAPSULE
    geom.quat = quat
    geom.size = [radius, half, 0.0]


def finish_floating_mjcf(
    spec: mujoco.MjSpec,
    prepared: PreparedSource,
    feet: list[str],
    imu: tuple[str, str | None],
    joint_names: list[str],
    home: np.ndarray,
    mjcf_path: Path,
) -> dict:
    """Add the free joint, floor, IMU and foot sites and sensors (module docstring) to ``spec``
    and write the MJCF to ``mjcf_path``. ``imu``: (link, MJCF site or None).

    Returns:
        ``{"feet": foot site names, "foot_shapes": foot -> description, "standing_height": m,
        "notes": lines on the floor's contact bits}``.

    Raises:
        RobotImportError: a foot link without a collision geometry, or whose geometry touches
            nothing (:func:`floor_contact_bits`).
    """
    model = compile_built(spec)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)  # base at the origin, joints at 0
    shapes, foot_geoms, contact_notes = {}, {}, []
    for foot in feet:
        model, data, foot_geoms[foot], shapes[foot] = add_foot_site(
            spec, model, data, prepared, foot, contact_notes
        )
    on_feet = {name for names in foot_geoms.values() for name in names}
    _leg_geoms(spec, prepared, on_feet)
    drop_unused_meshes(spec)
    _add_imu(spec, model, data, imu)

    model, height = _standing_height(spec, prepared, home, foot_geoms)
    root = spec.body(prepared.root_link)
    root.pos = [0.0, 0.0, height]
    root.quat = [1.0, 0.0, 0.0, 0.0]
    free = root.add_freejoint(name=FREE_JOINT)
    if root.childclass:  # else MuJoCo writes it class="main" there, which Pinocchio cannot read
        free.classname = spec.find_default(root.childclass)
    contype, conaffinity, floor_notes = floor_contact_bits(model, prepared, foot_geoms)
    floor_notes = contact_notes + floor_notes
    spec.worldbody.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 0.05], rgba=[0.5] * 3 + [1],
        contype=contype, conaffinity=conaffinity,
    )  # fmt: skip
    if (sun := spec.light("sun")) is not None:  # the file's own (a robot-import output's)
        spec.delete(sun)
    spec.worldbody.add_light(
        name="sun", pos=[0, 0, 3], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL
    )
    _write(spec, prepared, shapes, mjcf_path)
    return {
        "feet": list(feet), "foot_shapes": shapes, "standing_height": height, "notes": floor_notes,
    }  # fmt: skip


def _standing_height(spec, prepared: PreparedSource, home: np.ndarray, foot_geoms: dict):
    """``(model, height)``: ``spec`` compiled, and the root's height (m) at which the lowest
    point of the feet touches the floor at the home pose ``home`` (qpos, no free joint yet)."""
    model = compile_built(spec)
    data = mujoco.MjData(model)
    data.qpos[:] = home
    mujoco.mj_kinematics(model, data)
    bottom = min(
        float(geom_points(model, g, data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3))[:, 2].min())
        for names in foot_geoms.values()
        for g in (model.geom(n).id for n in names)
    )
    root_z = float(data.xpos[model.body(prepared.root_link).id][2])  # an MJCF places its root
    height = _sig(root_z - bottom, 4)
    return model, height


def _write(spec, prepared: PreparedSource, shapes: dict[str, str], mjcf_path: Path) -> None:
    """``spec`` compiled once more and written to ``mjcf_path`` (meshdir as the source gave it),
    under a comment saying what robot-import added."""
    compile_built(spec)
    xml = spec.to_xml()
    if prepared.meshdir_abs is not None:
        xml = xml.replace(
            f'meshdir="{prepared.meshdir_abs}"', f'meshdir="{prepared.meshdir_uri}"', 1
        )
    spheres = all(shape.startswith("a sphere") for shape in shapes.values())
    feet_words = "foot spheres" if spheres else "foot sites around the foot geoms"
    header = (
        f"<!-- Generated by robot-import (floating base) from {prepared.display} with MuJoCo's "
        f"{prepared.kind} compiler (mujoco.MjSpec). Radians, explicit inertials, no actuators "
        "(Robot.mjspec adds them per control mode). A free joint 'root' on the base, a flat "
        f"floor, an IMU site with gyro and accelerometer, {feet_words} with touch sensors. -->\n"
    )
    mjcf_path.write_text(header + xml, encoding="utf-8")


def _leg_geoms(spec: mujoco.MjSpec, prepared: PreparedSource, on_feet: set[str]) -> None:
    """On the bodies a hinge moves (legs), each geom the importer fitted and not a foot's: a
    mesh's hull reduced (:func:`~sim2real.robots.importer.leg_hulls.reduce_hull`), a box made
    the capsule along its long axis (as legged_gym's)."""
    for body in spec.bodies:  # leg links (bodies a hinge moves)
        if any(j.type == mujoco.mjtJoint.mjJNT_HINGE for j in body.joints):
            for geom in list(body.geoms):
                if geom.name in prepared.fitted_geoms and geom.name not in on_feet:
                    if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
                        reduce_hull(spec, geom)
                    elif geom.type == mujoco.mjtGeom.mjGEOM_BOX:  # as legged_gym's
                        _box_to_capsule(geom)


def floor_contact_bits(
    model: mujoco.MjModel, prepared: PreparedSource, foot_geoms: dict[str, list[str]]
) -> tuple[int, int, list[str]]:
    """The importer's floor's ``contype`` and ``conaffinity`` and the lines saying why.

    MuJoCo collides geoms ``a`` and ``b`` when ``contype_a & conaffinity_b`` or ``contype_b &
    conaffinity_a`` (or a ``<contact><pair>`` names both). The floor starts from the bits of the
    file's own floor (a scene file's plane, ``prepared.floor_bits``), else MuJoCo's default
    ``(1, 1)``; each foot none of whose geoms would touch it then widens it by its geoms' bits
    (Menagerie's Cassie: feet ``contype`` 2 and 4, a scene floor ``conaffinity`` 15). The other
    bodies whose geoms can touch something but not the floor are named.

    Raises:
        RobotImportError: a foot whose geoms have ``contype = conaffinity = 0`` and no pair with
            the floor (it touches nothing).
    """
    contype, conaffinity = prepared.floor_bits or DEFAULT_FLOOR_BITS
    origin = "the file's floor" if prepared.floor_bits else "MuJoCo's default floor"
    paired = {
        p["geom1"] if p["geom2"] == prepared.scene_geom else p["geom2"]
        for p in prepared.pairs
        if prepared.scene_geom in (p["geom1"], p["geom2"])
    }
    bits = {
        model.geom(g).name: (int(model.geom_contype[g]), int(model.geom_conaffinity[g]))
        for g in range(model.ngeom)
    }

    def touches(name: str) -> bool:
        ct, ca = bits[name]
        return name in paired or bool(ct & conaffinity) or bool(contype & ca)

    notes = []
    for foot, names in foot_geoms.items():
        if any(touches(n) for n in names):
            continue
        able = [n for n in names if bits[n] != (0, 0)]
        if not able:
            raise RobotImportError(
                f"{prepared.path}: foot {foot}: its geoms {names} have contype = conaffinity = 0 "
                "and no <contact><pair> with the floor: the foot touches nothing; expected "
                "collision geoms (contype or conaffinity set) or pairs with the floor"
            )
        old = (contype, conaffinity)
        for n in able:
            contype, conaffinity = contype | bits[n][1], conaffinity | bits[n][0]
        notes.append(
            f"floor contype/conaffinity {old} ({origin}) -> {(contype, conaffinity)}: foot "
            f"{foot}'s geoms {able} (contype, conaffinity {sorted({bits[n] for n in able})}) did "
            "not touch it"
        )
    bodies = sorted(
        {
            model.body(model.geom_bodyid[model.geom(n).id]).name
            for n, b in bits.items()
            if b != (0, 0) and model.geom_bodyid[model.geom(n).id] > 0 and not touches(n)
        }
    )
    if bodies:
        notes.append(
            f"bodies {bodies} have collision geoms that do not touch the floor (contype/"
            f"conaffinity {(contype, conaffinity)}): they pass through it, as in the file's bits"
        )
    return contype, conaffinity, notes


def _add_imu(spec, model, data, imu: tuple[str, str | None]) -> None:
    """The ``imu`` site (at the IMU link's frame, or at the MJCF's IMU site) on the nearest body
    a joint moves, and its gyro and accelerometer."""
    link, site = imu
    b = model.body(link).id
    anc = moving_ancestor(model, b)
    if site is None:
        pos, xmat = data.xpos[b], data.xmat[b]
    else:
        s = model.site(site).id
        pos, xmat = data.site_xpos[s], data.site_xmat[s]
    quat, inv, imu_quat = np.zeros(4), np.zeros(4), np.zeros(4)
    mujoco.mju_mat2Quat(quat, xmat)
    mujoco.mju_negQuat(inv, data.xquat[anc])
    mujoco.mju_mulQuat(imu_quat, inv, quat)
    old = spec.site(IMU_SITE)
    if old is not None:  # the MJCF's own 'imu' site: replaced by the one placed here
        spec.delete(old)
    spec.body(model.body(anc).name).add_site(
        name=IMU_SITE, size=[0.01, 0.01, 0.01], pos=in_body_frame(data, anc, pos), quat=imu_quat
    )
    for kind, name in (
        (mujoco.mjtSensor.mjSENS_GYRO, "imu_gyro"),
        (mujoco.mjtSensor.mjSENS_ACCELEROMETER, "imu_accelerometer"),
    ):
        spec.add_sensor(name=name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=IMU_SITE)
