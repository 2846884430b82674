"""Every run in the package is put together by the one assembly, :class:`sim2real.deploy.rig.rig.Rig`:
no ``Runtime(...)`` is built outside the rig and the runtime package, and none of the parts the rig
builds (the runtime's stages, the intervention monitor, the task) is put together by hand elsewhere,
so that the count cannot creep back."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "sim2real"
RIG = PACKAGE / "deploy" / "rig"
#: where a runtime may be built: the runtime package itself (its reference subclass) and the rig
HOMES = (PACKAGE / "deploy" / "runtime", RIG)
RUNTIMES = {"Runtime", "ReferenceRuntime"}
#: what the rig (through the runtime) builds for every run
PARTS = {"SafetyGuard", "CommandSmoother", "JointStateEstimator", "InterventionMonitor", "task_for"}


def _constructions(names: set[str], skip=HOMES) -> list[str]:
    """``path:line: name(...)`` of every call of a class or function in ``names`` (by its name,
    an attribute of that name, or an alias it was imported under) in ``sim2real/``, outside the
    folders ``skip``."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if any(path.is_relative_to(home) for home in skip):
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        called = set(names)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                called |= {a.asname for a in node.names if a.name in names and a.asname}
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            func = node.func
            name = getattr(func, "id", None) or getattr(func, "attr", None)
            if name in called:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {name}(...)")
    return found


def test_no_runtime_is_built_outside_the_rig():
    built = _constructions(RUNTIMES)
    assert not built, "build the run through sim2real.deploy.rig.rig.Rig:\n" + "\n".join(built)


#: The modules that build a part outside the rig, and why. The soak's own-loop reference replays
#: a fresh guard on another loop's states (no run of ours: nothing it changes is applied). The
#: rest speed's probe runs a one-env filter of the robot's defaults on readings of a joint at
#: rest to read its steady-state covariance (a constant of the robot; no run's estimate).
BY_HAND = {
    "sim2real/eval/soak/own_loop_limits.py": {"SafetyGuard"},
    "sim2real/deploy/estimation/rest.py": {"JointStateEstimator"},
}


def test_no_part_of_a_run_is_put_together_by_hand():
    built = [
        b
        for b in _constructions(PARTS)
        if b.split("(")[0].split(": ")[-1] not in BY_HAND.get(b.split(":")[0], set())
    ]
    assert not built, (
        "take it from a Rig (rig.runtime, rig.interventions, rig.task):\n" + "\n".join(built)
    )


def test_the_scan_finds_the_rigs_own_runtime():
    """The scan sees a construction where there is one: the rig's."""
    inside = [p for p in _constructions(RUNTIMES, skip=()) if p.startswith("sim2real/deploy/rig/")]
    assert len(inside) == 1 and inside[0].endswith("Runtime(...)"), inside


def _runtime_clock_writes(folders) -> list[str]:
    """``file:line`` of every assignment to a runtime's ``ticks`` or ``time`` (an attribute of
    ``rt``, ``runtime`` or ``*.rt``/``*.runtime``) in the ``.py`` files under ``folders``,
    outside the runtime package."""
    found = []
    for folder in folders:
        for path in sorted(folder.rglob("*.py")):
            if path.is_relative_to(HOMES[0]):
                continue
            tree = ast.parse(path.read_text(), filename=str(path))
            for node in ast.walk(tree):
                targets = getattr(node, "targets", None) or [getattr(node, "target", None)]
                for target in targets:
                    elts = getattr(target, "elts", [target])
                    for t in elts:
                        if isinstance(t, ast.Attribute) and t.attr in ("ticks", "time"):
                            owner = ast.unparse(t.value).split(".")[-1]
                            if owner in ("rt", "runtime"):
                                found.append(f"{path.name}:{node.lineno}")
    return found


def test_no_loop_writes_a_runtimes_clock_from_outside():
    """A loop in place of the runtime (the policy's own loop) keeps its own clock
    (:class:`sim2real.deploy.rig.own_loop.OwnLoop`): nothing in the package or the benchmarks
    moves a runtime's ``ticks`` or ``time``."""
    written = _runtime_clock_writes((PACKAGE, ROOT / "bench"))
    assert not written, "run OwnLoop on its own clock:\n" + "\n".join(written)


def test_the_clock_scan_finds_a_write(tmp_path):
    """The scan sees a write where there is one."""
    (tmp_path / "m.py").write_text("def f(twin):\n    twin.rt.ticks += 1\n")
    assert _runtime_clock_writes((tmp_path,)) == ["m.py:2"]


def test_every_run_ticks_through_the_rigs_after_tick():
    """A run's after-tick work is its rig's (``Rig.after_tick``: the monitors, the task, then the
    hooks, the soak batch's bookkeeping among them): nothing outside the rig calls the monitors
    alone (``rig.monitor``) and adds its own work around them."""
    found = []
    for folder in (PACKAGE, ROOT / "bench"):
        for path in sorted(folder.rglob("*.py")):
            if path.is_relative_to(RIG):
                continue
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                func = getattr(node, "func", None)
                if isinstance(func, ast.Attribute) and func.attr == "monitor":
                    if ast.unparse(func.value).split(".")[-1] == "rig":
                        found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not found, "call rig.after_tick (or add a RunHook):\n" + "\n".join(found)
