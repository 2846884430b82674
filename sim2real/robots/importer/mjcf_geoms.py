"""The geoms of an MJCF robot for the importer (:mod:`sim2real.robots.importer.mjcf`): missing mesh files
(:func:`missing_meshes`) and the collision geometry the toolkit keeps (:func:`simplify_geoms`:
visual-only geoms beside collision geoms dropped, each mesh geom its own convex hull written into
the MJCF, ``MESH_COLLISION``)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import mujoco
import numpy as np

from sim2real.robots.importer.source import DROP_MISSING, RobotImportError
from sim2real.robots.importer.urdf import COLLISION_BOXES

#: What a collision mesh of an MJCF becomes (with ``COLLISION_BOXES``): ``"hull"``, its convex
#: hull as an inline mesh (``<mesh vertex=...>``, the hull's vertices in the geom's own frame):
#: the shape MuJoCo collides a mesh as (its qhull hull, ``mesh_graph``), read by Pinocchio's MJCF
#: parser as a ``coal.Convex`` whose distance costs about what a box's does, and no mesh file
#: to ship; ``"box"``: its bounding box in the geom's frame, which counts feet passing close as
#: touching.
MESH_COLLISION = "hull"


@contextmanager
def mesh_collision(kind: str) -> Iterator[None]:
    """``MESH_COLLISION`` set to ``kind`` (``"hull"`` or ``"box"``) for the ``with`` block
    (``robot-import --mesh-boxes``).

    Raises:
        ValueError: another ``kind``.
    """
    global MESH_COLLISION
    if kind not in ("hull", "box"):
        raise ValueError(f"mesh collision {kind!r}: expected 'hull' or 'box'")
    saved, MESH_COLLISION = MESH_COLLISION, kind
    try:
        yield
    finally:
        MESH_COLLISION = saved


#: Suffix of the inline hull mesh made for a geom (``<body>_<k>_hull``, the body's k-th geom).
HULL_SUFFIX = "_hull"


def _mesh_file(spec: mujoco.MjSpec, mesh, path: Path) -> Path:
    """Where MuJoCo looks for a mesh asset's file: in ``meshdir`` relative to the model's folder
    (unless absolute)."""
    folder = spec.meshdir or ""
    base = Path(spec.modelfiledir or str(path.parent))
    return (base / folder / mesh.file).resolve()


def missing_meshes(spec: mujoco.MjSpec, path: Path, drop: bool, notes: list[str]) -> None:
    """Refuse mesh assets whose file is missing, or (``drop``) delete them and the geoms that
    use them, each noted."""
    missing = {m.name: _mesh_file(spec, m, path) for m in spec.meshes if m.file}
    missing = {k: v for k, v in missing.items() if not v.is_file()}
    if not missing:
        return
    users = {k: [g for g in spec.geoms if g.meshname == k] for k in missing}
    if not drop:
        name, file = next(iter(missing.items()))
        where = [g.parent.name or "world" for g in users[name]]
        more = f" ({len(missing) - 1} more missing)" if len(missing) > 1 else ""
        raise RobotImportError(
            f"{path}: <mesh name='{name}'>: file {file} does not exist (used by geoms of bodies "
            f"{where}){more}; {DROP_MISSING}"
        )
    for name, file in missing.items():
        where = [g.name or f"{g.parent.name or 'world'} (unnamed)" for g in users[name]]
        for geom in users[name]:
            spec.delete(geom)
        spec.delete(spec.mesh(name))
        notes.append(f"mesh '{name}' ({file}) missing: its geoms {where} dropped")


def simplify_geoms(
    spec: mujoco.MjSpec,
    model: mujoco.MjModel,
    notes,
    link_boxes: bool = False,
    keep: set[str] = frozenset(),
) -> tuple[str | None, set[tuple[str, int]]]:
    """Drop visual-only geoms beside collision geoms; each mesh geom becomes its convex hull
    (``MESH_COLLISION`` ``"hull"``: an inline mesh ``<body>_<k>_hull``) or its bounding box
    (``"box"``) in the mesh's own frame (``COLLISION_BOXES``; ``link_boxes``: one box per body,
    in the body frame, around its mesh geoms, added after its other geoms); other geoms stay as
    they are; every geom in group 0. ``keep``: names of geoms explicit ``<contact><pair>``s
    name, never dropped as visual-only.

    Returns ``(meshdir, fitted)``: the absolute mesh folder when mesh files are kept
    (``COLLISION_BOXES`` False), else None; the ``(body, k)`` of the hulls or boxes fitted
    (``k``: the geom's index in its body).
    """
    visual = 0
    boxed: list[str] = []
    for body in spec.bodies:
        geoms = list(body.geoms)
        if any(g.contype or g.conaffinity for g in geoms):
            for g in geoms:
                if not (g.contype or g.conaffinity) and g.name not in keep:
                    spec.delete(g)
                    visual += 1
            geoms = [g for g in geoms if g.contype or g.conaffinity or g.name in keep]
        if not COLLISION_BOXES:
            continue
        if link_boxes:
            boxed += _body_box(spec, body, geoms, model)
            continue
        for k, g in enumerate(geoms):
            if g.type == mujoco.mjtGeom.mjGEOM_MESH:
                if MESH_COLLISION == "hull":
                    _mesh_to_hull(spec, g, model, f"{body.name or 'world'}_{k}{HULL_SUFFIX}")
                else:
                    _mesh_to_box(g, model)
                boxed.append(g.name)
    for geom in spec.geoms:
        # Pinocchio's MJCF parser leaves group-3 geoms (the usual collision class) out of the
        # VISUAL geometry the guard and the importer check; the group only matters for drawing.
        geom.group = 0
    if visual:
        notes.append(f"{visual} visual-only geoms (contype = conaffinity = 0) dropped")
    if boxed and link_boxes:
        notes.append(f"mesh geoms replaced by one bounding box per body {boxed} (--link-boxes)")
    elif boxed and MESH_COLLISION == "hull":
        notes.append(
            f"{len(boxed)} mesh geoms replaced by their convex hulls, written into the MJCF "
            "(MESH_COLLISION)"
        )
    elif boxed:
        notes.append(
            f"{len(boxed)} mesh geoms replaced by their bounding boxes in the mesh frame, one "
            "box per geom (COLLISION_BOXES)"
        )
    fitted = {
        (body.name, k) for body in spec.bodies for k, g in enumerate(body.geoms) if g.name in boxed
    }
    drop_unused_meshes(spec)
    with_file = [m for m in spec.meshes if m.file]
    if not with_file:
        spec.meshdir = ""
        return None, fitted
    files = [Path(spec.meshdir, m.file).resolve() for m in with_file]
    base = Path(os.path.commonpath([str(f.parent) for f in files]))
    for mesh, file in zip(with_file, files, strict=True):
        mesh.file = Path(os.path.relpath(file, base)).as_posix()
    spec.meshdir = base.as_posix()
    return spec.meshdir, fitted


def _body_box(spec: mujoco.MjSpec, body, geoms, model: mujoco.MjModel) -> list[str]:
    """Replace a body's mesh geoms by one box around them (body frame); return its name."""
    meshes = [g for g in geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH]
    if not meshes:
        return []
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    corners = []
    for g in meshes:
        gid = model.geom(g.name).id
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, model.geom_quat[gid])
        aabb = model.geom_aabb[gid]
        corners.append(model.geom_pos[gid] + (aabb[:3] + signs * aabb[3:]) @ rot.reshape(3, 3).T)
    pts = np.vstack(corners)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    box = body.add_geom()
    box.type = mujoco.mjtGeom.mjGEOM_BOX
    box.pos = (lo + hi) / 2
    box.size = np.maximum((hi - lo) / 2, 5e-5)
    box.contype, box.conaffinity = meshes[0].contype, meshes[0].conaffinity
    box.rgba = meshes[0].rgba
    box.name = f"{body.name}_box"
    for g in meshes:
        spec.delete(g)
    return [box.name]


