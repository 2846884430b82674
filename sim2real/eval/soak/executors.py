"""How batches of soak sessions are dispatched: in this process, in local processes, or on Ray.

Every executor runs the same task, :func:`run_sessions` (one batch in one process, through
:class:`sim2real.eval.soak.batch.SessionBatch`): in the calling process (a campaign of a single batch), in a
pool of local processes (:func:`run_local`: ``concurrent.futures.ProcessPoolExecutor`` with the
``spawn`` start method, one worker per core by default, :func:`default_workers`), or as one Ray
task per batch on nodes that share no disk with the driver
(:func:`sim2real.eval.soak.ray_executor.run_ray`). While they wait, the executors update the
campaign's progress display (an object with ``update()``; :mod:`sim2real.eval.soak.campaign`).
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
from pathlib import Path

from sim2real.eval.soak.batch import BatchDiverged, SessionBatch
from sim2real.eval.soak.result import check_result, read_result
from sim2real.eval.soak.session import SessionConfig


def run_sessions(
    configs: list[SessionConfig],
    out: str,
    resume: bool = False,
    on_progress=None,
    recorders: tuple = (),
) -> list[dict]:
    """Run sessions as one batch in this process (the work of one executor task); ``recorders``:
    see :class:`sim2real.eval.soak.batch.SessionBatch`.

    Finished sessions (``result.json``) are skipped when resuming. If MuJoCo diverges in one
    session, it ends there (``diverged`` set) and the others continue from their last
    checkpoints, in a batch without it.

    Returns:
        One result per config, in order.
    """
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    results: dict[int, dict] = {}
    pending = list(configs)
    if resume:
        for c in configs:
            r = read_result(out, c.seed)
            if r is not None:
                check_result(r, c, out)
                results[c.seed] = r
        pending = [c for c in configs if c.seed not in results]
    while pending:
        try:
            batch = SessionBatch(
                pending, out, resume=resume, on_progress=on_progress, recorders=recorders
            )
            for r in batch.run():
                results[r["seed"]] = r
            pending = []
        except BatchDiverged as exc:
            for seed in exc.seeds:
                results[seed] = read_result(out, seed)
            pending = [c for c in pending if c.seed not in exc.seeds]
            resume = True
    return [results[c.seed] for c in configs]


def default_workers() -> int:
    """One worker per core available to this process."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


def run_local(
    batches: list[list[SessionConfig]], out: Path, resume: bool, workers: int, bar, recorders=()
) -> list[list[dict]]:
    """Run each batch as a :func:`run_sessions` task in a pool of ``workers`` local processes
    (at most one per batch; ``spawn``: the parent holds ONNX Runtime threads); ``bar.update()``
    is called while waiting.

    Returns:
        The results of each batch, in the order of ``batches``.
    """
    if not batches:
        return []
    ctx = multiprocessing.get_context("spawn")  # the parent holds ONNX Runtime threads: no fork
    workers = min(workers, len(batches))
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        futures = [pool.submit(run_sessions, b, str(out), resume, None, recorders) for b in batches]
        pending = set(futures)
        while pending:
            _, pending = concurrent.futures.wait(
                pending, timeout=0.5, return_when=concurrent.futures.FIRST_COMPLETED
            )
            bar.update()
        return [f.result() for f in futures]
