"""The floors the code keeps: every room is placed on a floor of the import contract (a room left
out would be held to nothing), the contract holds (``lint-imports``, as ``make lint`` runs it), and
no private name (``_x``) is imported from another room."""

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("deploy", "eval", "robots", "policies", "stacks")


def _contracts() -> dict[str, dict]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    return {c["id"]: c for c in config["contracts"]}


def _floor_rooms() -> set[str]:
    return {room.strip() for layer in _contracts()["floors"]["layers"] for room in layer.split("|")}


def room_of(module: str) -> str:
    """The room of a dotted module name, named as the floors name it (inside ``sim2real``):
    ``deploy.<room>`` and ``eval.<room>`` (a subpackage or a top-level module), ``robots``,
    ``policies`` and ``stacks`` whole (their floor is one room each)."""
    parts = module.split(".")
    if parts[0] == "sim2real":
        parts = parts[1:] or ["sim2real"]
    if parts[0] in ("robots", "policies", "stacks") or len(parts) == 1:
        return parts[0]
    return ".".join(parts[:2])


def _modules(folder: str) -> list[tuple[str, Path]]:
    """(dotted name, path) of every module under ``folder`` (relative to the repository root)."""
    out = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        out.append((".".join(parts), path))
    return out


def test_every_room_of_deploy_and_eval_stands_on_a_floor():
    floors = _floor_rooms()
    rooms = {
        room_of(name)
        for pkg in ("deploy", "eval")
        for name, _ in _modules(f"sim2real/{pkg}")
        if name.count(".") > 1 and not name.endswith("__main__")
    }
    assert rooms - floors == set(), "rooms missing from [tool.importlinter] floors in pyproject"
    assert {"robots", "policies", "stacks"} <= floors
    assert floors - rooms - {"robots", "policies", "stacks"} == set(), "floors naming no room"


def test_room_of_names_the_room():
    assert room_of("sim2real.deploy.safety.guard") == "deploy.safety"
    assert room_of("sim2real.deploy.robot_kind") == "deploy.robot_kind"
    assert room_of("sim2real.eval.world.pushes") == "eval.world"
    assert room_of("sim2real.robots.importer.mjcf") == "robots"
    assert room_of("sim2real.stacks.loops.walk") == "stacks"


def test_no_private_name_is_imported_from_another_room():
    crossing = []
    for folder in (*(f"sim2real/{pkg}" for pkg in PACKAGES), "tests", "bench"):
        for name, path in _modules(folder):
            if "tests/data" in path.as_posix():
                continue
            here = room_of(name) if folder.startswith("sim2real/") else folder
            for node in ast.walk(ast.parse(path.read_text())):
                if not (isinstance(node, ast.ImportFrom) and node.module and node.level == 0):
                    continue
                if node.module.split(".")[0] != "sim2real" or room_of(node.module) == here:
                    continue
                crossing += [
                    f"{path.relative_to(ROOT)}: {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                ]
    assert crossing == []


@pytest.mark.skipif(
    shutil.which("lint-imports") is None
    and not (Path(sys.executable).parent / "lint-imports").exists(),
    reason="import-linter is not installed (the dev extra)",
)
def test_the_floors_hold_and_a_room_importing_upwards_breaks_them(tmp_path):
    """``lint-imports`` passes on the repository, and fails on a copy where the ground floor
    imports the runtime: the contract is not vacuous."""
    exe = shutil.which("lint-imports") or str(Path(sys.executable).parent / "lint-imports")
    ok = subprocess.run([exe], cwd=ROOT, capture_output=True, text=True)
    assert ok.returncode == 0, ok.stdout[-2000:]
    shutil.copytree(
        ROOT / "sim2real", tmp_path / "sim2real", ignore=shutil.ignore_patterns("__pycache__")
    )
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    core = tmp_path / "sim2real" / "deploy" / "core" / "modes.py"
    core.write_text(
        core.read_text() + "\n\ndef _up():\n    from sim2real.deploy.runtime import loop  # noqa\n"
    )
    broken = subprocess.run([exe], cwd=tmp_path, capture_output=True, text=True)
    assert broken.returncode != 0
    assert "sim2real.deploy.core.modes -> sim2real.deploy.runtime.loop" in broken.stdout


def test_no_function_of_the_command_lines_is_over_80_lines():
    """The entry points stay thin callers of the rooms below (deploy-run, policy-export,
    robot-import, soak-test, sim2sim, sysid, the bench): a command-line function past 80 lines
    is doing a room's work."""
    long = []
    paths = {*(ROOT / "sim2real").rglob("cli*.py"), *(ROOT / "sim2real").rglob("cli/*.py")}
    paths.add(ROOT / "bench" / "__main__.py")
    assert ROOT / "sim2real" / "eval" / "cli.py" in paths  # soak-test's
    assert ROOT / "sim2real" / "deploy" / "cli" / "deploy_run.py" in paths
    for path in sorted(paths):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                size = node.end_lineno - node.lineno + 1
                if size > 80:
                    long.append(f"{path.relative_to(ROOT)}: {node.name} {size} lines")
    assert long == []
