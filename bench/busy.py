"""The ``busy`` item: the loop on the wall clock while every core is busy with other work.

``deploy-run --realtime`` (in this process, :func:`bench.session._deploy_run`) runs go2 (its
shipped policy, exported from ``sim2real/policies/go2.pt``, commanded 0.5 m/s forward) and arm6 (the bench
policy) for ``duration`` s each; then the two hardware-in-the-loop runs of ``make hil``, each
against its emulator in a process of its own: go2 over DDS (``sim2real.deploy.harness.unitree_hil``,
rows ``go2 dds``) and the SO-101 over the Feetech servo bus on a pty
(``sim2real.deploy.harness.servo_hil``, row ``so101 bus``), their shipped policies, ``duration`` s of
policy each. Every run's loop is at ``--rt-priority``
:data:`~sim2real.deploy.harness.common.LOOP_PRIORITY` (SCHED_FIFO, as ``make hil`` runs it and as
a robot's computer would) when this machine permits it, and at normal priority otherwise; the
section's ``loop_priority`` says which. One CPU-bound process per CPU (``while True: pass``) runs
beside all of them, started before and always stopped after. Reported per robot: ticks, overruns, missed
periods, their rate, the final state, go2's falls, and the report's longest control periods
(``deadline.long_ticks``, :mod:`sim2real.deploy.observe.long_ticks`) with their causes counted: what a
busy computer does to the loop, and whether it stopped it (a stall is not a fault:
:mod:`sim2real.deploy.core.modes`).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

from bench.common import POLICIES, BenchPolicy

#: go2's command in every busy run: 0.5 m/s forward, as ``make hil ROBOT=go2``
WALK = ("--command", "0.5,0,0")


def _burn(parent: int) -> None:
    """One CPU-bound loop, until the process ``parent`` (its own parent's pid) is gone: a bench
    killed from outside (a test's timeout sends SIGKILL) never runs its ``finally``, and its
    burners, inherited by init, spun on for hours beside every later run."""
    while os.getppid() == parent:
        for _ in range(1_000_000):  # ~10-30 ms between the checks
            pass


def burner_processes(count: int) -> list:
    """``count`` CPU-bound processes (not started; spawned, so they hold none of this process's
    threads), each ending on its own once this process is gone (:func:`_burn`)."""
    ctx = multiprocessing.get_context("spawn")
    return [ctx.Process(target=_burn, args=(os.getpid(),)) for _ in range(count)]


def _row(name: str, report: dict) -> dict:
    from bench.session import deadline_figures

    long = report["deadline"].get("long_ticks", [])
    causes: dict[str, int] = {}
    for t in long:
        if t["overran"]:
            causes[t["cause"]] = causes.get(t["cause"], 0) + 1
    loco = report.get("locomotion") or {}
    return {
        "robot": name,
        **deadline_figures(report),
        "final_state": report["final_state"],
        "final_cause": report["final_cause"],
        "falls": loco.get("falls"),
        "longest": long[:3],
        "overrun_causes": causes,
    }


def shipped_go2(folder: Path):
    """The shipped Go2 policy exported to ``folder/go2.onnx``, as what
    :func:`bench.session._deploy_run` reads of a :class:`~bench.common.BenchPolicy` (``robot.name``,
    ``path``)."""
    from sim2real.deploy.export import export_policy

    path = export_policy(POLICIES / "go2.pt", out=folder / "go2.onnx")
    from sim2real.robots.loading import ROBOTS_DIR

    robot = SimpleNamespace(name="go2", directory=ROBOTS_DIR / "go2")
    return SimpleNamespace(robot=robot, path=path)


def _hil(name: str, harness: list[str], policy: Path, duration: float, folder: Path, extra=()):
    """The row of one hardware-in-the-loop run (``python -m sim2real.deploy.harness.<harness>
    ... -- --policy POLICY --duration DURATION``), named ``name``.

    Raises:
        RuntimeError: the run wrote no report (its emulator did not start, bad input); its
            output's last lines say why.
    """
    report = folder / f"{name.replace(' ', '_')}.json"
    report.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", f"sim2real.deploy.harness.{harness[0]}", *harness[1:], "--"]
    cmd += ["--policy", str(policy), "--duration", str(duration), "--report", str(report), *extra]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=duration + 240)
    if not report.is_file():
        tail = (done.stdout + done.stderr).strip().splitlines()[-12:]
        raise RuntimeError(f"busy: {name} wrote no report (exit {done.returncode}): {tail}")
    return _row(name, json.loads(report.read_text()))


def measure(arm6: BenchPolicy, folder: Path, duration: float) -> dict:
    """The ``busy`` entry of results.json: ``{duration_s, burners, loop_priority, rows: [...]}`` (module
    docstring).

    Raises:
        RuntimeError: deploy-run refused its input or diverged (:func:`bench.session.
            _deploy_run`).
    """
    from bench.session import _deploy_run
    from sim2real.deploy.export import export_policy
    from sim2real.deploy.harness.common import LOOP_PRIORITY, fifo_refused

    refused = fifo_refused(LOOP_PRIORITY)
    rt = () if refused else ("--rt-priority", str(LOOP_PRIORITY))
    go2 = shipped_go2(folder)
    so101 = export_policy(POLICIES / "so101.pt", out=folder / "so101.onnx")
    burners = os.cpu_count() or 1
    procs = burner_processes(burners)
    rows = []
    try:
        for p in procs:
            p.start()
        report, _, _ = _deploy_run(go2, duration, True, WALK + rt)
        rows.append(_row("go2", report))
        report, _, _ = _deploy_run(arm6, duration, True, rt)
        rows.append(_row(arm6.robot.name, report))
        unitree = ["unitree_hil", "--robot", "go2", "--domain-id", "3"]
        rows.append(_hil("go2 dds", unitree, go2.path, duration, folder, WALK))
        servo = ["servo_hil", "--robot", "so101", "--protocol", "feetech"]
        rows.append(_hil("so101 bus", servo, so101, duration, folder))
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.join()
    priority = f"SCHED_FIFO {LOOP_PRIORITY}" if refused is None else f"normal ({refused})"
    return {
        "duration_s": float(duration),
        "burners": burners,
        "loop_priority": priority,
        "rows": rows,
    }
