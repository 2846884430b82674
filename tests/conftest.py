import functools
import gc
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
if "PYTEST_XDIST_WORKER" in os.environ:  # the workers share the cores: one thread each
    for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

gc.disable()  # while the test modules are imported: on again after (pytest_collection_finish)

import pytest  # noqa: E402

from sim2real.robots import load_robot  # noqa: E402

REPO = Path(__file__).resolve().parent.parent


def pytest_configure(config):
    """With pytest-xdist workers (``-n N``), compile the numba kernels once in the controller
    (``tests/warm_kernels.py``) before the workers start, instead of in every worker at once;
    not when ``SIM2REAL_KERNELS_WARM`` is set (``make test`` compiles them before both its runs)."""
    if "PYTEST_XDIST_WORKER" in os.environ or not getattr(config.option, "numprocesses", 0):
        return
    gc.enable()  # the xdist controller collects no test module (pytest_collection_finish)
    if os.environ.get("SIM2REAL_KERNELS_WARM"):
        return
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
    )
    subprocess.run([sys.executable, str(REPO / "tests" / "warm_kernels.py")], cwd=REPO, env=env)


@pytest.fixture(scope="session")
def stacks():
    """The other stacks' checkouts under ``$SIM2REAL_STACKS`` (:class:`tests.stacks.Stacks`); a
    test asking for it is marked ``stacks`` (:func:`pytest_itemcollected`)."""
    from tests.stacks import Stacks

    return Stacks()


