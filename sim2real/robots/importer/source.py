"""The importer's checked description, whatever the input format: :class:`PreparedSource`, its
joints (:class:`JointInfo`), the SRDF's collision exclusions (:func:`read_srdf`), the error
(:class:`RobotImportError`) and the refusal texts URDF and MJCF share.

A URDF becomes a PreparedSource in :func:`sim2real.robots.importer.urdf.prepare_urdf`, an MJCF in
:func:`sim2real.robots.importer.mjcf.prepare_mjcf`; the rest of the importer reads only this.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from sim2real.robots.packages import package_root
from sim2real.robots.robot import RobotSpecError

#: How a refusal for missing mesh files ends (URDF and MJCF alike).
DROP_MISSING = (
    "expected the mesh files (or --drop-missing-meshes to drop the geoms that use them, as "
    "MuJoCo users delete them)"
)
#: Smallest mass (kg) and principal inertia (kg m^2) accepted for a moving link.
MIN_MASS, MIN_INERTIA = 1e-9, 1e-12
#: How every refusal of a floating-base robot ends (URDF, SRDF and MJCF alike).
FLOATING_BASE = "a floating-base robot; expected a fixed-base arm (or --floating-base, legged)"


class RobotImportError(RobotSpecError):
    """The description cannot be imported; a one-line message naming file, element, expectation."""


class BuiltModelError(RobotImportError):
    """MuJoCo's compiler refuses the model the import built (not the user's file, which compiled
    before the import changed it): an importer's defect. The command line prefixes the source."""


def compile_built(spec):
    """Compile ``spec`` (a ``mujoco.MjSpec`` the import has edited) and return its ``MjModel``.

    Raises:
        BuiltModelError: MuJoCo's compiler refuses it (its message on one line).
    """
    try:
        return spec.compile()
    except ValueError as exc:
        message = "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        raise BuiltModelError(
            f"MuJoCo could not compile the robot the import built from it: {message} (if the "
            "file itself loads in MuJoCo, this is an importer's defect: please report it with "
            "the file)"
        ) from None


@dataclass
class JointInfo:
    """One movable joint as imported: limits in rad, rad/s and N m (``None`` when absent).

    ``velocity_from`` / ``effort_from``: where the description's value came from, as printed
    ("URDF", "MJCF actuatorfrcrange", "--velocity", ...).
    """

    name: str
    kind: str
    parent: str
    child: str
    lower: float = 0.0
    upper: float = 0.0
    velocity: float | None = None
    effort: float | None = None
    velocity_from: str = "URDF"
    effort_from: str = "URDF"


@dataclass
class PreparedSource:
    """A checked description (URDF or MJCF) ready for ``mujoco.MjSpec.from_string``.

    ``kind``: "URDF" or "MJCF"; ``text``: the rewritten URDF, or the MJCF in MuJoCo's canonical
    form (radians); ``joints``: movable joints by name; ``movable``: their names in file order;
    ``parent``: link -> (parent link, joint name, joint type) as imported (frozen joints are
    'fixed'; an MJCF body is a link); ``links``: link names in file order; ``meshdir_abs`` /
    ``meshdir_uri``: the mesh folder and how the MJCF names it (``package://...`` or a path
    relative to the robot folder's parent); ``notes``: decisions to print; ``disabled``: link
    pairs the description itself says are never checked (MJCF ``<contact><exclude>``), as sorted
    tuples; ``sites``: site name -> its body (MJCF); ``fitted``: ``(link, k)`` of the ``k``-th
    geom of a link that is a box fitted to a collision mesh (the importer's approximation, not
    the author's shape); ``fitted_geoms``: their geom names once named
    (:func:`sim2real.robots.importer.model.build_spec`); ``physics``: the line saying which integrator and
    solver settings the robot's MJCF carries (:mod:`sim2real.robots.importer.physics_option`);
    ``pairs``: the MJCF's ``<contact><pair>``s as attribute dicts and ``scene_geom`` the scene
    geom they name (the importer's floor takes its name), :mod:`sim2real.robots.importer.contact_pairs`;
    ``renamed_sites``: old -> new name of the MJCF's sites named like a body; ``floor_bits``:
    the ``(contype, conaffinity)`` of the MJCF's own floor (a scene file's plane), None without
    one; ``drive``: what an MJCF says of its drive (its ``<position>`` actuators' gains, its
    keyframe's pose: :class:`sim2real.robots.importer.mjcf_drive.SourceDrive`), None for a URDF.
    """

    path: Path
    display: str
    text: str
    joints: dict[str, JointInfo]
    movable: list[str]
    parent: dict[str, tuple[str, str, str]]
    links: list[str]
    root_link: str
    meshdir_abs: str | None = None
    meshdir_uri: str = ""
    notes: list[str] = field(default_factory=list)
    kind: str = "URDF"
    disabled: set[tuple[str, str]] = field(default_factory=set)
    sites: dict[str, str] = field(default_factory=dict)
    fitted: set[tuple[str, int]] = field(default_factory=set)
    fitted_geoms: set[str] = field(default_factory=set)
    physics: str = ""
    pairs: list[dict[str, str]] = field(default_factory=list)
    scene_geom: str | None = None
    renamed_sites: dict[str, str] = field(default_factory=dict)
    floor_bits: tuple[int, int] | None = None
    drive: object = None


@dataclass
class SrdfInfo:
    """The SRDF's ``disable_collisions`` link pairs (sorted tuples) and its path."""

    path: Path
    disabled: set[tuple[str, str]]


def read_srdf(
    path: Path, links: set[str], kind: str = "URDF", floating_base: bool = False
) -> SrdfInfo:
    """Read ``disable_collisions`` pairs; refuse a floating virtual joint or an unknown link.

    Args:
        path: The SRDF. links: Link names of the description (MJCF: body names). kind: "URDF"
            or "MJCF", for the messages. floating_base: accept a floating virtual joint.

    Raises:
        RobotImportError: invalid XML, a link not in the description, or ``<virtual_joint
            type="floating">`` (a legged robot).
    """
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise RobotImportError(f"{path}: not valid XML: {exc}") from None
    for vj in root.iter("virtual_joint"):
        if vj.get("type") == "floating" and not floating_base:
            raise RobotImportError(
                f"{path}: <virtual_joint name='{vj.get('name')}' type='floating'>: " + FLOATING_BASE
            )
    disabled = set()
    for dc in root.iter("disable_collisions"):
        a, b = dc.get("link1"), dc.get("link2")
        for link in (a, b):
            if link not in links:
                raise RobotImportError(
                    f"{path}: <disable_collisions link1='{a}' link2='{b}'>: link '{link}' is "
                    f"not in the {kind}; expected one of {sorted(x for x in links if x)}"
                )
        disabled.add(tuple(sorted((a, b))))
    return SrdfInfo(path=path, disabled=disabled)


def _display(path: Path) -> str:
    try:
        root = package_root("example-robot-data")
        return f"example-robot-data:{path.relative_to(root / 'robots').as_posix()}"
    except (RobotSpecError, ValueError):
        return path.name
