"""The ``busy`` item: the loop on the wall clock while every core is busy with other work.

``deploy-run --realtime`` (in this process, :func:`bench.session._deploy_run`) runs go2 (its
shipped policy, exported from ``sim2real/policies/go2.pt``, commanded 0.5 m/s forward) and arm6 (the bench
policy) for ``duration`` s each, while one CPU-bound process per CPU (``while True: pass``) runs
beside it, started before and always stopped after. Reported per robot: ticks, overruns, missed
periods, their rate, the final state, go2's falls, and the report's longest control periods
(``deadline.long_ticks``, :mod:`sim2real.deploy.observe.long_ticks`) with their causes counted: what a
busy computer does to the loop, and whether it stopped it (a stall is not a fault:
:mod:`sim2real.deploy.core.modes`).
"""

from __future__ import annotations

import multiprocessing
import os
from pathlib import Path
from types import SimpleNamespace

from bench.common import BenchPolicy


def _burn() -> None:  # pragma: no cover - runs in a child process until terminated
    while True:
        pass


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

    repo = Path(__file__).resolve().parents[1]
    path = export_policy(repo / "sim2real" / "policies" / "go2.pt", out=folder / "go2.onnx")
    return SimpleNamespace(robot=SimpleNamespace(name="go2"), path=path)


def measure(arm6: BenchPolicy, folder: Path, duration: float) -> dict:
    """The ``busy`` entry of results.json: ``{duration_s, burners, rows: [...]}`` (module
    docstring).

    Raises:
        RuntimeError: deploy-run refused its input or diverged (:func:`bench.session.
            _deploy_run`).
    """
    from bench.session import _deploy_run

    go2 = shipped_go2(folder)
    burners = os.cpu_count() or 1
    procs = [multiprocessing.get_context("spawn").Process(target=_burn) for _ in range(burners)]
    rows = []
    try:
        for p in procs:
            p.start()
        report, _, _ = _deploy_run(go2, duration, True, ("--command", "0.5,0,0"))
        rows.append(_row("go2", report))
        report, _, _ = _deploy_run(arm6, duration, True)
        rows.append(_row(arm6.robot.name, report))
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.join()
    return {"duration_s": float(duration), "burners": burners, "rows": rows}
