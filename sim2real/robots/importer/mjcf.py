"""MJCF reading for the importer: an MJCF robot checked and reduced to what the toolkit uses.

:func:`prepare_mjcf` loads the file with ``mujoco.MjSpec.from_file`` (MuJoCo's own parser: defaults,
includes, degrees or radians) and makes the :class:`~sim2real.robots.importer.source.PreparedSource`
a URDF makes; the rest of the import is shared. Kept:

- hinge joints, their ranges (radians), damping and friction loss (the armature is the motor's);
- geometry (:mod:`sim2real.robots.importer.mjcf_geoms`) and inertials, written for every body;
- ``<contact><exclude>`` pairs, as an SRDF's ``disable_collisions`` and written back;
- ``<contact><pair>``s with their own condim, friction, solref, solimp, margin and gap, following
  their geoms' new names (:mod:`sim2real.robots.importer.contact_pairs`; a pair whose geom the import
  drops is dropped with a note); a floating-base robot's pairs naming the scene's floor
  (``geom2="floor"``, not in the file) name the importer's floor, which takes that name;
- the ``<option>`` integrator and solver settings, its ``<flag>``s and (unless
  ``--physics-timestep``) its timestep (:mod:`sim2real.robots.importer.physics_option`; ``--option``
  overrides a setting);
- sites (one named like a body renamed ``<name>_site``; ``--imu``/``--ee-site`` follow);
- effort limits: ``actuatorfrcrange``, else the removed actuators' ``forcerange`` times gear;
- fixed tendons with limits (``<tendon><fixed limited="true">``, a linkage's limits) whose
  joints all stay hinges (:mod:`sim2real.robots.importer.mjcf_tendons`).

Removed, each with a printed note (:mod:`~sim2real.robots.importer.mjcf_drive` reads the gains,
home pose and floor bits first): actuators, keyframes, sensors, other tendons, equalities (a
coupled joint is frozen), textures, materials, skins, flexes, floors, jointless bodies hanging
from the world (other world geoms move into a fixed body ``base``); slide and ball joints frozen;
a floating base's own free joint (the importer adds its own). Refused (:class:`RobotImportError`):
a free joint without ``--floating-base`` or off the root body; contact pairs naming geoms the file
lacks, or any for a fixed base; a missing mesh; an unnamed hinge, an arm's hinge without limits
(unless ``--limit``; a floating base's is continuous, a wheel), a body with several hinges,
several jointed bodies under the world, a massless moving body, what MuJoCo refuses.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np

from sim2real.robots.importer.contact_pairs import take_pairs
from sim2real.robots.importer.mjcf_drive import floor_bits, read_drive
from sim2real.robots.importer.mjcf_geoms import missing_meshes, simplify_geoms
from sim2real.robots.importer.mjcf_joints import (
    check_free_joints,
    hinge_limits,
    joint_efforts,
    set_limits,
)
from sim2real.robots.importer.mjcf_tendons import drop_tendons_off_hinges, limited_fixed_tendons
from sim2real.robots.importer.source import (
    PreparedSource,
    RobotImportError,
    _display,
)

_HINGE = mujoco.mjtJoint.mjJNT_HINGE
_KIND = {
    mujoco.mjtJoint.mjJNT_SLIDE: "slide",
    mujoco.mjtJoint.mjJNT_BALL: "ball",
    mujoco.mjtJoint.mjJNT_FREE: "free",
}


def prepare_mjcf(
    path: Path,
    limit_flags: list[str],
    floating_base: bool = False,
    drop_missing_meshes: bool = False,
    link_boxes: bool = False,
    keyframe: str | None = None,
) -> PreparedSource:
    """Check the MJCF at ``path`` and reduce it for the importer (see the module docstring).

    Args:
        path: The MJCF file (root ``<mujoco>``). limit_flags: ``--limit JOINT=LOWER:UPPER``
            texts (rad, shell patterns over the hinges; later flags win) for hinges the file
            leaves unlimited (or to replace a range). floating_base: a legged robot: the free
            joint of the robot's root body (if any) is removed (the importer adds its own), the
            world body's other geoms are dropped. drop_missing_meshes: drop the geoms whose mesh
            file does not exist (each printed) instead of refusing. link_boxes: one bounding
            box per body around all its mesh geoms (coarser, fewer pairs) instead of one per
            mesh geom. keyframe: the ``<key>`` whose pose is the file's home
            (:func:`sim2real.robots.importer.mjcf_drive.read_drive`).

    Returns:
        A :class:`PreparedSource` of kind "MJCF" whose ``text`` is the reduced model in MuJoCo's
        canonical MJCF (radians), ``disabled`` its ``<contact><exclude>`` body pairs and
        ``sites`` its sites by body. Its links are the bodies, the world body first for a
        fixed base; for a floating base the root link is the robot's root body and the world
        is not a link.

    Raises:
        RobotImportError: one line naming the file, the element and what was expected (see the
            module docstring for what is refused).
    """
    notes: list[str] = []
    spec = _from_file(path)
    pairs, scene_geom = take_pairs(spec, path, floating_base, notes)
    _drop_appearance(spec)
    missing_meshes(spec, path, drop_missing_meshes, notes)
    _name_unnamed(spec.bodies[1:], "body")
    model = _compile(spec, path)
    model_in, drive = model, read_drive(model, path, keyframe)  # before actuators, keys go
    notes += drive.notes
    check_free_joints(model, path, floating_base)
    efforts = joint_efforts(model)
    disabled = {tuple(sorted((e.bodyname1, e.bodyname2))) for e in spec.excludes}
    tendons = limited_fixed_tendons(spec, model)
    frozen = _drop_elements(spec, notes, set(tendons), servos=len(drive.kp))
    _drop_scenery(spec, model, path, notes)
    root_body = None
    if floating_base:
        root_body = _floating_root(spec, path, notes)
    _freeze_joints(spec, path, frozen, notes)
    drop_tendons_off_hinges(spec, tendons, notes)
    spec = _canonical(spec, path, floating_base, notes)
    set_limits(spec, limit_flags, path)
    model = _compile(spec, path)
    joints = hinge_limits(model, path, efforts, floating_base)
    keep = {n for p in pairs for n in (p["geom1"], p["geom2"])}
    meshdir_abs, fitted = simplify_geoms(spec, model, notes, link_boxes, keep)
    renamed_sites = _rename_sites_like_bodies(spec, notes)
    text = _to_xml(spec, path)
    model = _compile(_from_string(text, path), path)

    parent, links, sites = _tree(model, root_body)
    return PreparedSource(
        path=path,
        display=_display(path),
        text=text,
        joints=joints,
        movable=list(joints),
        parent=parent,
        links=links,
        root_link=root_body or links[0],
        meshdir_abs=meshdir_abs,
        meshdir_uri=meshdir_abs or "",
        notes=notes,
        kind="MJCF",
        disabled={p for p in disabled if p[0] in links and p[1] in links},
        sites=sites,
        fitted=fitted,
        pairs=pairs,
        scene_geom=scene_geom,
        renamed_sites=renamed_sites,
        floor_bits=floor_bits(model_in),
        drive=drive,
    )


def _tree(model: mujoco.MjModel, root_body: str | None) -> tuple[dict, list[str], dict]:
    """The kinematic tree of the compiled ``model``: ``parent`` {body: (parent body, joint or
    "", "revolute" | "fixed")} (the floating root left out), the links (the world body first
    for a fixed base, left out for a floating one) and the named sites {site: body}."""
    names = [model.body(b).name for b in range(model.nbody)]
    parent = {}
    for b in range(1, model.nbody):
        n = model.body_jntnum[b]
        joint = model.joint(model.body_jntadr[b]).name if n else ""
        if names[b] != root_body:
            parent[names[b]] = (names[model.body_parentid[b]], joint, "revolute" if n else "fixed")
    links = names[1:] if root_body else names
    sites = {model.site(s).name: names[model.site_bodyid[s]] for s in range(model.nsite)}
    return parent, links, {k: v for k, v in sites.items() if k}


def _canonical(spec: mujoco.MjSpec, path: Path, floating_base: bool, notes) -> mujoco.MjSpec:
    """``spec`` written and read back in canonical form: radians, quaternions, explicit
    inertials computed from the full geometry, an absolute mesh folder, every geom named (to
    find it in the compiled model); a fixed base's world geoms moved into a body ``base``."""
    spec.compiler.saveinertial = True
    if spec.meshdir and not os.path.isabs(spec.meshdir):
        spec.meshdir = os.path.join(spec.modelfiledir or str(path.parent), spec.meshdir)
    elif not spec.meshdir:
        spec.meshdir = spec.modelfiledir or str(path.parent)
    text = _to_xml(spec, path)
    spec = _from_string(text if floating_base else _base_body(text, notes), path)
    spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
    _name_unnamed(spec.geoms, "geom")
    return spec


