"""URDF reading for the importer: validation and preparation for MuJoCo's URDF compiler.

:func:`prepare_urdf` checks what the importer cannot guess (limits of continuous joints, meshes,
inertias, duplicate names, floating bases) and rewrites the URDF for ``mujoco.MjSpec``: mesh URIs
relative to one mesh folder, visuals dropped, each collision mesh replaced by its bounding box in
the mesh's own frame (read with coal; one box per mesh, ``COLLISION_BOXES``; primitives kept as
they are), missing mesh files refused or, with ``--drop-missing-meshes``, their elements dropped,
prismatic and mimic joints frozen, and a
``<mujoco><compiler>`` element (radians from the URDF, no static-body fusion, balanced inertias).
Its result is a :class:`sim2real.robots.importer.source.PreparedSource`.
"""

from __future__ import annotations

import copy
import itertools
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from sim2real.robots.importer.source import (
    DROP_MISSING,
    FLOATING_BASE,
    MIN_INERTIA,
    MIN_MASS,
    JointInfo,
    PreparedSource,
    RobotImportError,
    SrdfInfo,
    _display,
)
from sim2real.robots.packages import PACKAGE_SCHEME, package_path_hint, package_root
from sim2real.robots.robot import RobotSpecError

#: Mesh formats MuJoCo decodes itself; others (COLLADA .dae) are replaced by a fitted box.
MUJOCO_MESH_FORMATS = (".stl", ".obj", ".msh")
#: Each collision mesh is replaced by its bounding box in the mesh's own frame (one box per
#: mesh, primitives kept as they are): the guard checks every listed pair each tick with coal,
#: and mesh-mesh pairs (85 on the SO-101) made 60 simulated seconds take over 10 minutes; boxes
#: keep it to seconds. Set False to keep the meshes (package:// meshdir).
COLLISION_BOXES = True


def _attr(el: ET.Element | None, attr: str) -> str | None:
    return None if el is None else el.get(attr)


def _float(el: ET.Element | None, attr: str) -> float | None:
    if el is None or el.get(attr) is None:
        return None
    try:
        return float(el.get(attr))
    except ValueError:
        return None


def _resolve_mesh(uri: str, urdf: Path) -> tuple[Path, str | None]:
    """(file, package name or None) of a URDF mesh filename."""
    if uri.startswith(PACKAGE_SCHEME):
        package, _, rest = uri[len(PACKAGE_SCHEME) :].partition("/")
        try:
            return package_root(package) / rest, package
        except RobotSpecError:
            return Path(uri), None
    if uri.startswith("file://"):
        return Path(uri[len("file://") :]), None
    return (urdf.parent / uri).resolve(), None