def _vertices_in_geom_frame(geom, model: mujoco.MjModel) -> np.ndarray:
    """(k, 3) m: the compiled vertices of mesh geom ``geom`` in the geom's own frame as the spec
    places it (``geom.pos``, ``geom.quat``; MuJoCo's compile re-centres a mesh, this undoes it)."""
    g = model.geom(geom.name).id
    mesh = int(model.geom_dataid[g])
    start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    vertices = model.mesh_vert[start : start + count].astype(np.float64)
    compiled = np.zeros(9)
    mujoco.mju_quat2Mat(compiled, model.geom_quat[g])
    in_body = model.geom_pos[g] + vertices @ compiled.reshape(3, 3).T
    quat = np.asarray(geom.quat, dtype=np.float64)
    own = np.zeros(9)
    mujoco.mju_quat2Mat(own, quat / np.linalg.norm(quat))
    return (in_body - np.asarray(geom.pos, dtype=np.float64)) @ own.reshape(3, 3)


def _mesh_to_hull(spec: mujoco.MjSpec, geom, model: mujoco.MjModel, name: str) -> None:
    """Turn a mesh geom into its convex hull: a new inline mesh ``name`` holding the
    vertices of the hull MuJoCo computed (``mesh_graph``: numvert, numface, vert_edgeadr,
    vert_globalid, ...), in the geom's own frame; the geom keeps its pose."""
    g = model.geom(geom.name).id
    mesh = int(model.geom_dataid[g])
    adr = int(model.mesh_graphadr[mesh])
    local = _vertices_in_geom_frame(geom, model)
    if adr >= 0:
        count = int(model.mesh_graph[adr])
        local = local[model.mesh_graph[adr + 2 + count : adr + 2 + 2 * count]]
    name = _free_mesh_name(spec, name, geom)
    hull = spec.add_mesh()
    hull.name = name
    hull.uservert = local.ravel()
    geom.meshname = hull.name