def _drop_appearance(spec: mujoco.MjSpec) -> None:
    """Delete materials and textures (their image files need not be there: nothing the toolkit
    reads depends on them), and their names in the default classes (a ``<default>``'s geom
    naming a material, as mjlab's and MuJoCo Menagerie's robots write them: the reduced file
    would name a material it no longer has)."""
    for geom in spec.geoms:
        geom.material = ""
    for site in spec.sites:
        site.material = ""
    for element in [*spec.geoms, *spec.sites]:  # the classes geoms and sites are written with
        element.classname.geom.material = ""
        element.classname.site.material = ""
    for element in [*spec.materials, *spec.textures]:
        spec.delete(element)


def _floating_root(spec: mujoco.MjSpec, path: Path, notes: list[str]) -> str:
    """The robot's root body of a floating-base MJCF: its free joint (if any) and the other
    geoms of the world body removed, its orientation reset (the importer adds the free joint,
    the floor and the standing height)."""
    bodies = list(spec.worldbody.bodies)
    if len(bodies) != 1:  # pragma: no cover - _drop_scenery refuses several robots
        raise RobotImportError(f"{path}: <worldbody>: expected one robot, found {bodies}")
    root = bodies[0]
    for joint in list(root.joints):
        if joint.type == mujoco.mjtJoint.mjJNT_FREE:
            spec.delete(joint)
            notes.append(
                f"free joint {joint.name or '(unnamed)'} of body {root.name} replaced by the "
                "importer's (base above the floor at the home pose)"
            )
    if root.joints:
        raise RobotImportError(
            f"{path}: <body name='{root.name}'>: joints {[j.name for j in root.joints]} on the "
            "root body; expected only a free joint there (a floating base)"
        )
    world = list(spec.worldbody.geoms)
    for geom in world:
        spec.delete(geom)
    if world:
        notes.append(f"{len(world)} geoms of the world body dropped: scenery")
    root.alt.type = mujoco.mjtOrientation.mjORIENTATION_QUAT
    root.quat = [1.0, 0.0, 0.0, 0.0]
    return root.name