def _rpy_matrix(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _box_from_mesh(file: Path, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre, full size) of the axis-aligned bounding box of a mesh in its own frame (m)."""
    import coal

    mesh = coal.MeshLoader().load(str(file), scale)
    v = np.asarray(mesh.vertices(), dtype=np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return (lo + hi) / 2, np.maximum(hi - lo, 1e-4)


def _legs(links, parent) -> int:
    """Chains leaving the root link that carry 3 or more movable joints (legs, arms of a torso)."""
    children: dict[str, list[str]] = {}
    for child, (par, _, _) in parent.items():
        children.setdefault(par, []).append(child)
    root = next(link for link in links if link not in parent)

    def deepest(link) -> int:
        here = 0 if parent.get(link, (None, None, "fixed"))[2] == "fixed" else 1
        return here + max((deepest(c) for c in children.get(link, [])), default=0)

    return sum(1 for c in children.get(root, []) if deepest(c) >= 3)


def prepare_urdf(
    path: Path,
    root: ET.Element,
    limit_flags: list[str],
    srdf: SrdfInfo | None,
    floating_base: bool = False,
    drop_missing_meshes: bool = False,
    link_boxes: bool = False,
) -> PreparedSource:
    """Check the URDF and rewrite it for MuJoCo's URDF compiler (see the module docstring).

    Args:
        limit_flags: ``--limit JOINT=LOWER:UPPER`` texts (rad, shell patterns over the revolute
            and continuous joints; later flags win). drop_missing_meshes: drop the ``<collision>``
            and ``<visual>`` elements whose mesh file does not exist (each printed) instead of
            refusing. link_boxes: one bounding box per link around all its collision meshes
            (coarser, fewer pairs) instead of one per mesh.

    Raises:
        RobotImportError: duplicate joint or link name, continuous joint without limits (and no
            ``--limit``), mesh that does not resolve, moving link without positive mass and
            inertia, floating base (several legs from the root), no movable joint.
    """
    root = copy.deepcopy(root)
    notes: list[str] = []
    links, joint_els = _unique_names(path, root)
    limit_overrides = _limit_overrides(path, joint_els, limit_flags)
    joints: dict[str, JointInfo] = {}
    movable: list[str] = []
    parent: dict[str, tuple[str, str, str]] = {}
    for j in joint_els:
        child, edge, info = _joint(path, j, set(links), limit_overrides, notes)
        parent[child] = edge
        if info is not None:
            joints[info.name] = info
            movable.append(info.name)
    if not movable:
        raise RobotImportError(f"{path}: <robot>: no revolute or continuous joint")
    roots = [link for link in links if link not in parent]
    if len(roots) != 1:
        raise RobotImportError(f"{path}: <robot>: expected one root link, found {roots}")
    if not floating_base and _legs(links, parent) >= 2:
        raise RobotImportError(
            f"{path}: <link name='{roots[0]}'>: several legs leave the root link: " + FLOATING_BASE
        )
    link_els = {link.get("name"): link for link in root.findall("link")}
    for name in movable:
        _check_inertia(path, link_els[joints[name].child], name)
    meshdir_abs, meshdir_uri, fitted = _rewrite_meshes(
        path, root, notes, drop_missing_meshes, link_boxes
    )
    _compile_for_mujoco(root, meshdir_abs)
    return PreparedSource(
        path=path,
        display=_display(path),
        text=ET.tostring(root, encoding="unicode"),
        joints=joints,
        movable=movable,
        parent=parent,
        links=links,
        root_link=roots[0],
        meshdir_abs=meshdir_abs,
        meshdir_uri=meshdir_uri,
        notes=notes,
        fitted=fitted,
    )


def _unique_names(path: Path, root: ET.Element) -> tuple[list[str], list[ET.Element]]:
    """The URDF's link names and ``<joint>`` elements, in file order (``RobotImportError`` on a
    name given twice)."""
    links = [link.get("name") for link in root.findall("link")]
    seen: set[str] = set()
    for link in links:
        if link in seen:
            raise RobotImportError(f"{path}: <link name='{link}'>: duplicate link name")
        seen.add(link)
    joint_els = root.findall("joint")
    names: set[str] = set()
    for j in joint_els:
        name = j.get("name")
        if name in names:
            raise RobotImportError(
                f"{path}: <joint name='{name}'>: duplicate joint name; expected unique names"
            )
        names.add(name)
    return links, joint_els


def _limit_overrides(path: Path, joint_els: list[ET.Element], limit_flags: list[str]) -> dict:
    """``--limit`` flags over the revolute and continuous joints: name -> (lower, upper) rad."""
    from sim2real.robots.importer import flags

    rotary = [
        j.get("name")
        for j in joint_els
        if j.get("type") in ("revolute", "continuous") and j.find("mimic") is None
    ]
    return flags.per_joint(
        limit_flags,
        rotary,
        "--limit",
        flags.position_range,
        "JOINT=LOWER:UPPER in rad with LOWER < UPPER (JOINT may be a pattern, e.g. "
        "'joint*=-3.14:3.14')",
        path.name,
    )


def _joint(
    path: Path, j: ET.Element, links: set[str], limit_overrides: dict, notes: list[str]
) -> tuple[str, tuple[str, str, str], JointInfo | None]:
    """One ``<joint>``: its child link, the child's edge ``(parent link, joint, kind)`` and,
    for a joint the runtime drives, its :class:`JointInfo` (``None``: fixed or frozen). Rewrites
    the element in place: a prismatic or mimic joint frozen (noted), a driven one a revolute
    with its limits (``--limit`` winning).

    Raises:
        RobotImportError: a parent or child that is not a link, a floating or planar joint, an
            unsupported type, a joint without ``lower < upper`` limits.
    """
    name, kind = j.get("name"), j.get("type")
    par = j.find("parent").get("link") if j.find("parent") is not None else None
    child = j.find("child").get("link") if j.find("child") is not None else None
    if par not in links or child not in links:
        raise RobotImportError(
            f"{path}: <joint name='{name}'>: parent '{par}' / child '{child}' must be links "
            "of the URDF"
        )
    if kind == "floating" or kind == "planar":
        raise RobotImportError(f"{path}: <joint name='{name}' type='{kind}'>: " + FLOATING_BASE)
    limit = j.find("limit")
    if kind in ("prismatic",) or (kind in ("revolute", "continuous") and j.find("mimic")):
        notes.append(
            f"joint {name} ({kind}{', mimic' if j.find('mimic') is not None else ''}) frozen "
            "at 0: the runtime drives revolute joints only"
        )
        _freeze(j)
        kind = "fixed"
    if kind == "fixed":
        return child, (par, name, "fixed"), None
    if kind not in ("revolute", "continuous"):
        raise RobotImportError(
            f"{path}: <joint name='{name}' type='{kind}'>: unsupported joint type; expected "
            "revolute, continuous, prismatic (frozen) or fixed"
        )
    lower, upper = _float(limit, "lower"), _float(limit, "upper")
    if name in limit_overrides:
        lower, upper = limit_overrides[name]
    if kind == "continuous" and (lower is None or upper is None or not lower < upper):
        raise RobotImportError(
            f"{path}: <joint name='{name}' type='continuous'>: no position limits; expected "
            f"<limit lower=... upper=...> (rad) or --limit {name}=LOWER:UPPER"
        )
    if lower is None or upper is None or not lower < upper:
        raise RobotImportError(
            f"{path}: <joint name='{name}'><limit lower upper>: got {lower}, {upper}; "
            f"expected lower < upper in rad (or --limit {name}=LOWER:UPPER)"
        )
    if limit is None:
        limit = ET.SubElement(j, "limit")
    limit.set("lower", repr(lower))
    limit.set("upper", repr(upper))
    j.set("type", "revolute")
    info = JointInfo(
        name, kind, par, child, lower, upper, _float(limit, "velocity"), _float(limit, "effort")
    )
    return child, (par, name, kind), info


def _compile_for_mujoco(root: ET.Element, meshdir_abs: str | None) -> None:
    """Drop what MuJoCo's URDF compiler does not read (visuals, gazebo, transmissions, an old
    ``<mujoco>``) and add its ``<compiler>`` (meshes by path, no visuals, no fusing)."""
    for link in root.findall("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
    for gazebo in root.findall("gazebo") + root.findall("transmission"):
        root.remove(gazebo)
    for old in root.findall("mujoco"):
        root.remove(old)
    mj = ET.SubElement(root, "mujoco")
    compiler = ET.SubElement(
        mj,
        "compiler",
        strippath="false",
        discardvisual="true",
        fusestatic="false",
        balanceinertia="true",
    )
    if meshdir_abs is not None:
        compiler.set("meshdir", meshdir_abs)


def _freeze(j: ET.Element) -> None:
    j.set("type", "fixed")
    for tag in ("mimic", "limit", "axis", "dynamics", "safety_controller", "calibration"):
        for el in j.findall(tag):
            j.remove(el)


def _check_inertia(path: Path, link: ET.Element, joint: str) -> None:
    name = link.get("name")
    inertial = link.find("inertial")
    mass = _float(inertial.find("mass") if inertial is not None else None, "value")
    inertia = inertial.find("inertia") if inertial is not None else None
    if inertial is None or mass is None or inertia is None:
        raise RobotImportError(
            f"{path}: <link name='{name}'> (moved by joint '{joint}'): no <inertial> with <mass> "
            "and <inertia>; expected the link's mass (kg) and inertia tensor (kg m^2)"
        )
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    values = [_float(inertia, k) or 0.0 for k in keys]
    ixx, ixy, ixz, iyy, iyz, izz = values
    tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    if mass <= MIN_MASS or np.linalg.eigvalsh(tensor).min() <= MIN_INERTIA:
        raise RobotImportError(
            f"{path}: <link name='{name}'><inertial> (moved by joint '{joint}'): mass {mass} kg, "
            f"inertia {dict(zip(keys, values, strict=True))}: zero inertia; expected mass > 0 and "
            "a positive-definite inertia tensor"
        )


def _rewrite_meshes(
    path: Path,
    root: ET.Element,
    notes: list[str],
    drop_missing: bool = False,
    link_boxes: bool = False,
) -> tuple[str | None, str, set[tuple[str, int]]]:
    """Resolve every mesh; refer to the kept ones relative to one folder (returned), or replace
    each collision mesh by its bounding box in place (``COLLISION_BOXES``; ``link_boxes``: one
    box per link, in the link frame, around all its meshes' boxes, appended after its other
    collision elements). Returns ``(meshdir_abs, meshdir_uri, fitted)``: ``fitted`` the
    ``(link, k)`` of the boxes, ``k`` counting the link's ``<collision>`` elements (the order
    MuJoCo's geoms keep)."""
    resolved = _resolve_meshes(path, root, notes, drop_missing)
    keep = () if COLLISION_BOXES else MUJOCO_MESH_FORMATS
    meshdir_abs, meshdir_uri = _meshdir(resolved, keep)
    boxed: set[int] = set()
    corners: dict[str, list[np.ndarray]] = {}
    for link, el, file, _ in resolved:
        mesh = el.find("geometry/mesh")
        if file.suffix.lower() in keep:
            mesh.set("filename", Path(os.path.relpath(file, meshdir_abs)).as_posix())
            continue
        boxed.add(id(el))
        _box_mesh(link, el, file, corners if link_boxes else None)
    for link in root.findall("link"):
        if link.get("name") in corners:
            boxed.add(id(_link_box(link, corners[link.get("name")])))
    fitted = set()
    for link in root.findall("link"):
        for k, el in enumerate(link.findall("collision")):
            if id(el) in boxed:
                fitted.add((link.get("name"), k))
    if corners:
        meshes = sum(len(c) for c in corners.values())
        notes.append(
            f"{meshes} collision meshes replaced by one bounding box per link (--link-boxes)"
        )
    elif boxed:
        notes.append(
            f"{len(boxed)} collision meshes replaced by their bounding boxes in the mesh frame, "
            "one box per mesh (COLLISION_BOXES)"
        )
    return meshdir_abs, meshdir_uri, fitted