def _free_mesh_name(spec: mujoco.MjSpec, name: str, geom) -> str:
    """``name`` for the hull of ``geom`` when no mesh asset holds it; when the mesh holding it
    is ``geom``'s own and no other geom uses it (an MJCF robot-import wrote, its hulls already
    inline), that mesh is deleted and its name reused (a re-import keeps the names); else the
    first free ``name_2``, ``name_3``, ..."""
    taken = spec.mesh(name)
    if taken is None:
        return name
    users = [g for g in spec.geoms if g.meshname == name]
    if users == [geom]:
        spec.delete(taken)
        return name
    k = 2
    while spec.mesh(f"{name}_{k}") is not None:
        k += 1
    return f"{name}_{k}"


def hull_to_box(spec: mujoco.MjSpec, geom) -> None:
    """Turn a geom holding an inline hull (:func:`_mesh_to_hull`) into the box bounding it in
    the geom's frame (a leg's capsule and a point foot's sphere start from this box)."""
    _box_around(geom, hull_points(spec, geom))


def hull_points(spec: mujoco.MjSpec, geom) -> np.ndarray:
    """(k, 3) m: the vertices of the inline hull of ``geom``, in the geom's own frame."""
    return np.asarray(spec.mesh(geom.meshname).uservert, dtype=np.float64).reshape(-1, 3)


def drop_unused_meshes(spec: mujoco.MjSpec) -> None:
    """Delete the mesh assets no geom uses."""
    used = {g.meshname for g in spec.geoms if g.type == mujoco.mjtGeom.mjGEOM_MESH}
    for mesh in list(spec.meshes):
        if mesh.name not in used:
            spec.delete(mesh)


def _mesh_to_box(geom, model: mujoco.MjModel) -> None:
    """Turn a mesh geom into the box bounding its vertices in the geom's own frame (the frame
    the MJCF places the mesh file in: a CAD export's axes, such as a foot's sole)."""
    _box_around(geom, _vertices_in_geom_frame(geom, model))


def _box_around(geom, local: np.ndarray) -> None:
    """Make ``geom`` the box bounding ``local`` (k, 3) m, points in the geom's own frame."""
    lo, hi = local.min(axis=0), local.max(axis=0)
    quat = np.asarray(geom.quat, dtype=np.float64)
    quat = quat / np.linalg.norm(quat)
    own = np.zeros(9)
    mujoco.mju_quat2Mat(own, quat)
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.meshname = ""
    geom.pos = np.asarray(geom.pos, dtype=np.float64) + own.reshape(3, 3) @ ((lo + hi) / 2)
    geom.quat = quat
    geom.size = np.maximum((hi - lo) / 2, 5e-5)
