"""What a newcomer notices: one atomic write and one file hash, one exception base class, clear
errors for a file given as the soak's folder and for damaged torch files, the runtime install
running without torch, package metadata without deprecated license fields, and docs a reader can
follow: no measured figures in docstrings, no citations of documents a reader of the repository
does not have, short module docstrings."""

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
import tokenize
from pathlib import Path

import numpy as np
import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from sim2real.robots.errors import Sim2RealError
from sim2real.robots.files import atomic_path, atomic_write, sha256_file

ROOT = Path(__file__).resolve().parent.parent
#: the rooms, as folders of the one package
PACKAGES = ("sim2real/deploy", "sim2real/eval", "sim2real/robots", "sim2real/policies")


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
    """Durable writes and file digests live in sim2real/robots/files.py only (no copies to drift)."""
    home = ROOT / "sim2real" / "robots" / "files.py"
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
    assert not copies, "use sim2real.robots.files instead:\n" + "\n".join(copies)


# ====================================================================== exceptions
def _toolkit_exceptions() -> list[type[BaseException]]:
    found = []
    for pkg in (f.replace("/", ".") for f in PACKAGES):
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
    assert not wrong, f"derive these from sim2real.robots.errors.Sim2RealError: {wrong}"
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
    """policies/arm.onnx as ``make export`` writes it; exported here from sim2real/policies/arm.pt in a
    fresh clone (ONNX files are built, not committed)."""
    path = ROOT / "sim2real" / "policies" / "arm.onnx"
    if path.is_file():
        return path
    from sim2real.deploy.export import export_policy

    pt = tmp_path_factory.mktemp("arm") / "arm.pt"
    pt.write_bytes((ROOT / "sim2real" / "policies" / "arm.pt").read_bytes())
    return export_policy(pt)


# ====================================================================== error messages
def test_soak_test_out_below_a_file_names_it_and_exits_3(tmp_path, capsys, arm_onnx):
    from sim2real.eval import cli

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

    from sim2real.deploy.cli.policy_export import EXIT_BAD_INPUT, main

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

    from sim2real.deploy.cli.policy_export import EXIT_BAD_INPUT, main

    torch.save({"net": torch.nn.Linear(2, 2)}, tmp_path / "module.pt")
    assert main([str(tmp_path / "module.pt")]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "module.pt: holds a pickled Python object (torch.nn.modules.linear.Linear)" in err
    assert "--trust-pickle" in err and "weights_only" not in err


def test_deploy_run_given_a_torch_file_says_to_export_it(capsys):
    from sim2real.deploy.cli.deploy_run import EXIT_BAD_INPUT, deploy_run_main

    pt = ROOT / "sim2real" / "policies" / "arm.pt"
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
        from sim2real.deploy.cli.deploy_run import deploy_run_main

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


#: Every package whose docstrings and comments a reader meets.
DOC_PACKAGES = ("sim2real", "bench")


def _docstrings(path: Path) -> list[tuple[str, str]]:
    """(where, docstring) of the module and of every class and function of ``path``."""
    tree = ast.parse(path.read_text())
    nodes = [tree] + [
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef)
    ]
    return [
        (getattr(n, "name", "module"), doc)
        for n in nodes
        if (doc := ast.get_docstring(n)) is not None
    ]


