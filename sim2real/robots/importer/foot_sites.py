"""A floating-base robot's foot in its MJCF: the geoms that touch the floor, the site around
them and its touch sensor (:func:`add_foot_site`), and the link that carries them
(:func:`foot_with_geometry`).

The foot's collision geometry stays as the description has it; only a hull the importer fitted
to a compact foot mesh becomes the sphere of its bounding box's mean half-size (a point foot, as
legged simulators model a quadruped's, ``POINT_FOOT_ASPECT``). The site ``<foot>`` encloses the
foot's geoms (a sphere around one sphere, else a box, ``TOUCH_MARGIN`` larger); a foot of
several geoms whose only sphere reaches farthest from its joint (unitree_mujoco's Go2 and B2) has
it around that sphere alone (:func:`_distal_sphere`). Geoms and site go on the nearest body a
joint moves: Pinocchio's MJCF parser misplaces sites of joint-less child bodies, and a touch
sensor counts the contacts of its own body. The module docstring of
:mod:`sim2real.robots.importer.floating_mjcf` places this in the whole MJCF.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.robots.importer.mjcf_geoms import hull_points, hull_to_box
from sim2real.robots.importer.model import _sig
from sim2real.robots.importer.source import PreparedSource, RobotImportError, compile_built

#: The foot site's (its touch sensor's) margin over the foot's geoms, m: the contact point of a
#: geom on a plane lies inside the geom by half the penetration (a few mm at most).
TOUCH_MARGIN = 0.005
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


def moving_ancestor(model: mujoco.MjModel, body: int) -> int:
    """The nearest of ``body`` and its ancestors that a joint moves (the root without one)."""
    while body > 0 and model.body_jntnum[body] == 0 and model.body_parentid[body] > 0:
        body = model.body_parentid[body]
    return body


def in_body_frame(data: mujoco.MjData, anc: int, pos: np.ndarray) -> np.ndarray:
    """(3,) m: world point ``pos`` in body ``anc``'s frame."""
    return data.xmat[anc].reshape(3, 3).T @ (pos - data.xpos[anc])


def add_foot_site(
    spec: mujoco.MjSpec,
    model: mujoco.MjModel,
    data: mujoco.MjData,
    prepared: PreparedSource,
    foot: str,
    contact_notes: list[str],
) -> tuple[mujoco.MjModel, mujoco.MjData, list[str], str]:
    """Foot ``foot``'s geoms moved to the body a joint moves (a fitted compact hull made a
    sphere), its site and ``<foot>_touch`` sensor added to ``spec``; a line appended to
    ``contact_notes`` where spheres are not one distal contact sphere.

    Args:
        model, data: ``spec`` compiled, at its kinematics (base at the origin, joints at 0).

    Returns:
        ``(model, data, the foot's geom names, the foot's shape in words)``: the model and data
        recompiled where a geom became a sphere, else those given.

    Raises:
        RobotImportError: the foot link has no collision geometry.
    """
    model, data, anc, kept, points, spheres, fitted_sphere = _gather(
        spec, model, data, prepared, foot
    )
    host = spec.body(model.body(anc).name)
    shape = _add_site(host, model, anc, foot, kept, points, spheres, fitted_sphere, contact_notes)
    spec.add_sensor(
        name=f"{foot}_touch",
        type=mujoco.mjtSensor.mjSENS_TOUCH,
        objtype=mujoco.mjtObj.mjOBJ_SITE,
        objname=foot,
    )
    return model, data, [g.name for g in kept], shape


def _gather(spec: mujoco.MjSpec, model, data, prepared: PreparedSource, foot: str):
    """Foot ``foot``'s geoms on the nearest body a joint moves (``anc``), a fitted compact hull
    made a sphere: ``(model, data, anc, kept geoms, each one's bounding points in anc's frame,
    the spheres as (index, centre, radius), whether a sphere was fitted)``."""
    body = spec.body(foot)
    b = model.body(foot).id
    if not list(body.geoms):
        raise RobotImportError(
            f"{prepared.path}: <link name='{foot}'> (a foot): no collision geometry; "
            "expected one (its contact geometry)"
        )
    anc = moving_ancestor(model, b)
    host = spec.body(model.body(anc).name)
    rot_anc = data.xmat[anc].reshape(3, 3)
    points, kept, fitted_sphere, spheres = [], [], False, []
    for geom in list(body.geoms):
        g = model.geom(geom.name).id
        pos = in_body_frame(data, anc, data.geom_xpos[g])
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
        points.append(geom_points(model, g, pos, rot))
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE:
            spheres.append((len(kept), pos, float(model.geom_size[g, 0])))
        if anc != b:  # the touch sensor counts the contacts of its site's body
            spec_pos = np.asarray(geom.pos, dtype=np.float64)
            spec_quat = np.asarray(geom.quat, dtype=np.float64)
            spec_quat = spec_quat / np.linalg.norm(spec_quat)
            rel = in_body_frame(data, anc, data.xpos[b] + data.xmat[b].reshape(3, 3) @ spec_pos)
            q, inv = np.zeros(4), np.zeros(4)
            mujoco.mju_negQuat(inv, data.xquat[anc])
            mujoco.mju_mulQuat(q, inv, data.xquat[b])
            mujoco.mju_mulQuat(q, q.copy(), spec_quat)
            geom = _move_geom(spec, geom, host, rel, q)
        kept.append(geom)
    return model, data, anc, kept, points, spheres, fitted_sphere


def _add_site(host, model, anc: int, foot: str, kept, points, spheres, fitted_sphere, notes):
    """The site ``foot`` on ``host`` around the foot's contact geometry (module docstring);
    returns the foot's shape in words."""
    pts = np.vstack(points)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    one = kept[0] if len(kept) == 1 else None
    anchor = _joint_anchor(model, anc)
    distal = None if one is not None else _distal_sphere(points, spheres, anchor)
    if one is not None and one.type == mujoco.mjtGeom.mjGEOM_SPHERE:
        r = float(one.size[0])
        host.add_site(name=foot, size=[r + TOUCH_MARGIN, 0, 0], pos=(lo + hi) / 2)
        made = " (the mean half-size of its compact mesh's box)" if fitted_sphere else ""
        shape = f"a sphere of radius {r:g} m{made}"
    elif distal is not None:  # unitree_mujoco's calf: shin geoms and the foot's sphere
        i, centre, r = distal
        host.add_site(name=foot, size=[r + TOUCH_MARGIN, 0, 0], pos=centre)
        others = sorted({_kind(g) for j, g in enumerate(kept) if j != i})
        shape = (
            f"a sphere of radius {r:g} m ({kept[i].name}), the distal end of its "
            f"{len(kept)} geoms ({', '.join(others)} above it: no foot contact)"
        )
    else:
        if spheres:
            names = [kept[i].name for i, _, _ in spheres]
            notes.append(
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
        shape = f"{count} ({', '.join(kinds)}) in a {size} cm box"
    return shape


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


def geom_points(model: mujoco.MjModel, g: int, pos, rot) -> np.ndarray:
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
