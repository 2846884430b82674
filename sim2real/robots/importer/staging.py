"""What both halves of robot-import (fixed-base and floating-base) share: their inputs
(:class:`ImportJob`), the motor caps recorded in the report, a temporary folder beside the output
that becomes the output only when :func:`robots.load_robot` loads it, the joint ranges as the
MJCF writes them, the collision pairs with their MuJoCo contact exclusions, and the arguments
both robot.toml writers take."""

from __future__ import annotations

import shutil
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import mujoco

from sim2real.robots.importer.model import cap_limits, choose_collision_pairs
from sim2real.robots.importer.source import PreparedSource, RobotImportError, SrdfInfo
from sim2real.robots.loading import load_robot
from sim2real.robots.packages import resolved_mjcf
from sim2real.robots.robot import RobotSpecError


@dataclass
class ImportJob:
    """What :func:`sim2real.robots.importer.pipeline.import_robot` hands either half of an import: the
    source file ``path``, the output folder ``out`` (its name the robot's ``name``), the prepared
    description ``urdf`` and SRDF, the compiled MuJoCo spec and model, the movable joints in
    order, the motor per joint (``chosen``), the motors' configurations and the motors given as
    files, the :class:`~sim2real.robots.importer.pipeline.ImportReport` to fill, the control rate (Hz),
    the physics timestep (s), the function that prints a line, and where the rate and the timestep
    came from (``rates_from``, :data:`sim2real.robots.importer.toml_text.RATE_SOURCES`)."""

    path: Path
    out: Path
    name: str
    urdf: PreparedSource
    srdf_info: SrdfInfo | None
    srdf_path: Path | None
    spec: mujoco.MjSpec
    model: mujoco.MjModel
    joint_names: list[str]
    chosen: dict
    motor_cfg: dict
    motor_tables: dict
    report: object
    control_rate: float
    physics_timestep: float
    log: Callable[[str], None]
    rates_from: tuple[str, str] = ("--control-rate", "--physics-timestep")
    #: The guard's pairs the written MJCF's contact bits keep apart (:func:`bits_apart`).
    pairs_apart: list = field(default_factory=list)

    def capped_limits(self) -> dict:
        """:func:`sim2real.robots.importer.model.cap_limits` with its lowered limits and notes added to
        the report; returns the limits per joint (lower, upper rad, velocity rad/s, effort N m)."""
        limits, lowered, notes = cap_limits(self.urdf, self.chosen, self.motor_cfg, self.log)
        self.report.lowered += lowered
        self.report.notes += notes
        return limits

    @contextmanager
    def staged(self) -> Iterator[tuple[Path, Path]]:
        """Yields ``(work, mjcf_path)``: a new folder named as the robot in a temporary folder
        beside ``out``, and its ``<name>.xml``. When the block ends without an exception, the
        folder must load with :func:`robots.load_robot`; it then replaces ``out``.

        Raises:
            RobotImportError: the folder does not load.
        """
        with tempfile.TemporaryDirectory(prefix=f".{self.name}-", dir=self.out.parent) as tmp:
            work = Path(tmp) / self.name
            work.mkdir()
            yield work, work / f"{self.name}.xml"
            try:
                load_robot(work)
            except RobotSpecError as exc:
                msg = f"{self.path}: the imported robot does not load: {exc}"
                raise RobotImportError(msg) from None
            if self.out.exists():
                shutil.rmtree(self.out)
            work.rename(self.out)

    def collision_pairs(self, mjcf_path: Path, model: mujoco.MjModel, home, *clearance) -> list:
        """:func:`sim2real.robots.importer.model.choose_collision_pairs` at ``home`` (rad; ``clearance``
        m when given): the dropped pairs logged, the excluded body pairs written into the MJCF's
        ``<contact>``; returns the geom pairs the guard checks."""
        pairs, excluded, dropped = choose_collision_pairs(
            mjcf_path, model, self.urdf, self.srdf_info, home, self.path, *clearance
        )
        for a, b, d in dropped:
            self.log(
                f"note: links {a} and {b} are {d * 1000:.1f} mm apart at home: pair not checked"
            )
        if excluded:
            add_contact_excludes(mjcf_path, excluded)
        self.pairs_apart = bits_apart(mjcf_path, pairs)
        return pairs

    def toml_args(self, mjcf_path: Path, limits: dict, motion, pairs: list) -> dict:
        """The keyword arguments both robot.toml writers take, for the MJCF at ``mjcf_path``,
        the joint ``limits``, the derived ``motion`` limits and the collision ``pairs``."""
        return {
            "name": self.name,
            "prepared": self.urdf,
            "mjcf": mjcf_path.name,
            "joint_names": self.joint_names,
            "limits": limits,
            "motion": motion,
            "chosen": self.chosen,
            "motor_cfg": self.motor_cfg,
            "pairs": pairs,
            "control_rate": self.control_rate,
            "physics_timestep": self.physics_timestep,
            "rates_from": self.rates_from,
            "pairs_apart": self.pairs_apart,
            "disabled_by": disabled_by(self.urdf, self.srdf_path),
            "lowered": self.report.lowered,
            "motor_tables": self.motor_tables,
        }


def disabled_by(source: PreparedSource, srdf_path: Path | None) -> str | None:
    """What named the unchecked link pairs, for robot.toml's comment (None: nothing did)."""
    named = []
    if srdf_path is not None:
        named.append(f"the SRDF ({Path(srdf_path).name})")
    if source.disabled:
        named.append(f"the MJCF's <contact><exclude> ({source.path.name})")
    return " or ".join(named) or None


def written_ranges(
    mjcf_path: Path, joint_names: list[str], limits: dict, first: int = 0
) -> mujoco.MjModel:
    """The model of the MJCF as written: it writes ranges to 6 significant digits, and robot.toml
    must say the same, so each joint's (lo, hi) in ``limits`` (joint ``i`` is the model's joint
    ``first + i``) is replaced, in place, by the written one (rad)."""
    written = mujoco.MjModel.from_xml_path(str(resolved_mjcf(mjcf_path)))
    for i, j in enumerate(joint_names):
        if not written.jnt_limited[first + i]:  # continuous: stays (-inf, inf)
            continue
        lo, hi = (float(x) for x in written.jnt_range[first + i])
        limits[j] = (lo, hi, *limits[j][2:])
    return written


def bits_apart(mjcf_path: Path, pairs: list) -> list[tuple[str, str]]:
    """The geom pairs of ``pairs`` that MuJoCo never collides in the MJCF at ``mjcf_path``:
    neither ``contype_a & conaffinity_b`` nor ``contype_b & conaffinity_a`` is set and no
    ``<contact><pair>`` names both (MuJoCo's filter, ``mj_collision``; the guard checks them
    all the same)."""
    model = mujoco.MjModel.from_xml_path(str(resolved_mjcf(mjcf_path)))
    explicit = {
        frozenset((int(a), int(b))) for a, b in zip(model.pair_geom1, model.pair_geom2, strict=True)
    }
    ct, ca = model.geom_contype, model.geom_conaffinity
    apart = []
    for a, b in pairs:
        i, j = model.geom(a).id, model.geom(b).id
        if not (ct[i] & ca[j] or ct[j] & ca[i]) and frozenset((i, j)) not in explicit:
            apart.append((a, b))
    return apart


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