def _resolve_meshes(
    path: Path, root: ET.Element, notes: list[str], drop_missing: bool
) -> list[tuple[ET.Element, ET.Element, Path, str | None]]:
    """Every collision mesh that resolves, as ``(link, element, file, package or None)``; a
    missing mesh refused (``RobotImportError`` naming the first), or with ``drop_missing`` its
    element dropped and noted."""
    resolved: list[tuple[ET.Element, ET.Element, Path, str | None]] = []
    missing: list[tuple[ET.Element, ET.Element, str, Path, str]] = []
    for link in root.findall("link"):
        for tag in ("collision", "visual"):
            for el in link.findall(tag):
                for mesh in el.iter("mesh"):
                    uri = mesh.get("filename", "")
                    file, package = _resolve_mesh(uri, path)
                    if not file.is_file():
                        missing.append((link, el, uri, file, tag))
                    elif tag == "collision":
                        resolved.append((link, el, file, package))
    if missing and not drop_missing:
        link, _, uri, file, tag = missing[0]
        more = f" ({len(missing) - 1} more missing)" if len(missing) > 1 else ""
        where = f"<link name='{link.get('name')}'><{tag}><mesh filename='{uri}'>"
        if uri.startswith(PACKAGE_SCHEME) and not file.is_absolute():  # no package found
            package = uri[len(PACKAGE_SCHEME) :].partition("/")[0]
            raise RobotImportError(
                f"{path}: {where}: does not resolve: {package_path_hint(package, path)}{more}; "
                f"or --drop-missing-meshes to drop the geoms that use them"
            )
        raise RobotImportError(
            f"{path}: {where}: does not resolve (looked for {file}){more}; {DROP_MISSING}"
        )
    for link, el, uri, _, tag in missing:
        link.remove(el)
        notes.append(f"link {link.get('name')}: <{tag}> mesh '{uri}' missing: dropped")
    return resolved