@functools.cache
def _source(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def pytest_itemcollected(item):
    """The ``stacks`` mark on every test that reads another stack's files (asks for the
    ``stacks`` fixture, itself or through its fixtures), before ``-m`` selects: one marker,
    never forgotten. And a test marked ``wallclock`` or ``alone`` must be in a file whose text
    names that mark (``pytest.mark.wallclock``): ``make test`` collects those runs from the
    files it greps so (the Makefile's WALLCLOCK_FILES, ALONE_FILES), not from every module
    (collecting all of them took 16 CPU-s for 19 tests)."""
    if "stacks" in getattr(item, "fixturenames", ()):
        item.add_marker(pytest.mark.stacks)
    for mark in ("wallclock", "alone"):
        if item.get_closest_marker(mark) and f"pytest.mark.{mark}" not in _source(item.path):
            raise pytest.UsageError(
                f"{item.nodeid}: marked {mark!r}, but its file does not name "
                f"pytest.mark.{mark}: make test would not run it (Makefile, WALLCLOCK_FILES)"
            )


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
    """In a pytest-xdist worker under ``--dist loadgroup``, the ``@group`` suffix of each marked
    test's id that pytest-xdist's scheduler groups by (``xdist_group``): pytest-xdist 3.8 sets it
    on ``item._nodeid``, which pytest 9 no longer reads, so every group was spread over the
    workers (the bench's runs side by side, a module's fixtures built on both)."""
    if not getattr(config.option, "loadgroup", False):  # set in the workers of loadgroup only
        return
    try:
        from _pytest.nodeid import NodeId  # pytest 9's ids; before it, pytest-xdist's suffix held
    except ImportError:
        return
    for item in items:
        marks = item.iter_markers("xdist_group")
        group = "_".join(
            sorted({str(m.args[0] if m.args else m.kwargs.get("name", "default")) for m in marks})
        )
        if group and not item.nodeid.endswith("@" + group):
            item._id = NodeId.parse(f"{item.nodeid}@{group}")


# Opt-in CPU accounting: SIM2REAL_TEST_CPU=FILE appends, per test and phase, the tab-separated
# line "worker nodeid phase cpu_s wall_s end_time": cpu_s is the process's CPU (user + system)
# plus its waited-for children's (a subprocess.run's; not a Ray worker's nor a daemon's), which
# ranks tests on a busy machine where wall times do not; end_time (time.time()) shows a worker
# idle at the end. Each worker also writes "worker <collection> - cpu_s - end_time": its CPU
# from its start to the end of collection (the interpreter, the test modules' imports).
# tests/cpu_table.py sums the file by test and by file.
CPU_LOG = os.environ.get("SIM2REAL_TEST_CPU")


def _cpu_s() -> float:
    """This process's CPU seconds, user plus system, with its waited-for children's."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _cpu_line(*fields) -> None:
    """Append one line to :data:`CPU_LOG` (one ``write`` on an ``O_APPEND`` file: the workers'
    lines do not interleave)."""
    line = "\t".join(str(f) for f in fields) + "\n"
    fd = os.open(CPU_LOG, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line.encode())
    finally:
        os.close(fd)


def _worker() -> str:
    return os.environ.get("PYTEST_XDIST_WORKER", "main")


# The garbage collector in a test process. A worker imports every test module at collection
# (torch, MuJoCo, Pinocchio, numba, ONNX Runtime...): ~570,000 tracked objects, which one full
# collection walks in ~0.4 s. CPython ran ~25 full collections while the modules were imported
# (half a worker's collection time), and every Runtime built in a test collects every generation
# once (Runtime.__init__: its set-up's garbage), as do the emulators' loops (core/collector.py).
# So the collector is off while the modules are imported (from conftest's import, which comes
# first) and on again after, and each test runs over a frozen heap (gc.freeze: what exists
# at its start is in the permanent generation, which collections skip; unfrozen at its end, so
# nothing a test left stays uncollected; only in the xdist workers, WORKER_FREEZE): a full collection in a test walks that test's own
# objects. The runtime's run and the emulators' loops freeze the heap too and leave it frozen when
# it was at their start (sim2real/deploy/core/collector.py, heap_frozen: the freeze nests).
def pytest_collection_finish(session):
    gc.enable()
    if CPU_LOG:
        _cpu_line(_worker(), "<collection>", "-", f"{_cpu_s():.3f}", "-", f"{time.time():.3f}")


def _cpu_phase(item, phase):
    if not CPU_LOG:
        yield
        return
    cpu, wall = _cpu_s(), time.perf_counter()
    yield
    cpu, wall = _cpu_s() - cpu, time.perf_counter() - wall
    _cpu_line(_worker(), item.nodeid, phase, f"{cpu:.3f}", f"{wall:.3f}", f"{time.time():.3f}")


#: Only in the suite's pytest-xdist workers: the wall-clock runs (emulators on threads of the test
#: process, timed against a subprocess's loop) keep the collector as a user's process has it.
WORKER_FREEZE = "PYTEST_XDIST_WORKER" in os.environ
#: The process's resident memory may grow by this fraction (what tests keep, or garbage cycles a
#: fixture let go while the heap was frozen) before a test first collects the whole heap once.
HEAP_GROWTH = 0.25
_heap = {"resident": 0}


def _resident_bytes() -> int:
    """This process's resident memory (Linux: /proc/self/statm; elsewhere its peak)."""
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Each test over a frozen heap (see :func:`pytest_collection_finish`;
    ``heap_frozen``, which the runtime's run and the emulators' pause nest in). After it, its own
    garbage cycles are collected (the heap still frozen: a walk of its own objects only); a
    process grown by :data:`HEAP_GROWTH` since the last whole collection collects the whole heap
    first, so that cycles let go while frozen (a module fixture's) are not kept for the session."""
    if not WORKER_FREEZE:
        yield
        return
    from sim2real.deploy.core.collector import heap_frozen

    if _resident_bytes() > (1 + HEAP_GROWTH) * _heap["resident"]:
        gc.collect()
        _heap["resident"] = _resident_bytes()
    with heap_frozen():
        try:
            yield
        finally:
            gc.collect()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    yield from _cpu_phase(item, "setup")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    yield from _cpu_phase(item, "call")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item, nextitem):
    yield from _cpu_phase(item, "teardown")


@pytest.fixture(scope="module")
def one_torch_thread():
    """One torch thread for a module's tests: two spin-wait on a loaded 2-core machine
    (PITFALLS.md). Modules ask for it with ``pytest.mark.usefixtures``."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def go2_onnx(tmp_path_factory):
    """The shipped go2 policy (sim2real/policies/go2.pt) exported to ONNX, once per session
    (skips without torch, the extra 'export')."""
    pytest.importorskip("torch")
    from tests.runtime_fixtures import shipped_onnx

    return shipped_onnx("go2", tmp_path_factory.mktemp("go2policy"))


@pytest.fixture(scope="session")
def go2_policies(go2_onnx, tmp_path_factory):
    """The Go2's walking (:func:`go2_onnx`), standing and lying policies
    (sim2real/policies/go2_stand.pt, go2_lie.pt) exported to ONNX, once per session: {name: path}."""
    from tests.runtime_fixtures import shipped_onnx

    folder = tmp_path_factory.mktemp("operator_policies")
    out = {
        name: str(shipped_onnx(stem, folder))
        for name, stem in (("stand", "go2_stand"), ("lie", "go2_lie"))
    }
    return {"walk": str(go2_onnx), **out}


# A Robot is frozen with read-only arrays: one load per session serves every test.
def _robot_fixture(name: str):
    """A session fixture ``name``: the shipped robot of that name, loaded once."""

    @pytest.fixture(scope="session", name=name)
    def robot():
        return load_robot(name)

    return robot


arm3 = _robot_fixture("arm3")
arm6 = _robot_fixture("arm6")
go2 = _robot_fixture("go2")
so101 = _robot_fixture("so101")


@pytest.fixture(scope="session")
def go2_true_heading(tmp_path_factory):
    """The shipped go2 with its IMU's heading drift lines (``heading_rate_sigma``,
    ``heading_walk``) taken out: an IMU whose attitude has the true heading, as robot folders
    imported before robot-import wrote those lines have it."""
    import shutil

    from sim2real.robots.loading import ROBOTS_DIR

    folder = tmp_path_factory.mktemp("go2_true_heading") / "go2"
    shutil.copytree(ROBOTS_DIR / "go2", folder)
    toml = folder / "robot.toml"
    lines = toml.read_text().splitlines(keepends=True)
    kept = [x for x in lines if not x.startswith(("heading_rate_sigma", "heading_walk"))]
    assert len(kept) == len(lines) - 2, "the shipped go2's heading drift lines moved"
    toml.write_text("".join(kept))
    return load_robot(folder)


arm3_xm430 = _robot_fixture("arm3_xm430")
