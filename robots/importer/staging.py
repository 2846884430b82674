"""The steps both halves of robot-import (fixed-base and floating-base) share around the robot's
files: the motor caps recorded in the report, a temporary folder beside the output that becomes
the output only when :func:`robots.load_robot` loads it, the joint ranges as the MJCF writes
them, and the collision pairs with their MuJoCo contact exclusions."""

from __future__ import annotations

import shutil
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import mujoco

from robots.importer.model import cap_limits, choose_collision_pairs
from robots.importer.source import PreparedSource, RobotImportError
from robots.loading import load_robot
from robots.packages import resolved_mjcf
from robots.robot import RobotSpecError


def capped_limits(urdf: PreparedSource, chosen: dict, motor_cfg: dict, report, log) -> dict:
    """:func:`robots.importer.model.cap_limits` with its lowered limits and notes added to
    ``report.lowered`` / ``report.notes``; returns the limits per joint (rad, rad/s, N m)."""
    limits, lowered, notes = cap_limits(urdf, chosen, motor_cfg, log)
    report.lowered += lowered
    report.notes += notes
    return limits


@contextmanager
def staged(out: Path, name: str, path: Path) -> Iterator[tuple[Path, Path]]:
    """Yields ``(work, mjcf_path)``: a new folder ``name`` in a temporary folder beside ``out``
    and ``work / f"{name}.xml"``. When the block ends without an exception, the folder must
    load with :func:`robots.load_robot`; it then replaces ``out``.

    Raises:
        RobotImportError: the folder does not load (``path`` names the source).
    """
    with tempfile.TemporaryDirectory(prefix=f".{name}-", dir=out.parent) as tmp:
        work = Path(tmp) / name
        work.mkdir()
        yield work, work / f"{name}.xml"
        try:
            load_robot(work)
        except RobotSpecError as exc:
            raise RobotImportError(f"{path}: the imported robot does not load: {exc}") from None
        if out.exists():
            shutil.rmtree(out)
        work.rename(out)


def written_ranges(
    mjcf_path: Path, joint_names: list[str], limits: dict, first: int = 0
) -> mujoco.MjModel:
    """The model of the MJCF as written: it writes ranges to 6 significant digits, and robot.toml
    must say the same, so each joint's (lo, hi) in ``limits`` (joint ``i`` is the model's joint
    ``first + i``) is replaced, in place, by the written one (rad)."""
    written = mujoco.MjModel.from_xml_path(str(resolved_mjcf(mjcf_path)))
    for i, j in enumerate(joint_names):
        lo, hi = (float(x) for x in written.jnt_range[first + i])
        limits[j] = (lo, hi, *limits[j][2:])
    return written


def collision_pairs(mjcf_path: Path, model, urdf, srdf_info, home, path: Path, log, *clearance):
    """:func:`robots.importer.model.choose_collision_pairs` (``clearance`` m, when given): the
    dropped pairs logged, the excluded body pairs written into the MJCF's ``<contact>``; returns
    the pairs the guard checks."""
    pairs, excluded, dropped = choose_collision_pairs(
        mjcf_path, model, urdf, srdf_info, home, path, *clearance
    )
    for a, b, d in dropped:
        log(f"note: links {a} and {b} are {d * 1000:.1f} mm apart at home: pair not checked")
    if excluded:
        add_contact_excludes(mjcf_path, excluded)
    return pairs


def add_contact_excludes(mjcf_path: Path, excluded: list[tuple[str, str]]) -> None:
    """Add ``<exclude body1 body2>`` for each body pair to the MJCF's ``<contact>`` (made when
    missing), keeping its first line (the generated-by comment)."""
    tree = ET.parse(mjcf_path)
    root = tree.getroot()
    contact = root.find("contact")
    if contact is None:
        contact = ET.SubElement(root, "contact")
    for a, b in excluded:
        ET.SubElement(contact, "exclude", body1=a, body2=b)
    ET.indent(tree, "  ")
    text = ET.tostring(root, encoding="unicode")
    head = mjcf_path.read_text(encoding="utf-8").split("\n", 1)[0]
    mjcf_path.write_text(head + "\n" + text + "\n", encoding="utf-8")