def _rename_sites_like_bodies(spec: mujoco.MjSpec, notes: list[str]) -> dict[str, str]:
    """Rename each site named like a body (``<body name="pelvis"><site name="pelvis"/>``) to
    ``<name>_site`` (Pinocchio makes a BODY and an OP_FRAME frame of one name, and
    ``getFrameId(name)`` raises "Several frames match the filter"); return old -> new name
    (``--imu`` and ``--ee-site`` naming the old name follow it)."""
    bodies = {b.name for b in spec.bodies}
    taken = bodies | {s.name for s in spec.sites}
    renamed: dict[str, str] = {}
    for site in spec.sites:
        if site.name and site.name in bodies:
            new, k = f"{site.name}_site", 1
            while new in taken:
                k += 1
                new = f"{site.name}_site{k}"
            renamed[site.name] = new
            site.name = new
            taken.add(new)
    if renamed:
        notes.append(
            f"{len(renamed)} sites named like a body renamed {renamed} (Pinocchio's frame names "
            "must differ); --imu and --ee-site naming the old name follow"
        )
    return renamed


def _name_unnamed(elements, prefix: str) -> None:
    """Give unnamed elements (bodies, geoms) the first free name ``PREFIX<k>``."""
    taken = {e.name for e in elements}
    k = 0
    for element in elements:
        while not element.name:
            k += 1
            if f"{prefix}{k}" not in taken:
                element.name = f"{prefix}{k}"
                taken.add(element.name)


def _from_file(path: Path) -> mujoco.MjSpec:
    try:
        return mujoco.MjSpec.from_file(str(path))
    except ValueError as exc:
        raise RobotImportError(
            f"{path}: MuJoCo's MJCF parser refuses it: {_one_line(exc)}"
        ) from None


def _from_string(text: str, path: Path) -> mujoco.MjSpec:
    try:
        return mujoco.MjSpec.from_string(text)
    except ValueError as exc:  # pragma: no cover - MuJoCo reading what it wrote
        raise RobotImportError(
            f"{path}: MuJoCo cannot read back the reduced MJCF: {_one_line(exc)}"
        ) from None


def _compile(spec: mujoco.MjSpec, path: Path) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as exc:
        raise RobotImportError(
            f"{path}: MuJoCo's MJCF compiler refuses it: {_one_line(exc)}"
        ) from None


def _to_xml(spec: mujoco.MjSpec, path: Path) -> str:
    try:
        return spec.to_xml()
    except ValueError as exc:
        raise RobotImportError(
            f"{path}: MuJoCo cannot write the reduced MJCF: {_one_line(exc)}"
        ) from None


