"""What a newcomer notices (issue 18): one atomic write and one file hash, one exception base
class, clear errors for a file given as the soak's folder and for damaged torch files, the runtime
install running without torch, package metadata without deprecated license fields, and no
measured figures in docstrings."""

import ast
import hashlib
import importlib
import inspect
import os
import pkgutil
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from robots.errors import Sim2RealError
from robots.files import atomic_path, atomic_write, sha256_file

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("deploy", "eval", "robots", "policies")


def _sources(*folders: str) -> list[Path]:
    return sorted(p for f in folders for p in (ROOT / f).rglob("*.py"))


# ====================================================================== files
def test_atomic_write_fsyncs_a_temporary_file_in_the_folder_then_replaces(tmp_path, monkeypatch):
    """The bytes reach the disk under a temporary name in the destination's folder before the
    rename: a reader (or a crash) never sees half a file."""
    dest = tmp_path / "report.json"
    dest.write_text("old")
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", Path(os.readlink(f"/proc/self/fd/{fd}"))))
        return real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", Path(src), Path(dst)))
        return real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    assert atomic_write(dest, "é\n") == dest
    monkeypatch.undo()
    assert dest.read_bytes() == "é\n".encode()
    (_, synced), (_, src, dst) = events
    assert synced == src and src.parent == tmp_path and src != dest and dst == dest
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]
    (tmp_path / "plain.json").write_text("{}")  # as readable as a file written plainly
    with atomic_path(tmp_path / "new.onnx") as tmp:
        tmp.write_bytes(b"x")
    for written in (tmp_path / "new.onnx", atomic_write(tmp_path / "new.json", b"{}")):
        assert written.stat().st_mode & 0o777 == (tmp_path / "plain.json").stat().st_mode & 0o777


def test_a_failed_write_leaves_the_destination_as_it_was(tmp_path):
    dest = tmp_path / "model.onnx"
    dest.write_bytes(b"previous")
    with pytest.raises(RuntimeError, match="check failed"), atomic_path(dest) as tmp:
        tmp.write_bytes(b"new, unchecked")
        raise RuntimeError("check failed")
    assert dest.read_bytes() == b"previous"
    with atomic_path(dest) as tmp:  # the body's file becomes the destination
        tmp.write_bytes(b"new")
    assert dest.read_bytes() == b"new"
    (tmp_path / "folder").mkdir()
    with pytest.raises(OSError):  # a folder in the way: refused, nothing left behind
        atomic_write(tmp_path / "folder", b"x")
    with pytest.raises(FileNotFoundError):
        atomic_write(tmp_path / "missing" / "x.json", b"x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder", "model.onnx"]


