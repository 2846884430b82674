"""What the robot-import tests share: the guard that skips a module without coal or
example-robot-data, and the test humanoid (``tests/test_import_humanoid.py``) with more MJCF in
it, imported with its flags into ``<tmp>/robots/tiny``."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim2real.deploy.cli.robot_import import main
from sim2real.robots.importer.pipeline import resolve_source
from tests.test_import_humanoid import FLAGS, write_humanoid

#: The prefix of example-robot-data's descriptions.
ERD = "example-robot-data:"


def require_example_robot_data(description: str) -> None:
    """Skip the calling test module unless coal is installed and the example-robot-data
    ``description`` (a path inside the package) resolves."""
    pytest.importorskip("coal")
    try:
        resolve_source(ERD + description)
    except Exception:  # pragma: no cover
        pytest.skip("example-robot-data is not installed", allow_module_level=True)


def humanoid_with(folder: Path, xml: str, before: str = "</mujoco>") -> Path:
    """The test humanoid's MJCF written into ``folder`` with ``xml`` put before its first
    ``before`` tag; returns the MJCF's path."""
    source = write_humanoid(folder)
    source.write_text(source.read_text().replace(before, xml + "\n" + before, 1))
    return source


def import_tiny(source: Path, tmp_path: Path, *flags: str) -> tuple[int, Path]:
    """``robot-import source`` with the humanoid's flags (then ``flags``) into
    ``tmp_path/robots/tiny``: (exit code, that folder)."""
    out = tmp_path / "robots" / "tiny"
    return main([str(source), "--out", str(out), *FLAGS, *flags]), out
