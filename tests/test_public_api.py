"""The toolkit's package: ``sim2real`` holds every room of the toolkit, exposes its entry points,
and cannot be shadowed by a user's own ``robots/`` folder (the layout the README suggests for robot
descriptions); ``bench``, the benchmarks, is installed beside it (``python -m bench``)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from setuptools import find_packages

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

import sim2real

ROOT = Path(__file__).resolve().parents[1]


def test_every_public_name_resolves():
    for name in sim2real.__all__:
        assert getattr(sim2real, name) is not None, name
    assert sorted(dir(sim2real)) == sorted(sim2real.__all__)


def test_a_users_robots_folder_does_not_shadow_the_toolkit(tmp_path):
    (tmp_path / "robots" / "my_arm").mkdir(parents=True)
    code = (
        "import sys\n"
        "from sim2real import load_robot, PolicySpec\n"
        "arm = load_robot('arm3')\n"
        "assert PolicySpec.for_robot(arm).act_dim == 3\n"
        "assert 'mujoco' in sys.modules\n"
        "print('ok')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"
    # the toolkit installs no top-level ``robots``: the name is the user's
    bare = subprocess.run(
        [sys.executable, "-c", "from robots import load_robot"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert bare.returncode != 0 and "load_robot" in bare.stderr


def test_importing_the_package_loads_no_simulator(tmp_path):
    code = "import sys, sim2real; print('mujoco' in sys.modules, 'onnxruntime' in sys.modules)"
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert done.stdout.strip() == "False False", done.stderr


def test_pip_install_puts_the_toolkit_and_its_benchmarks():
    """What ``pip install .`` installs, from pyproject.toml's own package list: ``sim2real`` and
    ``bench`` (``python -m bench`` from any folder), no other top-level name (``robots`` is the
    user's)."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    include = pyproject["tool"]["setuptools"]["packages"]["find"]["include"]
    packages = find_packages(where=str(ROOT), include=include)
    assert {p.partition(".")[0] for p in packages} == {"sim2real", "bench"}
    assert "bench" in packages and not any(p.startswith("bench.") for p in packages)
    for room in ("deploy", "eval", "robots", "policies"):
        assert f"sim2real.{room}" in packages


def test_no_module_imports_a_room_by_a_bare_name():
    """Every import names the one package (``sim2real.deploy...``): a bare ``deploy`` would work
    from a checkout and fail when installed."""
    bare = re.compile(r"^\s*(from|import) (deploy|eval|robots|policies)\b", re.M)
    found = []
    for path in [
        *ROOT.glob("sim2real/**/*.py"),
        *ROOT.glob("tests/*.py"),
        *ROOT.glob("bench/*.py"),
    ]:
        found += [
            f"{path.relative_to(ROOT)}: {m.group(0).strip()}"
            for m in bare.finditer(path.read_text())
        ]
    assert not found, found


def test_the_benchmarks_run_from_any_folder_once_installed(tmp_path):
    """``python -m bench`` runs the checkout's ``bench`` from a folder outside it, with no
    PYTHONPATH: the editable install (``make install``) maps ``bench`` beside ``sim2real``.
    Skipped, naming it, when the interpreter's installed ``bench`` is another checkout's (a second
    worktree) or missing (an install older than this package list)."""
    import os

    import pytest

    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    where = subprocess.run(
        [sys.executable, "-c", "import bench; print(bench.__file__)"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    installed = (
        Path(where.stdout.strip()).resolve().parent.parent if where.returncode == 0 else None
    )
    if installed != ROOT:
        pytest.skip(f"the installed bench is {installed}'s, not this checkout's ({ROOT})")
    done = subprocess.run(
        [sys.executable, "-m", "bench", "--help"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: python -m bench") and "--only" in done.stdout


def test_the_benchmarks_results_go_beside_them_or_to_the_working_folder(tmp_path, monkeypatch):
    """A run without ``--out`` writes the checkout's ``bench/results.json`` where that folder is
    writable (a checkout, an editable install), else ``results.json`` in the working folder (a
    wheel installed where the user cannot write)."""
    from bench import __main__ as bench_main

    beside = tmp_path / "bench" / "results.json"
    beside.parent.mkdir()
    assert bench_main.default_out(beside) == beside
    assert bench_main.parse_args(["--only", "tick"]).out == bench_main.RESULTS
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setattr(bench_main.os, "access", lambda path, mode: False)
    assert bench_main.default_out(beside) == work / "results.json"
    assert bench_main.parse_args(["--only", "tick"]).out == work / "results.json"
    named = tmp_path / "mine.json"
    assert bench_main.parse_args(["--out", str(named)]).out == named
