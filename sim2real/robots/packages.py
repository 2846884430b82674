"""Installed description packages: ``package://PACKAGE/...`` URIs and the MJCF that names one.

:func:`package_root` finds an installed package (``SIM2REAL_PACKAGE_PATH``, then the Python
distributions of ``PACKAGE_LOCATIONS``); :func:`resolved_mjcf` gives MuJoCo and Pinocchio an MJCF
whose ``package://`` meshdir is resolved. Both raise :class:`sim2real.robots.robot.RobotSpecError`.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

from sim2real.robots.files import atomic_write
from sim2real.robots.robot import RobotSpecError

#: Prefix of an MJCF ``meshdir`` that names an installed package instead of a folder.
PACKAGE_SCHEME = "package://"
#: Where installed description packages keep their files, inside their Python distribution
#: (example-robot-data installs through cmeel under ``cmeel.prefix/share/<name>``).
PACKAGE_LOCATIONS = {
    "example-robot-data": ("example-robot-data", "cmeel.prefix/share/example-robot-data")
}


def package_root(package: str) -> Path:
    """Folder of an installed description package (``package://PACKAGE/...`` URIs).

    Looks in the folders of the ``SIM2REAL_PACKAGE_PATH`` environment variable (``os.pathsep``
    separated, each holding ``PACKAGE/``), then in the Python distributions of
    ``PACKAGE_LOCATIONS``.

    Raises:
        RobotSpecError: the package is not installed.
    """
    for folder in filter(None, os.environ.get("SIM2REAL_PACKAGE_PATH", "").split(os.pathsep)):
        candidate = Path(folder) / package
        if candidate.is_dir():
            return candidate.resolve()
    if package in PACKAGE_LOCATIONS:
        from importlib import metadata

        dist_name, inside = PACKAGE_LOCATIONS[package]
        try:
            root = Path(str(metadata.distribution(dist_name).locate_file(inside)))
        except metadata.PackageNotFoundError:
            root = None
        if root is not None and root.is_dir():
            return root.resolve()
        hint = f"pip install {dist_name}  (or: pip install 'sim2real-deploy[robots]')"
    else:
        known = sorted(PACKAGE_LOCATIONS)
        hint = f"put its folder in a folder listed in SIM2REAL_PACKAGE_PATH (known: {known})"
    raise RobotSpecError(f"package '{package}' is not installed: {hint}")


def package_path_hint(package: str, near: Path | None = None) -> str:
    """What to set so that ``package://PACKAGE/...`` resolves, for a refusal: the
    ``SIM2REAL_PACKAGE_PATH`` variable (ROS's ``ROS_PACKAGE_PATH`` is not read) and the folder to
    put in it, the parent of a folder named ``package`` that holds ``near`` (a description inside
    its package, as ROS packages keep ``urdf/`` beside ``meshes/``) when there is one; what it
    holds now when it is set."""
    now = os.environ.get("SIM2REAL_PACKAGE_PATH", "")
    above = [] if near is None else [near.resolve(), *near.resolve().parents]
    where = next((p.parent for p in above if p.name == package), None)
    value = f"{where}{os.pathsep}$SIM2REAL_PACKAGE_PATH" if where and now else where
    folder = (
        f"export SIM2REAL_PACKAGE_PATH={value}" if where is not None
        else f"set SIM2REAL_PACKAGE_PATH to the folder that holds {package}/"
    )  # fmt: skip
    found = (
        f" (SIM2REAL_PACKAGE_PATH={now}: no {package}/ in it)"
        if now
        else " (SIM2REAL_PACKAGE_PATH is not set)"
    )
    return f"package '{package}' not found{found}; {folder}"


def resolve_package_uri(uri: str) -> Path:
    """``package://PACKAGE/rest`` -> the file's path in the installed package (not checked)."""
    package, _, rest = uri[len(PACKAGE_SCHEME) :].partition("/")
    return package_root(package) / rest


def resolved_mjcf(mjcf: Path) -> Path:
    """The MJCF MuJoCo and Pinocchio read: ``mjcf`` itself, or, when its ``<compiler meshdir>``
    names an installed package (``package://...``), a copy in the temporary folder with the
    meshdir resolved to an absolute path (the robot folder holds no third-party meshes)."""
    root = ET.parse(mjcf).getroot()
    compiler = root.find("compiler")
    meshdir = None if compiler is None else compiler.get("meshdir")
    if not meshdir or not meshdir.startswith(PACKAGE_SCHEME):
        return mjcf
    try:
        folder = resolve_package_uri(meshdir)
    except RobotSpecError as exc:
        raise RobotSpecError(f"{mjcf}: <compiler meshdir='{meshdir}'>: {exc}") from None
    if not folder.is_dir():
        raise RobotSpecError(
            f"{mjcf}: <compiler meshdir='{meshdir}'> resolves to {folder}, which does not exist"
        )
    text = mjcf.read_text(encoding="utf-8").replace(
        f'meshdir="{meshdir}"', f'meshdir="{folder.as_posix()}"', 1
    )
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / "sim2real-robots" / digest / mjcf.name
    if not out.is_file():
        out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(out, text)
    return out
