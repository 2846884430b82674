"""The physics options an imported robot's MJCF carries: MuJoCo's ``<option>`` integrator and
solver settings, kept from the description, set with ``robot-import --option KEY=VALUE``, or the
toolkit's default.

A policy learns its training simulator; the integrator and the solver's iterations are part of
it (mjlab trains its G1 with 10 solver and 20 line-search iterations, MuJoCo's defaults are 100
and 50; a published MJCF may ask for Euler). :func:`apply_options` writes, per key, the flag's
value, else the one the MJCF states (``<option>`` in the file or a file it includes), else the
default: the toolkit's implicit-fast integrator (stable with stiff PD servos at the physics
timestep), MuJoCo's for the rest. It returns one line saying what the robot uses and where each
value came from. The plant (:meth:`robots.Robot.mjspec`) keeps them, and the ``<flag>``s the
MJCF sets (``eulerdamp``, ...: MuJoCo writes them into the reduced file). The timestep
(:func:`choose_timestep`) is ``--physics-timestep``, else the MJCF's, else the toolkit's
default; it must divide the control period.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco

from sim2real.robots.importer.flags import split
from sim2real.robots.importer.source import RobotImportError

#: ``<option>`` attributes kept or set, with their MjSpec enum (None: a number of that type).
OPTIONS: dict[str, tuple[type, dict[str, int] | None]] = {
    "integrator": (
        int,
        {
            "Euler": mujoco.mjtIntegrator.mjINT_EULER,
            "RK4": mujoco.mjtIntegrator.mjINT_RK4,
            "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
            "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
        },
    ),
    "cone": (
        int,
        {"pyramidal": mujoco.mjtCone.mjCONE_PYRAMIDAL, "elliptic": mujoco.mjtCone.mjCONE_ELLIPTIC},
    ),  # fmt: skip
    "solver": (
        int,
        {
            "PGS": mujoco.mjtSolver.mjSOL_PGS,
            "CG": mujoco.mjtSolver.mjSOL_CG,
            "Newton": mujoco.mjtSolver.mjSOL_NEWTON,
        },
    ),
    "iterations": (int, None),
    "ls_iterations": (int, None),
    "noslip_iterations": (int, None),
    "impratio": (float, None),
    "tolerance": (float, None),
    "ls_tolerance": (float, None),
}
#: The toolkit's own defaults where they are not MuJoCo's.
TOOLKIT_DEFAULTS = {"integrator": "implicitfast"}


def source_options(path: Path, keys=OPTIONS) -> dict[str, str]:
    """The ``<option>`` attributes of :data:`OPTIONS` (or ``keys``) an MJCF states, in the file
    or a file it includes (a later one wins, as in MuJoCo); empty for a URDF or an unreadable
    file (the importer's own parse reports those)."""
    out: dict[str, str] = {}

    def visit(file: Path, depth: int) -> None:
        try:
            root = ET.parse(file).getroot()
        except (OSError, ET.ParseError):
            return
        for element in root.iter():
            if element.tag == "option":
                out.update({k: v for k, v in element.attrib.items() if k in keys})
            elif element.tag == "include" and depth < 8 and element.get("file"):
                visit(file.parent / element.get("file"), depth + 1)

    if path.suffix.lower() != ".urdf":
        visit(path, 0)
    return out


def choose_timestep(path: Path, flag: float | None, default: float) -> tuple[float, str]:
    """The physics timestep (s) of the imported robot and where it came from: ``flag``
    (``--physics-timestep``) when given, else the MJCF's ``<option timestep>`` when it states
    one, else ``default``.

    Raises:
        RobotImportError: the MJCF's timestep is not a positive number.
    """
    if flag is not None:
        return flag, "--physics-timestep"
    stated = source_options(path, ("timestep",)).get("timestep")
    if stated is None:
        return default, "the toolkit's default"
    try:
        value = float(stated)
    except ValueError:
        value = -1.0
    if not value > 0:
        raise RobotImportError(
            f"{path}: <option timestep='{stated}'>: expected a positive number of seconds "
            "(or --physics-timestep S)"
        )
    return value, "the MJCF"


def _value(key: str, text: str, where: str):
    kind, names = OPTIONS[key]
    if names is not None:
        if text not in names:
            raise RobotImportError(f"{where}: {key} '{text}': expected one of {list(names)}")
        return names[text]
    try:
        value = kind(text)
    except ValueError:
        expected = "an integer" if kind is int else "a number"
        raise RobotImportError(f"{where}: {key} '{text}': expected {expected}") from None
    if not value >= 0:
        raise RobotImportError(f"{where}: {key} '{text}': expected a value >= 0")
    return value


def apply_options(spec: mujoco.MjSpec, stated: dict[str, str], flags: list[str]) -> str:
    """Set ``spec.option`` from ``--option KEY=VALUE`` ``flags`` (later win), else the MJCF's
    ``stated`` options, else the defaults; return the line saying what the robot uses.

    Raises:
        RobotImportError: a flag without ``=``, an unknown key (naming the keys), or a value of
            the wrong kind (naming the expected values); an invalid value the MJCF states.
    """
    given: dict[str, str] = {}
    for text in flags:
        key, value = split("--option", text, "KEY=VALUE, e.g. iterations=10")
        if key not in OPTIONS:
            raise RobotImportError(f"--option '{text}': unknown key '{key}'; expected one of "
                                   f"{list(OPTIONS)}")  # fmt: skip
        _value(key, value, f"--option '{text}'")
        given[key] = value
    parts = []
    for key in OPTIONS:
        if key in given:
            text, origin = given[key], "--option"
        elif key in stated:
            text, origin = stated[key], "the MJCF"
        elif key in TOOLKIT_DEFAULTS:
            text, origin = TOOLKIT_DEFAULTS[key], "the toolkit's default"
        else:
            continue
        setattr(spec.option, key, _value(key, text, f"<option {key}>"))
        parts.append(f"{key} {text} ({origin})")
    return "physics: " + ", ".join(parts) + "; MuJoCo's defaults for the rest"