def _comments(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every ``#`` comment of ``path``."""
    with path.open("rb") as f:
        tokens = list(tokenize.tokenize(f.readline))
    return [(t.start[0], t.string) for t in tokens if t.type == tokenize.COMMENT]


# A figure: a number (thousands separated by commas, decimals, exponent) and a unit, a unit being
# a time, a size, a rate (anything per second), a physical unit, ``%`` or a factor ``x``. Counts
# (steps, ticks, samples) are settings far more often than results and are not units here.
_NUMBER = r"(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:e-?\d+)?"
_UNIT = (
    r"(?:%|x\b(?!\s*\d)|[a-zA-Zµ]+/s\b|(?:us|µs|ns|ms|s|sec|secs|seconds?|min|mins|minutes?|h|hr"
    r"|hours?|days?|B|bytes?|kB|KB|KiB|MB|MiB|GB|GiB|Hz|kHz|MHz|rad|mrad|deg|degC|°C?|K|N|Nm"
    r"|N\s?m|mm|cm|m|km|W|mW|kW|V|mV|A|mA|J|fps)\b)"
)
_FIGURE = re.compile(r"(?<![\w.\-/])" + _NUMBER + r"\s*" + _UNIT)
#: An approximate figure: ``~40 s``, ``about 3 %``, ``≈ 12 MB``, ``roughly 2-3 min``.
APPROXIMATE = re.compile(
    r"(?:~|≈|\babout\b|\broughly\b|\baround\b)\s*"
    + _NUMBER
    + r"(?:\s*(?:-|to)\s*"
    + _NUMBER
    + r")?\s*"
    + _UNIT
)
#: Words that make a figure in the same sentence a measurement (``wall`` but not wall clock).
MEASUREMENT_WORD = re.compile(
    r"\bmeasured\b|\btook\b|\btakes about\b|\bobserved\b|\bprofiled\b|\bbenchmark(?:ed|s)?\b"
    r"|\bp50\b|\bp99(?:\.9)?\b|\bmedian\b|\bwall\b(?![ -]?clock)|\bfaster\b|\bslower\b"
    r"|\bspeed-?ups?\b|\bper second on this machine\b|\bin our runs?\b",
    re.IGNORECASE,
)
#: A run cited as a figure's source: ``(..., 9 %, ``deploy-run --robot arm3 --duration 400``)``.
CITED_RUN = re.compile(r"``(?:deploy-run|soak-test|make \w+|python -m [\w.]+) [^`]*``")
#: What makes a figure a limit or a setting, not a result: a bound just before it (``<= 50 us``,
#: ``more than 0.25 s``, ``every 2 s``) or a named constant it is the value of
#: (``TRACKING_TOLERANCE`` (0.2 m/s)).
_BOUND = re.compile(
    r"(?:<=?|>=?|=|≤|≥|\bat (?:most|least)|\bmore than|\bless than|\bunder|\bover|\bwithin"
    r"|\bup to|\bbelow|\babove|\bevery|\blimit|\btarget)\s*$",
    re.IGNORECASE,
)
_CONSTANT = re.compile(r"``[A-Z][A-Z0-9_]*``[^.;`]{0,20}$")
_SENTENCE_END = re.compile(r"(?<=[.!?;])\s+|\n\s*\n")


def _a_limit(text: str, start: int) -> bool:
    before = text[:start]
    return bool(_BOUND.search(before[-30:]) or _CONSTANT.search(before))


def measured_figures(doc: str) -> list[str]:
    """The measured figures of a docstring: approximate figures, figures in a sentence with a
    word of measurement, and figures beside a cited run; limits and named constants excepted."""
    hits = [m.group(0) for m in APPROXIMATE.finditer(doc)]
    for sentence in _SENTENCE_END.split(doc):
        sentence = " ".join(sentence.split())
        word = MEASUREMENT_WORD.search(sentence)
        if word:
            hits += [
                f"{m.group(0)} ({word.group(0)})"
                for m in _FIGURE.finditer(sentence)
                if not _a_limit(sentence, m.start())
            ]
    for group in re.finditer(r"\(([^()]*)\)", " ".join(doc.split())):
        inside = group.group(1)
        if CITED_RUN.search(inside):
            hits += [
                f"{m.group(0)} (a cited run)"
                for m in _FIGURE.finditer(inside)
                if not _a_limit(inside, m.start())
            ]
    return hits


def test_the_measured_figure_patterns_tell_figures_from_constants():
    measured = [
        "The soak took 9.9 min on one core.",
        "Its export ran in ~0.1 s.",
        "A film is about 1 MB.",
        "The cache is ≈ 12 MB.",
        "It lost roughly 3 % of the frames.",
        "The kernel was measured at 5 us per tick.",
        "p50 of the tick: 62.5 us.",
        "The batched path is 15x faster.",
        "In our runs it stopped after 40 s.",
        "(arm3: 9 % over, ``deploy-run --robot arm3 --duration 400``)",
    ]
    constants = [
        "Encoder noise sigma 0.0157 rad (the datasheet's resolution).",
        "A new goal every 4 s; the default period is 2.5 s.",
        "Return delay 500 us, the factory default (e-Manual).",
        "When the plant falls more than 0.25 s behind (a machine slower than real time), it resets.",
        "Target: overhead without physics <= 50 us p50.",
        "Within ``TRACKING_TOLERANCE`` (0.2 m/s), measured on the averaged velocity.",
        "``flags`` (4, envs) bool: rows new safe stop, took over, resumed.",
        "Latencies in 1 us bins; the wall clock's period is 1/500 s.",
        "The same 8,192 samples per update as 16 x 512 learned faster per sample.",
        "factor ~ U(1 - r, 1 + r)",
    ]
    assert [s for s in measured if not measured_figures(s)] == []
    assert {s: measured_figures(s) for s in constants if measured_figures(s)} == {}


def test_no_measured_figures_in_docstrings_in_any_unit():
    """A figure measured by running the code goes stale as the code changes: timings, sizes,
    rates, success rates and speed-ups belong in docs/measurements.md, dated by commit."""
    hits = [
        f"{path.relative_to(ROOT)}: {where}: {figure!r}"
        for path in _sources(*DOC_PACKAGES)
        for where, doc in _docstrings(path)
        for figure in measured_figures(doc)
    ]
    assert not hits, "move measured figures to docs/measurements.md:\n" + "\n".join(hits)


#: Documents a reader of the repository does not have: the design notes and pitfalls of the
#: project's planning, its issue tracker (an issue's number; an upstream issue is cited as
#: ``owner/repo#N`` or a URL) and the sections of its seed specification.
UNAVAILABLE_REFERENCE = re.compile(
    r"\b(?:DESIGN|PITFALLS)\.md\b|\bissues?\s+#?\d+|\bseed(?:'s)?\s+sections?\s+\d+",
    re.IGNORECASE,
)


def test_no_docstring_or_comment_cites_a_document_the_reader_does_not_have():
    hits = []
    for path in _sources(*DOC_PACKAGES):
        name = path.relative_to(ROOT)
        for where, doc in _docstrings(path):
            hits += [
                f"{name}: docstring of {where}: {m.group(0)!r}"
                for m in UNAVAILABLE_REFERENCE.finditer(doc)
            ]
        for line, comment in _comments(path):
            hits += [
                f"{name}:{line}: comment: {m.group(0)!r}"
                for m in UNAVAILABLE_REFERENCE.finditer(comment)
            ]
    assert not hits, "say what the reference says, or cite what a reader can open:\n" + "\n".join(
        hits
    )


#: Files a reader opens beside the code, besides its docstrings and comments: the user
#: documentation, the robots' and motors' descriptions, the soak's worlds, the policies' ranges
#: files and recipes, the package metadata, the JSON of the documentation and the benchmarks, and
#: the tests. tests/data is other people's artifacts, kept as published, and is left out.
REFERENCE_FILES = (
    "README.md",
    "docs/*.md",
    "sim2real/robots/*/robot.toml",
    "sim2real/robots/motors/*.toml",
    "sim2real/eval/world/*.toml",
    "sim2real/policies/*.toml",
    "pyproject.toml",
    "docs/**/*.json",
    "bench/**/*.json",
    "sim2real/policies/*.json",
    "tests/*.py",
)
#: A citation of the project's issue tracker by number, or of a section of the seed specification,
#: with or without its number: say what the rule or the figure is, not where it was decided. An
#: upstream issue names its repository and a ``#`` ("the SO-ARM100 issue #134"): a reader can open it.
UNAVAILABLE_IN_FILES = re.compile(r"\bissues?\s+\d+|\bseed(?:'s)?\s+sections?\b", re.IGNORECASE)


def test_no_document_description_or_test_cites_a_document_the_reader_does_not_have():
    paths = sorted({p for pattern in REFERENCE_FILES for p in ROOT.glob(pattern)})
    assert (
        ROOT / "README.md" in paths and ROOT / "sim2real" / "robots" / "go2" / "robot.toml" in paths
    )
    hits = []
    for path in paths:
        text = path.read_text()
        hits += [
            f"{path.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)!r}"
            for m in UNAVAILABLE_IN_FILES.finditer(text)
        ]
    assert not hits, "say what the reference says, or cite what a reader can open:\n" + "\n".join(
        hits
    )


#: The longest module docstring: what the module is, shapes, units, errors, sources of
#: constants. User documentation goes to README.md and docs/, the design to docs/architecture.md.
MODULE_DOCSTRING_LINES = 30


def test_module_docstrings_are_short():
    long = []
    for path in _sources(*DOC_PACKAGES):
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        if len(doc.splitlines()) > MODULE_DOCSTRING_LINES:
            long.append(f"{path.relative_to(ROOT)}: {len(doc.splitlines())} lines")
    assert not long, f"module docstrings of at most {MODULE_DOCSTRING_LINES} lines:\n" + "\n".join(
        long
    )


#: The longest module, in lines: past it a module holds more than one concept; split it by concept.
MODULE_LINES = 500
#: Modules still past MODULE_LINES, to be split; the list only shrinks (an entry back within the
#: limit, or gone, fails the test until it is removed here).
LONG_MODULES: set[str] = set()


def _module_length_problems(root: Path, paths: list[Path], allowed: set[str]) -> list[str]:
    """A module past MODULE_LINES not in ``allowed``, and an ``allowed`` entry within it (or
    gone): each a line naming it."""
    lines = {str(p.relative_to(root)): len(p.read_text().splitlines()) for p in paths}
    long = {name: n for name, n in lines.items() if n > MODULE_LINES}
    return _ratchet(
        long,
        allowed,
        lambda name, n: f"{name}: {n} lines (at most {MODULE_LINES}: split it by concept)",
        f"within {MODULE_LINES} lines now (or gone): remove it from LONG_MODULES",
    )


def _ratchet(found: dict, allowed: set[str], problem, stale: str) -> list[str]:
    """An allowed list that can only shrink: ``problem(name, value)`` for each entry of
    ``found`` not in ``allowed``, and ``"{name}: {stale}"`` for each ``allowed`` name no longer
    found."""
    problems = [problem(name, v) for name, v in sorted(found.items()) if name not in allowed]
    return problems + [f"{name}: {stale}" for name in sorted(allowed - set(found))]


def test_no_module_is_over_500_lines():
    paths = _sources("sim2real", "bench")
    assert ROOT / "sim2real" / "eval" / "soak" / "batch.py" in paths and any(
        p.parent == ROOT / "bench" for p in paths
    )
    problems = _module_length_problems(ROOT, paths, LONG_MODULES)
    assert not problems, "\n".join(problems)


def test_the_module_length_check_names_a_new_long_module_and_a_stale_exception(tmp_path):
    (tmp_path / "long.py").write_text("x = 1\n" * (MODULE_LINES + 1))
    (tmp_path / "ok.py").write_text("x = 1\n" * MODULE_LINES)
    (tmp_path / "allowed.py").write_text("x = 1\n" * (MODULE_LINES + 1))
    (tmp_path / "split.py").write_text("x = 1\n")
    paths = sorted(tmp_path.glob("*.py"))
    problems = _module_length_problems(tmp_path, paths, {"allowed.py", "split.py", "gone.py"})
    assert [p.split(":")[0] for p in problems] == ["long.py", "gone.py", "split.py"]
    assert _module_length_problems(tmp_path, paths, {"allowed.py", "long.py"}) == []


# ====================================================================== kernel tables
#: An array of a kernel's table read by its place: an index into a table of addresses
#: (``SLOT`` arithmetic, ``put_slot``, ``view1`` .. ``view4``, a ``pointer`` to an address
#: read from a table, ``put(table, ...)``). A kernel reads a declared table by name instead
#: (:mod:`sim2real.deploy.kernels.tables`).
POSITIONAL_VIEW = re.compile(
    r"\*\s*SLOT\b|\bSLOT\s*\*|import .*\bSLOT\b|\bput_slots?\(|\bview[1-4]\(|\b_?pointer\(|\bput\(table"
)
#: The modules viewing foreign memory by address (MuJoCo's ``MjData``, per env, from an int64
#: field of a declared table): the list only shrinks.
POSITIONAL_MODULES = {
    "sim2real/deploy/backends/sim/legged_sensors_kernel.py",  # each env's MjData sensordata, qpos
    "sim2real/deploy/backends/sim/plant_kernel.py",  # each env's MjData arrays (views)
    "sim2real/deploy/rig/after_tick_kernel.py",  # each env's MjData qpos, qvel, site
    "sim2real/deploy/backends/sim/truth.py",  # each env's MjData qpos, qvel (the true base)
}


def _positional_view_problems(root: Path, paths: list[Path], allowed: set[str]) -> list[str]:
    """The modules (but ``kernels/calls.py``, which defines the addresses' helpers) that read a
    table's array by its place and are not ``allowed``, and the ``allowed`` that no longer do."""
    found = {}
    for path in paths:
        name = path.relative_to(root).as_posix()
        if name.endswith("kernels/calls.py"):
            continue
        hits = [
            i
            for i, line in enumerate(path.read_text().splitlines(), 1)
            if POSITIONAL_VIEW.search(line)
        ]
        if hits:
            found[name] = hits
    return _ratchet(
        found,
        allowed,
        lambda name, lines: (
            f"{name}:{lines[0]}: an array read by its place in a table: "
            "declare the table (sim2real.deploy.kernels.tables.Table) and read it by name"
        ),
        "reads no table by place now (or gone): remove it from POSITIONAL_MODULES",
    )


def test_no_kernel_reads_an_array_of_its_table_by_position():
    problems = _positional_view_problems(ROOT, _sources("sim2real", "bench"), POSITIONAL_MODULES)
    assert not problems, "\n".join(problems)


def test_the_positional_view_check_names_a_new_one_and_a_stale_exception(tmp_path):
    (tmp_path / "slots.py").write_text("a = view2(table, s + 4 * SLOT, f8)\n")
    (tmp_path / "address.py").write_text("q = numba.carray(_pointer(table[Q]), (envs, n), f8)\n")
    (tmp_path / "named.py").write_text("a = t.pred\nhelp = 'motor SLOT stops, heat:SLOT=W'\n")
    (tmp_path / "fixed.py").write_text("a = t.q\n")
    paths = sorted(tmp_path.glob("*.py"))
    problems = _positional_view_problems(tmp_path, paths, {"address.py", "fixed.py"})
    assert [p.split(":")[0] for p in problems] == ["slots.py", "fixed.py"]
