"""Soak campaigns: several seeded sessions, planned into batches and dispatched to an executor.

A **campaign** is several seeded sessions (seeds ``seed, seed + 1, ...``; :mod:`sim2real.eval.soak.session`)
in one folder ``OUT``: :func:`run_campaign` checks the robot and policy, plans the sessions into
batches of ``sessions_per_process`` (:func:`plan_batches`; a resumed campaign keeps the batches
its checkpoints were made in), runs them by local processes (one worker per core; a campaign of a
single batch runs in the calling process) or by Ray (one task per batch, on nodes that need not
see the driver's files;
:mod:`sim2real.eval.soak.ray_executor`),
shows the progress in simulated hours and speed, and returns one result per session
(:mod:`sim2real.eval.soak.result`; :mod:`sim2real.eval.report.build` turns them into the campaign's reports).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import time
from dataclasses import replace
from pathlib import Path

from sim2real.eval.soak import checkpoint as ckpt
from sim2real.eval.soak.executors import default_workers, run_local, run_sessions
from sim2real.eval.soak.exhibition import check_exhibition
from sim2real.eval.soak.ray_executor import run_ray
from sim2real.eval.soak.result import check_result, read_result
from sim2real.eval.soak.session import SESSIONS_DIR, SessionConfig, SessionError, session_dir
from sim2real.eval.soak.transport import opened_files, pack_inputs


def plan_batches(
    configs: list[SessionConfig], out: str | os.PathLike, per_process: int, resume: bool
) -> list[list[SessionConfig]]:
    """Group sessions into batches of at most ``per_process``. When resuming, sessions that were
    checkpointed together are grouped as they were (same neighbours, same tick), so that the
    resumed run equals the uninterrupted one."""
    if per_process < 1:
        raise SessionError(f"sessions_per_process: expected an integer >= 1, got {per_process}")
    batches: list[list[SessionConfig]] = []
    fresh: list[SessionConfig] = []
    if resume:
        groups: dict[tuple, list[SessionConfig]] = {}
        by_seed = {c.seed: c for c in configs}
        for c in configs:
            if read_result(out, c.seed) is not None:
                continue
            got = ckpt.read_checkpoint(session_dir(out, c.seed))
            if got is None:
                fresh.append(c)
                continue
            meta = got[1]
            key = (int(meta["tick"]), tuple(int(s) for s in meta.get("batch", [c.seed])))
            groups.setdefault(key, []).append(by_seed[c.seed])
        batches.extend(groups.values())
    else:
        fresh = list(configs)
    for i in range(0, len(fresh), per_process):
        batches.append(fresh[i : i + per_process])
    return batches


class _Progress:
    """Campaign progress in simulated hours and speed (simulated / wall), from the sessions'
    ``progress.json`` files, shown with tqdm."""

    def __init__(self, configs: list[SessionConfig], out: Path, show: bool):
        self.configs, self.out = configs, out
        self.total_h = sum(c.hours for c in configs)
        self.start = {c.seed: self._done_s(c.seed) for c in configs}
        self.t0 = time.perf_counter()
        self.bar = None
        self._last, self._shown = -1.0, 0.0
        if show:
            from tqdm import tqdm

            self.bar = tqdm(
                total=round(self.total_h, 4),
                unit="sim-h",
                desc="soak",
                bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.3f}/{total:.3f} simulated h "
                "[{elapsed}<{remaining}{postfix}]",
                dynamic_ncols=True,
            )
            self.update()

    def _done_s(self, seed: int) -> float:
        path = session_dir(self.out, seed) / "progress.json"
        try:
            return float(json.loads(path.read_text())["simulated_s"])
        except (OSError, ValueError, KeyError, json.JSONDecodeError):
            return 0.0

    def update(self) -> None:
        if self.bar is None:
            return
        done = {c.seed: self._done_s(c.seed) for c in self.configs}
        total_s = sum(done.values())
        new_s = sum(max(done[s] - self.start[s], 0.0) for s in done)
        wall = time.perf_counter() - self.t0
        if total_s == self._last and wall - self._shown < 5.0:
            return
        self._last, self._shown = total_s, wall
        self.bar.n = round(total_s / 3600.0, 4)
        self.bar.set_postfix_str(f"speed {new_s / wall:.1f}x real time" if wall > 0 else "")
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.update()
            self.bar.close()


def run_campaign(
    template: SessionConfig,
    sessions: int,
    out: str | os.PathLike,
    *,
    resume: bool = False,
    executor: str = "local",
    address: str | None = None,
    sessions_per_process: int = 1,
    workers: int | None = None,
    progress: bool = True,
    recorders: tuple = (),
) -> list[dict]:
    """Run ``sessions`` seeded sessions (seeds ``template.seed + i``) and return their results.

    Args:
        template: Options of every session; its seed is the first session's.
        sessions: Number of sessions (>= 1).
        out: Campaign folder (``sessions/<id>/`` holds checkpoints, progress and results).
        resume: Continue an interrupted campaign from its checkpoints; without it, the sessions'
            earlier state in ``out`` is discarded.
        executor: ``'local'`` (processes; a campaign of one batch runs in this process) or
            ``'ray'`` (its nodes need not see ``out`` nor the inputs: they travel with the tasks,
            :mod:`sim2real.eval.soak.ray_executor`).
        address: Ray cluster address (``ray.init(address)``); None starts a local Ray instance
            unless one is already initialized in this process.
        sessions_per_process: Sessions batched in one runtime.
        workers: Local processes (default: one per core).
        progress: Show a progress bar (simulated hours and speed).
        recorders: Recorders each batch builds (:class:`sim2real.eval.soak.batch.SessionBatch`), e.g.
            ``(sim2real.eval.film.strip.FilmRecorder,)`` for the film strip
            (:func:`sim2real.eval.film.render.film_campaign` renders it afterwards).

    Raises:
        SessionError: bad options (named).
        ValueError: unreadable robot or policy; sim2real.eval.soak.checkpoint.CheckpointError when resuming.
    """
    from sim2real.robots import load_robot

    if not isinstance(sessions, int) or sessions < 1:
        raise SessionError(f"sessions: expected an integer >= 1, got {sessions!r}")
    if executor not in ("local", "ray"):
        raise SessionError(f"executor: expected 'local' or 'ray', got {executor!r}")
    if workers is not None and workers < 1:
        raise SessionError(f"workers: expected an integer >= 1, got {workers}")
    out = Path(out)
    # bad input fails here, before any worker starts; a Ray worker gets the files opened
    with opened_files() if executor == "ray" else contextlib.nullcontext(set()) as opened:
        robot = load_robot(template.robot)
        policy = template.load_policy(robot)
    check_exhibition(policy, robot, template)  # a clip that does not fit: refused, nothing written
    configs = [replace(template, seed=template.seed + i) for i in range(sessions)]
    if not resume:
        for c in configs:
            shutil.rmtree(session_dir(out, c.seed), ignore_errors=True)
    else:
        for c in configs:  # finished sessions must have been run with these options
            r = read_result(out, c.seed)
            if r is not None:
                check_result(r, c, out)
    (out / SESSIONS_DIR).mkdir(parents=True, exist_ok=True)
    batches = plan_batches(configs, out, sessions_per_process, resume)
    bar = _Progress(configs, out, progress)
    try:
        if executor == "local" and len(batches) == 1:  # one batch: no process to spawn
            results = [run_sessions(batches[0], str(out), resume, bar.update, recorders)]
        elif executor == "local":
            results = run_local(batches, out, resume, workers or default_workers(), bar, recorders)
        else:
            inputs = pack_inputs(template, opened, policy)
            results = run_ray(batches, out, resume, address, workers, bar, recorders, inputs)
    finally:
        bar.close()
    by_seed = {r["seed"]: r for rs in results for r in rs}
    for c in configs:  # sessions finished before a resume
        if c.seed not in by_seed:
            by_seed[c.seed] = read_result(out, c.seed)
    return [by_seed[c.seed] for c in configs]