def test_sha256_file_is_the_digest_of_the_whole_file(tmp_path):
    data = np.random.default_rng(0).bytes(5 * (1 << 20) // 2)  # 2.5 chunks
    (tmp_path / "big.bin").write_bytes(data)
    assert sha256_file(tmp_path / "big.bin") == hashlib.sha256(data).hexdigest()


def test_one_atomic_write_and_one_sha256_file_in_the_codebase():
    """Durable writes and file digests live in robots/files.py only (no copies to drift)."""
    home = ROOT / "robots" / "files.py"
    copies = []
    for path in _sources(*PACKAGES, "bench"):
        if path == home:
            continue
        text = path.read_text()
        for pattern in (
            r"os\.fsync\(",
            r"def (atomic_write|sha256_file|file_sha256)\b",
            r"iter\(lambda: \w+\.read\(",
        ):
            copies += [
                f"{path.relative_to(ROOT)}: {m.group(0)}" for m in re.finditer(pattern, text)
            ]
    assert not copies, "use robots.files instead:\n" + "\n".join(copies)


# ====================================================================== exceptions
def _toolkit_exceptions() -> list[type[BaseException]]:
    found = []
    for pkg in PACKAGES:
        module = importlib.import_module(pkg)
        names = [pkg] + [m.name for m in pkgutil.walk_packages(module.__path__, pkg + ".")]
        for name in names:
            if name.rsplit(".", 1)[-1] == "__main__":
                continue
            mod = importlib.import_module(name)
            found += [
                c
                for _, c in inspect.getmembers(mod, inspect.isclass)
                if c.__module__ == name and issubclass(c, BaseException) and c is not Sim2RealError
            ]
    return found


def test_every_toolkit_exception_derives_from_the_base_and_keeps_its_builtin_base():
    """``except Sim2RealError`` catches every error the toolkit defines, and ``except
    ValueError`` (or OSError, RuntimeError) clauses written before the base still catch theirs."""
    found = _toolkit_exceptions()
    names = {c.__name__ for c in found}
    assert {"SpecError", "PolicyLoadError", "RobotSpecError", "ServoBusError", "FilmError"} <= names
    wrong = [f"{c.__module__}.{c.__name__}" for c in found if not issubclass(c, Sim2RealError)]
    assert not wrong, f"derive these from robots.errors.Sim2RealError: {wrong}"
    builtin = [
        f"{c.__module__}.{c.__name__}"
        for c in found
        if not any(
            b.__module__ == "builtins" and b not in (Exception, BaseException, object)
            for b in c.__mro__
        )
    ]
    assert not builtin, f"keep a built-in base (ValueError, RuntimeError, OSError): {builtin}"


@pytest.fixture(scope="module")
def arm_onnx(tmp_path_factory) -> Path:
    """policies/arm.onnx as ``make export`` writes it; exported here from policies/arm.pt in a
    fresh clone (ONNX files are built, not committed)."""
    path = ROOT / "policies" / "arm.onnx"
    if path.is_file():
        return path
    from deploy.export import export_policy

    pt = tmp_path_factory.mktemp("arm") / "arm.pt"
    pt.write_bytes((ROOT / "policies" / "arm.pt").read_bytes())
    return export_policy(pt)


# ====================================================================== error messages
def test_soak_test_out_below_a_file_names_it_and_exits_3(tmp_path, capsys, arm_onnx):
    from eval import cli

    (tmp_path / "notes.txt").write_text("a file")
    out = tmp_path / "notes.txt" / "campaign"
    argv = ["--policy", str(arm_onnx), "--hours", "0.001", "--out", str(out)]
    assert cli.main(argv) == cli.EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert f"--out: {tmp_path / 'notes.txt'} is a file; expected the campaign folder" in err
    assert "Errno" not in err


def test_a_damaged_torch_file_is_refused_in_our_words(tmp_path, capsys):
    """Bytes that start like a pickle (1 random file in 256 does) or a zip but cannot be read get
    our message, never torch's advice to load with weights_only=False."""
    import torch

    from deploy.export import EXIT_BAD_INPUT, main

    rng = np.random.default_rng(0)
    (tmp_path / "random.pt").write_bytes(b"\x80\x02" + rng.bytes(4094))
    torch.save({"w": torch.zeros(64, 64)}, tmp_path / "good.pt")
    (tmp_path / "cut.pt").write_bytes((tmp_path / "good.pt").read_bytes()[:200])
    for name in ("random.pt", "cut.pt"):
        for argv in ([str(tmp_path / name)], ["--inspect", str(tmp_path / name)]):
            assert main(argv) == EXIT_BAD_INPUT, argv
            err = capsys.readouterr().err
            assert f"{tmp_path / name}: not a readable torch file (truncated or corrupt?)" in err
            assert "weights_only" not in err and "PyTorch 2.6" not in err and "Warning" not in err


def test_a_pickled_object_still_points_to_trust_pickle(tmp_path, capsys):
    import torch

    from deploy.export import EXIT_BAD_INPUT, main

    torch.save({"net": torch.nn.Linear(2, 2)}, tmp_path / "module.pt")
    assert main([str(tmp_path / "module.pt")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "module.pt: holds a pickled Python object (torch.nn.modules.linear.Linear)" in err
    assert "--trust-pickle" in err and "weights_only" not in err


def test_deploy_run_given_a_torch_file_says_to_export_it(capsys):
    from deploy.cli.deploy_run import EXIT_BAD_INPUT, deploy_run_main

    pt = ROOT / "policies" / "arm.pt"
    assert deploy_run_main(["--robot", "arm3", "--policy", str(pt), "--duration", "1"]) == (
        EXIT_BAD_INPUT
    )
    err = capsys.readouterr().err
    assert f"{pt}: not an ONNX file" in err and f"export it first with `policy-export {pt}`" in err


# ====================================================================== runtime install
#: Run first in the child: importing torch, Stable-Baselines3 or Gymnasium fails, as in the
#: runtime install (``pip install .``, no extras).
NO_TRAINING_STACK = textwrap.dedent(
    """
    import sys

    BLOCKED = {"torch", "stable_baselines3", "sb3_contrib", "gymnasium", "onnxscript"}

    class NotInstalled:
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] in BLOCKED:
                raise ImportError(f"No module named {name!r} (runtime install)")
            return None

    sys.meta_path.insert(0, NotInstalled())
    try:
        import torch  # noqa: F401
    except ImportError:
        pass
    else:
        raise SystemExit("the import blocker does not work")
    """
)


def test_deploy_run_runs_without_torch(tmp_path, arm_onnx):
    """The runtime install has no torch: deploy-run imports and runs a shipped ONNX policy."""
    report = tmp_path / "run.json"
    argv = ["--robot", "arm3", "--policy", str(arm_onnx), "--duration", "2"]
    argv += ["--report", str(report)]
    code = NO_TRAINING_STACK + textwrap.dedent(
        f"""
        from deploy.cli.deploy_run import deploy_run_main

        code = deploy_run_main({argv!r})
        loaded = sorted(m for m in sys.modules if m.partition(".")[0] in BLOCKED)
        assert not loaded, loaded
        raise SystemExit(code)
        """
    )
    env = {**os.environ, "ORT_DISABLE_TELEMETRY": "1"}
    env.pop("MUJOCO_GL", None)
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    assert "final state       RUNNING" in proc.stdout
    assert report.is_file()


# ====================================================================== metadata and docs
def test_license_is_an_spdx_expression_without_deprecated_fields():
    """setuptools >= 77 warns, on every install, about a ``project.license`` table and about
    ``License ::`` classifiers beside an SPDX ``license`` string."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert isinstance(project["license"], str) and project["license"] == "Apache-2.0"
    assert not [c for c in project.get("classifiers", []) if c.startswith("License ::")]


#: Figures that come from running the code (timings, throughput, speed-ups): they belong in
#: ``docs/measurements.md`` and the bench, where they are dated, not in docstrings.
MEASURED = re.compile(r"~\s*\d[\d.]*\s*(us|µs|ms)\b|\d[\d,.]*\s*steps/s|\d+(\.\d+)?\s*x faster")


def test_no_measured_figures_in_docstrings():
    hits = []
    for path in _sources(*PACKAGES):
        tree = ast.parse(path.read_text())
        nodes = [tree] + [
            n
            for n in ast.walk(tree)
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef)
        ]
        for node in nodes:
            doc = ast.get_docstring(node) or ""
            hits += [f"{path.relative_to(ROOT)}: {m.group(0)!r}" for m in MEASURED.finditer(doc)]
    assert not hits, "move measured figures to docs/measurements.md:\n" + "\n".join(hits)
