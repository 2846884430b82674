"""Campaign throughput: simulated robot time per wall time, with every core busy.

``workers`` processes (default: one per CPU; started with the ``spawn`` method, with
``OMP_NUM_THREADS=OPENBLAS_NUM_THREADS=MKL_NUM_THREADS=1``) each run one batched
:class:`sim2real.deploy.runtime.Runtime` over ``SimBackend(envs=k)`` (k sessions in lockstep, one ONNX
Runtime call for all of them, ``SimClock``, ``GoalScheduler`` goals), for each k of ``envs``
in turn. Per k, every worker builds its runtime, runs it through RAMP_IN (not timed: a start-up
cost paid once per 8-hour session), waits at a barrier with the others, then runs ``duration``
simulated seconds. The campaign's wall time is from the first worker's start to the last worker's
end (``time.monotonic``, one clock for all processes on Linux)::

    throughput = workers * k * duration / wall      (simulated seconds per wall second, "x")

The best k is the one with the highest throughput.

**Physics only**, in the same run and the same pattern (every worker, each k, after a barrier):
the runtime's own plant models (``rt.backend.models`` / ``datas``, still at the state the run
left them) stepped with ``mujoco.mj_step(nstep=decimation)`` per control tick and nothing else,
for as many ticks. ``physics_fraction = throughput / physics-only throughput`` is the share of
bare MuJoCo stepping the whole toolkit keeps.

**Floor**: the library calls every tick must make besides physics cannot be batched away: Ruckig
steps all ``k * n`` DoFs, Pinocchio runs per env. After physics only, every worker times those
calls alone over its k envs (:class:`bench.floors.FloorLoop`, after a barrier, for as many ticks);
``floor_only_x = workers * k * duration / (physics-only wall + the slowest worker's library
calls)`` is the most any runtime on these libraries can reach, and ``floor_fraction =
throughput / floor_only_x`` the share of it ours keeps (the bench's target: >= 0.8).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import time
import traceback
from pathlib import Path

_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
BARRIER_TIMEOUT_S = 300.0


def _worker(index, robot_name, policy_path, envs_list, duration, barrier, results) -> None:
    """One campaign process: for each k, build, warm up, wait at the barrier, run, report."""
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    try:
        from bench.common import BenchPolicy, summary
        from bench.tick import make_runtime, warm_up
        from sim2real.robots import load_robot

        robot = load_robot(robot_name)
        bp = BenchPolicy(robot, None, None, Path(policy_path), 0.0)
        for k in envs_list:
            t = time.monotonic()
            rt, goals = make_runtime(bp, envs=k, seed=1000 * index + k)
            warm_up(rt, goals)
            setup = time.monotonic() - t
            ticks = int(round(duration / rt.dt))
            barrier.wait(BARRIER_TIMEOUT_S)
            start = time.monotonic()
            rt.run(ticks, on_tick=goals)
            end = time.monotonic()
            physics = _physics_only(rt.backend, ticks, barrier)
            calls_s = _library_calls(rt, ticks, barrier)
            results.put(
                {
                    "worker": index,
                    "envs": k,
                    "start": start,
                    "end": end,
                    "setup_s": setup,
                    "simulated_s": ticks * rt.dt,
                    "tick_cost_us": summary(rt.tick_cost),
                    "physics_p50_us": rt.latency.summary(7)["p50_us"],
                    "safe_stops": int(rt.counters.safe_stops.sum()),
                    "running": int((rt.mode == 2).sum()),
                    "physics_start": physics[0],
                    "physics_end": physics[1],
                    "library_calls_s": calls_s,
                }
            )
    except BaseException:  # noqa: BLE001 - reported to the parent, which raises
        barrier.abort()
        results.put({"worker": index, "error": traceback.format_exc()})


def _physics_only(backend, ticks: int, barrier) -> tuple[float, float]:
    """Step ``backend``'s MuJoCo models alone for ``ticks`` control ticks (after the barrier);
    returns the (start, end) monotonic times."""
    import mujoco

    step, nstep = mujoco.mj_step, backend.decimation
    pairs = list(zip(backend.models, backend.datas, strict=True))
    barrier.wait(BARRIER_TIMEOUT_S)
    start = time.monotonic()
    for _ in range(ticks):
        for m, d in pairs:
            step(m, d, nstep=nstep)
    return start, time.monotonic()


def _library_calls(rt, ticks: int, barrier) -> float:
    """The seconds ``ticks`` control ticks of ``rt``'s library calls alone take outside physics
    (:class:`bench.floors.FloorLoop` over its k envs, after the barrier): the ONNX Runtime call
    of the batch, Ruckig's step of its ``k * n`` DoFs, Pinocchio's FK and the drive model's
    dynamics per env."""
    from bench.floors import FLOOR_OUTSIDE_PHYSICS, FLOOR_STAGES, FloorLoop

    floors = FloorLoop(rt, physics=False)
    floors.run(min(ticks, 50))  # first calls: allocations
    barrier.wait(BARRIER_TIMEOUT_S)
    rec = floors.run(ticks)
    outside = [FLOOR_STAGES.index(s) for s in FLOOR_OUTSIDE_PHYSICS]
    return float(rec[:, outside].sum()) * 1e-9


def measure(
    robot_name: str, policy_path: Path, envs: list[int], duration: float, workers: int
) -> dict:
    """The ``campaign`` entry of results.json (see the module docstring).

    Raises:
        RuntimeError: a worker failed (its traceback is in the message) or timed out.
    """
    from bench.common import environment

    ctx = mp.get_context("spawn")
    barrier = ctx.Barrier(workers)
    results = ctx.Queue()
    with environment(**{v: "1" for v in _THREAD_VARS}):
        procs = [
            ctx.Process(
                target=_worker,
                args=(i, robot_name, str(policy_path), envs, duration, barrier, results),
                daemon=True,
            )
            for i in range(workers)
        ]
        t0 = time.monotonic()
        for p in procs:
            p.start()
    rows: list[dict] = []
    try:
        while len(rows) < workers * len(envs):
            try:
                r = results.get(timeout=BARRIER_TIMEOUT_S)
            except queue.Empty:
                raise RuntimeError("campaign: no result from the workers in time") from None
            if "error" in r:
                raise RuntimeError(f"campaign worker {r['worker']} failed:\n{r['error']}")
            rows.append(r)
    finally:
        for p in procs:
            p.join(timeout=10)
            if p.is_alive():
                p.terminate()
    total_wall = time.monotonic() - t0

    configs = []
    for k in envs:
        mine = [r for r in rows if r["envs"] == k]
        wall = max(r["end"] for r in mine) - min(r["start"] for r in mine)
        physics_wall = max(r["physics_end"] for r in mine) - min(r["physics_start"] for r in mine)
        simulated = sum(r["simulated_s"] * k for r in mine)
        floor_wall = physics_wall + max(r["library_calls_s"] for r in mine)
        configs.append(
            {
                "envs_per_worker": k,
                "workers": workers,
                "sessions": workers * k,
                "simulated_s_per_session": mine[0]["simulated_s"],
                "wall_s": wall,
                "throughput_x": simulated / wall,
                "physics_only_x": simulated / physics_wall,
                "physics_fraction": physics_wall / wall,
                "floor_only_x": simulated / floor_wall,
                "floor_fraction": floor_wall / wall,
                "library_calls_s": max(r["library_calls_s"] for r in mine),
                "per_worker_loop_s": [r["end"] - r["start"] for r in mine],
                "setup_s": max(r["setup_s"] for r in mine),
                "tick_cost_p50_us": max(r["tick_cost_us"]["p50_us"] for r in mine),
                "physics_p50_us": max(r["physics_p50_us"] for r in mine),
                "safe_stops": sum(r["safe_stops"] for r in mine),
                "sessions_running_at_end": sum(r["running"] for r in mine),
            }
        )
    best = max(configs, key=lambda c: c["throughput_x"])
    return {
        "robot": robot_name,
        "workers": workers,
        "configs": configs,
        "best": {
            k: best[k]
            for k in ("envs_per_worker", "workers", "throughput_x", "physics_only_x")
            + ("physics_fraction", "floor_only_x", "floor_fraction")
        },
        "section_wall_s": total_wall,
        "method": "workers * envs * simulated_s / (last end - first start); start-up, model "
        "loading and RAMP_IN excluded",
    }
