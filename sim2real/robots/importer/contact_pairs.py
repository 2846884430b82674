"""An MJCF's explicit ``<contact><pair>``s carried through the import with their own settings.

Robots written for explicit pairs (every geom ``contype = conaffinity = 0``, the feet touching
the floor through ``<pair geom1="left_foot" geom2="floor" condim="3" friction="0.6 0.6"/>``)
are trained with those pairs' friction, solref, solimp, margin and gap. :func:`take_pairs`
detaches them from the MjSpec before the importer reduces it (so they cannot name a geom it
deletes), :func:`rename_pair_geoms` follows the names :func:`sim2real.robots.importer.model.build_spec`
gives geoms, and :func:`write_pairs` writes them into the robot's MJCF once it is written: a
pair whose geom is no longer in the file is dropped with a printed note.

A pair that names a geom of the scene the robot file is meant to be included in (``geom2=
"floor"``, not in the file, or a plane or height field of the world body) keeps it for a
floating-base robot: the importer's floor takes that name. Several such names, or any for a
fixed-base robot, are refused (:class:`RobotImportError`): import the scene file instead.
Pinocchio's MJCF parser ignores ``<pair>``s.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco

from sim2real.robots.importer.source import PreparedSource, RobotImportError

#: Name of the floor the importer writes for a floating-base robot (floating_mjcf).
FLOOR = "floor"
_FLOOR_TYPES = (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD)


def _text(values) -> str:
    return " ".join(f"{float(v):.8g}" for v in values)


def take_pairs(
    spec: mujoco.MjSpec, path: Path, floating_base: bool, notes: list[str]
) -> tuple[list[dict[str, str]], str | None]:
    """Delete ``spec``'s ``<contact><pair>``s and return them as ``<pair>`` attribute dicts
    (geom names as the file writes them; friction, solref, solimp, margin (m) and gap (m) as
    MuJoCo resolved them with the file's defaults) and the one scene geom they name (the
    importer's floor takes its name), or None.

    Raises:
        RobotImportError: pairs name several scene geoms, or any for a fixed-base robot (one
            line naming the pairs and saying to import the scene file instead).
    """
    geoms = {g.name: g for g in spec.geoms}
    pairs = list(spec.pairs)

    def scene(name: str) -> bool:
        if name not in geoms:
            return True
        g = geoms[name]
        return floating_base and g.parent.name == "world" and g.type in _FLOOR_TYPES

    named = sorted({n for p in pairs for n in (p.geomname1, p.geomname2) if n and scene(n)})
    if named and (not floating_base or len(named) > 1):
        which = [f"{p.geomname1}-{p.geomname2}" for p in pairs if {p.geomname1, p.geomname2}
                 & set(named)][:4]  # fmt: skip
        why = "a fixed-base robot has no floor" if not floating_base else "one floor stands in"
        raise RobotImportError(
            f"{path}: <contact><pair>s {which} name geoms {named} the file does not have (its "
            f"scene's?; {why}): import the scene file that includes it instead"
        )
    out = []
    for p in pairs:
        attrs = {
            "geom1": p.geomname1,
            "geom2": p.geomname2,
            "condim": str(int(p.condim)),
            "friction": _text(p.friction),
            "solref": _text(p.solref),
            "solreffriction": _text(p.solreffriction),
            "solimp": _text(p.solimp),
            "margin": f"{float(p.margin):.8g}",
            "gap": f"{float(p.gap):.8g}",
        }
        if p.name:
            attrs["name"] = p.name
        out.append(attrs)
        spec.delete(p)
    if named:
        notes.append(
            f"<contact><pair>s name {named}, a geom of the scene this file is included in: the "
            "importer's floor takes that name"
        )
    return out, (named[0] if named else None)


def pair_geoms(prepared: PreparedSource) -> set[str]:
    """Names of the robot's geoms the kept pairs name (the importer must not drop them)."""
    return {n for p in prepared.pairs for n in (p["geom1"], p["geom2"])} - {prepared.scene_geom}


def rename_pair_geoms(prepared: PreparedSource, renamed: dict[str, str]) -> None:
    """Follow ``renamed`` (old geom name -> new) in the kept pairs."""
    for p in prepared.pairs:
        for key in ("geom1", "geom2"):
            if p[key] != prepared.scene_geom:
                p[key] = renamed.get(p[key], p[key])


def write_pairs(mjcf_path: Path, prepared: PreparedSource, log) -> None:
    """Write the kept pairs and the MJCF's ``<contact><exclude>``s (body pairs of the robot's
    links, ``prepared.disabled``) into the robot's MJCF at ``mjcf_path`` (its first line, the
    generator's comment, kept); name the importer's floor after the scene geom the pairs name;
    print (``log``) a note per pair whose geom the import dropped."""
    excludes = sorted(prepared.disabled) if prepared.kind == "MJCF" else []
    if not prepared.pairs and not excludes:
        return
    tree = ET.parse(mjcf_path)
    root = tree.getroot()
    world = root.find("worldbody")
    if prepared.scene_geom and prepared.scene_geom != FLOOR and world is not None:
        for geom in world.findall("geom"):
            if geom.get("name") == FLOOR:
                geom.set("name", prepared.scene_geom)
    names = {g.get("name") for g in root.iter("geom")}
    contact = root.find("contact")
    if contact is None:
        contact = ET.SubElement(root, "contact")
    for a, b in excludes:
        ET.SubElement(contact, "exclude", body1=a, body2=b)
    kept, dropped = 0, []
    for p in prepared.pairs:
        if p["geom1"] in names and p["geom2"] in names:
            ET.SubElement(contact, "pair", p)
            kept += 1
        else:
            dropped.append(f"{p['geom1']}-{p['geom2']}")
    ET.indent(tree, "  ")
    text = ET.tostring(root, encoding="unicode")
    head = mjcf_path.read_text(encoding="utf-8").split("\n", 1)[0]
    mjcf_path.write_text(head + "\n" + text + "\n", encoding="utf-8")
    if excludes:
        log(f"note: {len(excludes)} <contact><exclude>s kept")
    if prepared.pairs:
        log(f"note: {kept} <contact><pair>s kept with their own friction, solref, solimp, margin")
    if dropped:
        log(f"note: {len(dropped)} <contact><pair>s {dropped[:4]} dropped: the import dropped "
            "their geoms")  # fmt: skip