def _meshdir(resolved: list, keep: tuple) -> tuple[str | None, str]:
    """The one folder the kept meshes are referred to from: ``(absolute path or None, as
    written: a package URI where they all come from one package, else the path)``."""
    files = [f for _, _, f, _ in resolved if f.suffix.lower() in keep]
    if not files:
        return None, ""
    packages = {p for _, _, f, p in resolved if f.suffix.lower() in keep}
    if len(packages) == 1 and None not in packages:
        package = next(iter(packages))
        base = package_root(package)
        meshdir_uri = f"{PACKAGE_SCHEME}{package}"
    else:
        base = Path(os.path.commonpath([str(f.parent) for f in files]))
        meshdir_uri = str(base)
    return base.as_posix(), meshdir_uri


def _box_mesh(link: ET.Element, el: ET.Element, file: Path, corners: dict | None) -> None:
    """A collision mesh's bounding box: in place of the mesh, in its frame (its centre moved
    into the element's origin); or, given ``corners`` (``--link-boxes``), the box's corners in
    the link frame added to the link's list and the element removed."""
    mesh = el.find("geometry/mesh")
    scale = np.array([float(x) for x in (mesh.get("scale") or "1 1 1").split()])
    centre, size = _box_from_mesh(file, scale)
    origin = el.find("origin")
    xyz = np.array([float(x) for x in (_attr(origin, "xyz") or "0 0 0").split()])
    rpy = np.array([float(x) for x in (_attr(origin, "rpy") or "0 0 0").split()])
    if corners is not None:
        signs = np.array(list(itertools.product((-0.5, 0.5), repeat=3)))
        pts = xyz + (centre + signs * size) @ _rpy_matrix(rpy).T
        corners.setdefault(link.get("name"), []).append(pts)
        link.remove(el)
        return
    if origin is None:
        origin = ET.SubElement(el, "origin")
    origin.set("xyz", " ".join(repr(float(v)) for v in xyz + _rpy_matrix(rpy) @ centre))
    origin.set("rpy", " ".join(repr(float(v)) for v in rpy))
    geometry = el.find("geometry")
    geometry.remove(mesh)
    ET.SubElement(geometry, "box", size=" ".join(repr(float(v)) for v in size))


def _link_box(link: ET.Element, corners: list[np.ndarray]) -> ET.Element:
    """One collision box around ``corners`` (link frame), appended to the link; returned."""
    pts = np.vstack(corners)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    col = ET.SubElement(link, "collision")
    ET.SubElement(col, "origin", xyz=" ".join(repr(float(v)) for v in (lo + hi) / 2))
    geometry = ET.SubElement(col, "geometry")
    ET.SubElement(geometry, "box", size=" ".join(repr(float(v)) for v in hi - lo))
    return col
