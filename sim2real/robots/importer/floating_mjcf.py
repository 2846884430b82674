"""The MJCF of a floating-base (legged) robot: :func:`finish_floating_mjcf`.

A floating-base robot gets, in its MJCF:

- a MuJoCo free joint ``root`` on the root link (Pinocchio's MJCF parser reads it as its
  free-flyer root joint, ``pin.JointModelFreeFlyer``), the base placed so that the feet touch
  the floor at the home pose;
- a flat floor (a plane ``floor`` in the world body) and a light;
- a site ``imu`` at the IMU (``--imu LINK`` or an MJCF site, else a site or link named
  ``imu``, else the root link) with MuJoCo ``gyro`` and ``accelerometer`` sensors;
- per foot (leaf links at the end of the longest chains of movable joints, or ``--foot LINK``):
  the foot's collision geometry kept as the description has it (a sole's box, capsules, several
  contact spheres, a foot mesh's convex hull); only a hull the importer fitted to a compact foot
  mesh becomes the sphere of its bounding box's mean half-size (a point foot, as legged
  simulators model a quadruped's, ``POINT_FOOT_ASPECT``). A site ``<foot>`` encloses the foot's
  geoms (a sphere around one sphere, else a box, ``TOUCH_MARGIN`` larger) with a MuJoCo
  ``touch`` sensor on it (the normal force of the contacts inside the site: foot contact). A
  foot of several geoms whose only sphere reaches farthest from its joint (unitree_mujoco's Go2
  and B2: the calf's shin cylinders or boxes and the foot's sphere at its end,
  :func:`_distal_sphere`) has the site around that sphere alone: its centre and radius are the
  foot the base estimator and the fall check read; with spheres but none so placed, a note says
  the site encloses them all.
  Geoms and site go on the nearest body a joint moves (the calf): Pinocchio's MJCF parser
  misplaces sites of joint-less child bodies, and a touch sensor counts the contacts of its
  own body;
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

from sim2real.robots.importer.leg_hulls import reduce_hull
from sim2real.robots.importer.mjcf_geoms import drop_unused_meshes, hull_points, hull_to_box
from sim2real.robots.importer.model import _sig
from sim2real.robots.importer.source import PreparedSource, RobotImportError, compile_built

#: Name of the MuJoCo free joint of the base (Pinocchio names its free-flyer joint the same).
FREE_JOINT = "root"
#: Site of the IMU (its gyro and accelerometer sensors are ``imu_gyro``, ``imu_accelerometer``).
IMU_SITE = "imu"
#: The foot site's (its touch sensor's) margin over the foot's geoms, m: the contact point of a
#: geom on a plane lies inside the geom by half the penetration (a few mm at most).
TOUCH_MARGIN = 0.005
#: ``(contype, conaffinity)`` of a plane that sets neither (MuJoCo's defaults): the floor of a
#: robot file without one, before the feet widen it (:func:`floor_contact_bits`).
DEFAULT_FLOOR_BITS = (1, 1)
#: A foot's box fitted to a mesh whose shortest side is at least this fraction of its longest
#: is a point foot (a quadruped's rubber ball, go2's foot_convex.stl) and becomes the sphere of
#: its mean half-size; a flat sole (a humanoid's) is far thinner than long and stays a box.
POINT_FOOT_ASPECT = 0.5


def foot_with_geometry(spec: mujoco.MjSpec, prepared: PreparedSource, foot: str):
    """``(link, note)``: the link carrying foot ``foot``'s collision geometry and a line saying
    why when it is not ``foot`` (None then). A link without geometry fixed to its parent (holosoma's
    massless ``*_foot_contact_point`` under each ankle link) hands the foot to the nearest
    ancestor through fixed joints that has geometry; a link without geometry anywhere up there
    stays (:func:`finish_floating_mjcf` refuses it)."""
    link = foot
    while not list(spec.body(link).geoms) and link in prepared.parent:
        parent, _, kind = prepared.parent[link]
        if kind != "fixed" or parent == "world":
            break
        link = parent
    if link == foot or not list(spec.body(link).geoms):
        return foot, None
    return link, (
        f"foot {foot} has no collision geometry and is fixed to {link}: the foot is {link} "
        "(its geoms and the foot site)"
    )


def _moving_ancestor(model: mujoco.MjModel, body: int) -> int:
    while body > 0 and model.body_jntnum[body] == 0 and model.body_parentid[body] > 0:
        body = model.body_parentid[body]
    return body


def _relative(data: mujoco.MjData, anc: int, pos: np.ndarray) -> np.ndarray:
    return data.xmat[anc].reshape(3, 3).T @ (pos - data.xpos[anc])


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


#: Geom attributes copied when a foot geom moves to the body a joint moves.
_GEOM_FIELDS = (
    "type", "size", "contype", "conaffinity", "condim", "priority", "friction", "solmix",
    "solref", "solimp", "margin", "gap", "rgba", "group", "meshname", "fromto",
)  # fmt: skip


def _move_geom(spec: mujoco.MjSpec, geom, host, pos: np.ndarray, quat: np.ndarray):
    """A copy of ``geom`` on body ``host`` at ``pos``, ``quat`` (host frame); ``geom`` deleted."""
    name = geom.name
    copy = host.add_geom()
    for attr in _GEOM_FIELDS:
        setattr(copy, attr, getattr(geom, attr))
    copy.pos, copy.quat = pos, quat
    spec.delete(geom)
    copy.name = name
    return copy


def _geom_points(model: mujoco.MjModel, g: int, pos, rot) -> np.ndarray:
    """Points whose bounding box in the frame of ``pos``/``rot`` (the geom's pose there, m)
    bounds geom ``g``: exact for spheres, capsules, boxes and meshes (their vertices); the
    bounding box's corners for cylinders and ellipsoids."""
    kind, size = model.geom_type[g], model.geom_size[g]
    axes = np.vstack([np.eye(3), -np.eye(3)])
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return pos + size[0] * axes
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        ends = [pos + rot[:, 2] * size[1], pos - rot[:, 2] * size[1]]
        return np.vstack([end + size[0] * axes for end in ends])
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[g]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        return pos + model.mesh_vert[start : start + count] @ rot.T
    half = {
        mujoco.mjtGeom.mjGEOM_CYLINDER: [size[0], size[0], size[1]],
        mujoco.mjtGeom.mjGEOM_ELLIPSOID: size,
    }.get(kind, size)
    signs = np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T
    return pos + (signs * np.asarray(half)) @ rot.T


def _kind(geom) -> str:
    """A geom's type in words (``box``, ``sphere``, ...)."""
    return mujoco.mjtGeom(int(geom.type)).name[7:].lower()


def _joint_anchor(model: mujoco.MjModel, body: int) -> np.ndarray:
    """(3,) m: the anchor of body ``body``'s first joint in its frame (its origin without one)."""
    if model.body_jntnum[body] == 0:
        return np.zeros(3)
    return np.array(model.jnt_pos[model.body_jntadr[body]], dtype=np.float64)


def _distal_sphere(points: list[np.ndarray], spheres: list, anchor: np.ndarray):
    """``(index, centre, radius)`` of a foot's contact sphere among its several geoms, or None.

    The contact sphere is the foot's only sphere geom when it reaches farther from the joint's
    ``anchor`` than every other geom (``points``: each geom's bounding points, host frame, m;
    ``spheres``: ``(index, centre, radius)`` of the sphere geoms): unitree_mujoco's Go2 and B2
    model each foot as a sphere geom on the calf at its distal end, beside the shin's cylinders
    or boxes, and that sphere is what touches the floor. A foot of several spheres (a sole's
    corner spheres) or whose sphere is not its distal end has none: its site encloses all."""
    if len(spheres) != 1:
        return None
    i, centre, radius = spheres[0]
    reach = [float(np.linalg.norm(p - anchor, axis=1).max()) for p in points]
    reach[i] = float(np.linalg.norm(np.asarray(centre) - anchor)) + radius
    if any(r >= reach[i] for j, r in enumerate(reach) if j != i):
        return None
    return i, np.asarray(centre, dtype=np.float64), radius


def _point_foot(spec: mujoco.MjSpec, geom, fitted: set[str]) -> bool:
    """Whether a foot geom is a hull or box the importer fitted to a compact mesh (the sides of
    its bounding box within ``POINT_FOOT_ASPECT`` of each other): it becomes a sphere."""
    if geom.name not in fitted:
        return False
    if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
        pts = hull_points(spec, geom)
        size = (pts.max(axis=0) - pts.min(axis=0)) / 2
    elif geom.type == mujoco.mjtGeom.mjGEOM_BOX:
        size = np.asarray(geom.size, dtype=np.float64)
    else:
        return False
    return float(size.min() / size.max()) >= POINT_FOOT_ASPECT


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
        body = spec.body(foot)
        b = model.body(foot).id
        if not list(body.geoms):
            raise RobotImportError(
                f"{prepared.path}: <link name='{foot}'> (a foot): no collision geometry; "
                "expected one (its contact geometry)"
            )
        anc = _moving_ancestor(model, b)
        host = spec.body(model.body(anc).name)
        rot_anc = data.xmat[anc].reshape(3, 3)
        points, kept, fitted_sphere, spheres = [], [], False, []
        for geom in list(body.geoms):
            g = model.geom(geom.name).id
            pos = _relative(data, anc, data.geom_xpos[g])
            rot = rot_anc.T @ data.geom_xmat[g].reshape(3, 3)
            if _point_foot(spec, geom, prepared.fitted_geoms):  # a point foot, as legged sims
                if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
                    hull_to_box(spec, geom)
                geom.type = mujoco.mjtGeom.mjGEOM_SPHERE
                geom.size = [_sig(float(np.mean(geom.size)), 3), 0.0, 0.0]
                fitted_sphere = True
                model = compile_built(spec)  # the sphere's size for the points below
                data = mujoco.MjData(model)
                mujoco.mj_kinematics(model, data)
                g = model.geom(geom.name).id
            points.append(_geom_points(model, g, pos, rot))
            if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE:
                spheres.append((len(kept), pos, float(model.geom_size[g, 0])))
            if anc != b:  # the touch sensor counts the contacts of its site's body
                spec_pos = np.asarray(geom.pos, dtype=np.float64)
                spec_quat = np.asarray(geom.quat, dtype=np.float64)
                spec_quat = spec_quat / np.linalg.norm(spec_quat)
                rel = _relative(data, anc, data.xpos[b] + data.xmat[b].reshape(3, 3) @ spec_pos)
                q, inv = np.zeros(4), np.zeros(4)
                mujoco.mju_negQuat(inv, data.xquat[anc])
                mujoco.mju_mulQuat(q, inv, data.xquat[b])
                mujoco.mju_mulQuat(q, q.copy(), spec_quat)
                geom = _move_geom(spec, geom, host, rel, q)
            kept.append(geom)
        foot_geoms[foot] = [g.name for g in kept]
        pts = np.vstack(points)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        one = kept[0] if len(kept) == 1 else None
        anchor = _joint_anchor(model, anc)
        distal = None if one is not None else _distal_sphere(points, spheres, anchor)
        if one is not None and one.type == mujoco.mjtGeom.mjGEOM_SPHERE:
            r = float(one.size[0])
            host.add_site(name=foot, size=[r + TOUCH_MARGIN, 0, 0], pos=(lo + hi) / 2)
            made = " (the mean half-size of its compact mesh's box)" if fitted_sphere else ""
            shapes[foot] = f"a sphere of radius {r:g} m{made}"
        elif distal is not None:  # unitree_mujoco's calf: shin geoms and the foot's sphere
            i, centre, r = distal
            host.add_site(name=foot, size=[r + TOUCH_MARGIN, 0, 0], pos=centre)
            others = sorted({_kind(g) for j, g in enumerate(kept) if j != i})
            shapes[foot] = (
                f"a sphere of radius {r:g} m ({kept[i].name}), the distal end of its "
                f"{len(kept)} geoms ({', '.join(others)} above it: no foot contact)"
            )
        else:
            if spheres:
                names = [kept[i].name for i, _, _ in spheres]
                contact_notes.append(
                    f"foot {foot}: no one contact sphere among its {len(kept)} geoms (spheres "
                    f"{names}; a point foot is one sphere reaching farthest from its joint): the "
                    "foot site encloses them all, as a sole's, and the estimator reads the foot "
                    "at the site's centre with no contact radius"
                )
            host.add_site(
                name=foot,
                type=mujoco.mjtGeom.mjGEOM_BOX,
                size=(hi - lo) / 2 + TOUCH_MARGIN,
                pos=(lo + hi) / 2,
            )
            kinds = sorted({_kind(g) for g in kept})
            size = " x ".join(f"{x * 100:.1f}" for x in hi - lo)
            count = f"{len(kept)} geoms" if len(kept) > 1 else "1 geom"
            shapes[foot] = f"{count} ({', '.join(kinds)}) in a {size} cm box"
        spec.add_sensor(
            name=f"{foot}_touch",
            type=mujoco.mjtSensor.mjSENS_TOUCH,
            objtype=mujoco.mjtObj.mjOBJ_SITE,
            objname=foot,
        )
    on_feet = {name for names in foot_geoms.values() for name in names}
    for body in spec.bodies:  # leg links (bodies a hinge moves)
        if any(j.type == mujoco.mjtJoint.mjJNT_HINGE for j in body.joints):
            for geom in list(body.geoms):
                if geom.name in prepared.fitted_geoms and geom.name not in on_feet:
                    if geom.type == mujoco.mjtGeom.mjGEOM_MESH:
                        reduce_hull(spec, geom)
                    elif geom.type == mujoco.mjtGeom.mjGEOM_BOX:  # as legged_gym's
                        _box_to_capsule(geom)
    drop_unused_meshes(spec)
    _add_imu(spec, model, data, imu)

    # standing height: the lowest point of the feet touches the floor at the home pose
    model = compile_built(spec)
    data = mujoco.MjData(model)
    data.qpos[:] = home
    mujoco.mj_kinematics(model, data)
    bottom = min(
        float(
            _geom_points(model, g, data.geom_xpos[g], data.geom_xmat[g].reshape(3, 3))[:, 2].min()
        )
        for names in foot_geoms.values()
        for g in (model.geom(n).id for n in names)
    )
    root_z = float(data.xpos[model.body(prepared.root_link).id][2])  # an MJCF places its root
    height = _sig(root_z - bottom, 4)
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
    return {
        "feet": list(feet), "foot_shapes": shapes, "standing_height": height, "notes": floor_notes,
    }  # fmt: skip


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
    anc = _moving_ancestor(model, b)
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
        name=IMU_SITE, size=[0.01, 0.01, 0.01], pos=_relative(data, anc, pos), quat=imu_quat
    )
    for kind, name in (
        (mujoco.mjtSensor.mjSENS_GYRO, "imu_gyro"),
        (mujoco.mjtSensor.mjSENS_ACCELEROMETER, "imu_accelerometer"),
    ):
        spec.add_sensor(name=name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=IMU_SITE)