def _drop_elements(
    spec: mujoco.MjSpec, notes: list[str], keep_tendons: set[str] = frozenset(), servos: int = 0
) -> set[str]:
    """Delete what the toolkit does not simulate (but the tendons named in ``keep_tendons``);
    return the joints equalities couple. ``servos``: the actuators that are position servos
    whose gains :func:`read_drive` read (the note names them only then)."""
    read = f"the gains of its {servos} <position> servos read" if servos else "no <position> servo"
    frozen = {e.name1 for e in spec.equalities if e.type == mujoco.mjtEq.mjEQ_JOINT and e.name1}
    tendons = [t for t in spec.tendons if t.name not in keep_tendons]
    for what, elements, why in (
        ("actuators", spec.actuators, f"Robot.mjspec adds the drives ({read})"),
        ("sensors", spec.sensors, "the sim backend models robot.toml's sensors"),
        ("tendons", tendons, "spatial or unlimited: the runtime drives joints"),
        ("equality constraints", spec.equalities, "the runtime simulates open chains"),
        ("keyframes", spec.keys, "their home pose read first (mjcf_drive)"),
        ("skins", spec.skins, "not simulated"),
        ("flexes", spec.flexes, "not simulated"),
        ("contact excludes", spec.excludes, ""),  # kept as the importer's disabled pairs
    ):
        elements = list(elements)
        for element in elements:
            spec.delete(element)
        if elements and why:
            names = [e.name for e in elements if e.name][:4]
            named = f" {names}" if names else ""
            notes.append(f"{len(elements)} {what}{named} dropped: {why}")
    floors = [
        g
        for g in spec.geoms
        if g.type == mujoco.mjtGeom.mjGEOM_HFIELD
        or (g.type == mujoco.mjtGeom.mjGEOM_PLANE and g.parent.name == "world")
    ]
    for geom in floors:
        spec.delete(geom)
    if floors:
        notes.append(f"{len(floors)} floor geoms (planes, height fields) dropped")
    for hfield in list(spec.hfields):
        spec.delete(hfield)
    return frozen


def _base_body(text: str, notes: list[str]) -> str:
    """Move the geoms of the world body (a fixed base MuJoCo fused into the world, or a table)
    into a fixed body of their own, ``base``, which then carries the robot (the importer's links
    are bodies; Pinocchio's MJCF parser reads one tree from the world)."""
    root = ET.fromstring(text)
    world = root.find("worldbody")
    geoms = [] if world is None else world.findall("geom")
    if not geoms:
        return text
    taken = {b.get("name") for b in root.iter("body")}
    name = next(n for n in ("base", "world_base", "world_geoms") if n not in taken)
    body = ET.Element("body", name=name)
    for child in geoms + world.findall("body"):
        world.remove(child)
        body.append(child)
    world.insert(0, body)
    notes.append(f"{len(geoms)} geoms of the world body moved into a fixed body '{name}'")
    return ET.tostring(root, encoding="unicode")


def _drop_scenery(spec: mujoco.MjSpec, model: mujoco.MjModel, path: Path, notes) -> None:
    """Delete bodies hanging from the world whose subtree has no joint; refuse two robots."""
    jointed = []
    for body in list(spec.worldbody.bodies):
        b = model.body(body.name).id
        in_tree = np.flatnonzero(model.body_rootid == b)
        if model.body_jntnum[in_tree].sum() == 0:
            notes.append(f"body {body.name} (no joint below it) dropped: scenery")
            spec.delete(body)
        else:
            jointed.append(body.name)
    if len(jointed) > 1:
        raise RobotImportError(
            f"{path}: <worldbody>: several bodies with joints hang from the world {jointed}; "
            "expected one robot"
        )


def _freeze_joints(spec: mujoco.MjSpec, path: Path, frozen: set[str], notes) -> None:
    """Freeze slide, ball and coupled joints; refuse unnamed hinges and multi-hinge bodies."""
    for joint in list(spec.joints):
        kind = _KIND.get(joint.type, "hinge")
        if kind != "hinge" or joint.name in frozen:
            why = f"{kind}, coupled by an <equality joint>" if joint.name in frozen else kind
            notes.append(
                f"joint {joint.name or '(unnamed)'} ({why}) frozen at its reference position: "
                "the runtime drives hinge joints only"
            )
            spec.delete(joint)
            continue
        if not joint.name:
            raise RobotImportError(
                f"{path}: <body name='{joint.parent.name}'><joint>: unnamed hinge joint; "
                "expected a name (robot.toml and policies name joints)"
            )
    for body in spec.bodies:
        if len(body.joints) > 1:
            raise RobotImportError(
                f"{path}: <body name='{body.name}'>: {len(body.joints)} hinge joints "
                f"{[j.name for j in body.joints]}; expected one joint per body"
            )
    if not spec.joints:
        raise RobotImportError(f"{path}: <mujoco>: no hinge joint; expected a robot's hinges")


def _one_line(exc: Exception) -> str:
    """MuJoCo's multi-line error message on one line."""
    return "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
