"""Sessions through ``deploy-run`` itself: the 8-hour-equivalent estimate and wall-clock mode.

Both call :func:`sim2real.deploy.cli.deploy_run.deploy_run_main` (the shipped code path:
robot and policy loading, ``SimBackend``, ``Runtime`` with ``GoalScheduler`` goals every 4 s and
deploy-run's own per-tick bookkeeping) with ``--report`` to a temporary file, its printed summary
captured.

**8-hour-equivalent session** (:func:`session`): a run of ``duration`` simulated seconds with
``SimClock`` (lockstep, as fast as the CPU allows), in a fresh process after a 1-s run there,
as a user's ``deploy-run`` has its process to itself (wall-clock runs stay in this one). The
report's ``wall_s`` is the run (``rig.start`` + ``rig.run``); set-up is the rest of the call
(loading the robot and the ONNX policy, building the runtime; imports excluded, they are done
once per process) plus the report's ``start_s`` (the runtime's start and the hooks' set-up,
paid once per session). The loop alone, ``loop_s = wall_s - start_s``, is extrapolated linearly:
``estimate_8h_s = setup_s + loop_s * 28800 / duration_s``.

**Wall-clock mode** (:func:`wallclock`): ``deploy-run --realtime``, a
:class:`sim2real.deploy.runtime.clock.WallClock` with the robot's control period (arm6: 1/500 s), for
``duration`` seconds of real time, once per configuration of ``WALLCLOCK_MODES``: each wait
strategy (sleep, hybrid, spin) at normal priority, hybrid and spin at SCHED_FIFO priority
``RT_PRIORITY`` with the memory locked
(``--rt-priority``; where the system refuses, the row says so in its ``notes`` and ran at normal
priority), and hybrid at that priority pinned to one CPU (``--cpu``, the last one; ``spin+fifo+cpu``
on request). Reported per configuration: deadline overruns (ticks that ended after their
deadline) and missed periods (skipped, not burst), their rate per tick, the wake-up jitter
(lateness against the deadline, the WallClock's own histogram), the runtime's tick cost in that
mode, and the settings read back during the run (scheduler, priority, CPUs, memory lock).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import io
import json
import multiprocessing
import os
import tempfile
import time
from pathlib import Path

from bench.common import LEGGED_COMMAND, BenchPolicy

EIGHT_HOURS_S = 8 * 3600.0
#: SCHED_FIFO priority of the ``+fifo`` configurations. Our choice: 50, the default thread
#: priority of ros2_control's controller manager; any priority above the normal tasks' serves
#: on a machine without other real-time work.
RT_PRIORITY = 50
#: The CPU of the ``+cpu`` configurations: the last one this process may use.
PINNED_CPU = max(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 0
_FIFO = ("--rt-priority", str(RT_PRIORITY))
#: Wall-clock configurations: name -> deploy-run options.
WALLCLOCK_MODES = {
    "sleep": ("--wait", "sleep"),
    "hybrid": ("--wait", "hybrid"),
    "spin": ("--wait", "spin"),
    "hybrid+fifo": ("--wait", "hybrid", *_FIFO),
    "spin+fifo": ("--wait", "spin", *_FIFO),
    "hybrid+fifo+cpu": ("--wait", "hybrid", *_FIFO, "--cpu", str(PINNED_CPU)),
    "spin+fifo+cpu": ("--wait", "spin", *_FIFO, "--cpu", str(PINNED_CPU)),
}
#: The configurations of a bench run without ``--wallclock-modes``.
DEFAULT_WALLCLOCK_MODES = ("sleep", "hybrid", "spin", "hybrid+fifo", "spin+fifo", "hybrid+fifo+cpu")
#: Simulated s of the short run before the measured session in its process (our choice).
SESSION_WARMUP_S = 1.0
#: Target of the wallclock item: overrun rate of arm6 at 500 Hz over 10 minutes of wall clock.
WALLCLOCK_TARGET = {"overrun_rate": 1e-4, "duration_s": 600.0}


def _deploy_run(
    bp: BenchPolicy, duration: float, realtime: bool, extra: tuple[str, ...] = ()
) -> tuple[dict, float, str]:
    """Run deploy-run on ``bp`` (``extra``: more options); returns (its report, outer wall time
    s, its printed summary).

    Raises:
        RuntimeError: deploy-run refused its input (exit 3) or the simulation diverged (exit 4).
    """
    return _deploy_run_on(_robot_argument(bp.robot), str(bp.path), duration, realtime, extra)


def _deploy_run_on(
    robot: str, policy: str, duration: float, realtime: bool, extra: tuple[str, ...] = ()
) -> tuple[dict, float, str]:
    """:func:`_deploy_run` of deploy-run's ``--robot`` and ``--policy`` arguments."""
    from sim2real.deploy.cli.deploy_run import EXIT_BAD_INPUT, deploy_run_main
    from sim2real.deploy.cli.run_verdict import EXIT_DIVERGED

    with tempfile.TemporaryDirectory() as tmp:
        report_path = Path(tmp) / "report.json"
        argv = [
            "--robot",
            robot,
            "--policy",
            policy,
            "--duration",
            repr(float(duration)),
            "--seed",
            "0",
            "--report",
            str(report_path),
        ] + (["--realtime"] if realtime else [])
        argv += list(extra)
        out, err = io.StringIO(), io.StringIO()
        t = time.perf_counter()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = deploy_run_main(argv)
        outer = time.perf_counter() - t
        if code in (EXIT_BAD_INPUT, EXIT_DIVERGED):
            raise RuntimeError(f"deploy-run {' '.join(argv)} exited {code}: {err.getvalue()}")
        report = json.loads(report_path.read_text())
    return report, outer, out.getvalue()


def _robot_argument(robot) -> str:
    """deploy-run's ``--robot`` for ``robot``: its name for a shipped robot, else its folder (an
    imported robot's)."""
    from sim2real.robots.loading import ROBOTS_DIR

    shipped = (ROBOTS_DIR / robot.name).resolve() == Path(robot.directory).resolve()
    return robot.name if shipped else str(robot.directory)


def deadline_figures(report: dict) -> dict:
    """A deploy-run report's deadline counts, the columns every row of a wall-clock run has:
    ``ticks`` (duration x control rate), ``overruns``, ``missed_periods`` and ``overrun_rate``
    (overruns per tick; NaN for no ticks)."""
    d = report["deadline"]
    ticks = int(round(float(report["duration_s"]) * report["control_rate_hz"]))
    return {
        "ticks": ticks,
        "overruns": int(d["overruns"]),
        "missed_periods": int(d["missed_periods"]),
        "overrun_rate": d["overruns"] / ticks if ticks else float("nan"),
    }


def session(bp: BenchPolicy, duration: float) -> dict:
    """The ``session.<robot>`` entry of results.json (see the module docstring), run in a
    process of its own (:func:`_session_process`)."""
    extra = () if bp.actor is not None else ("--command", LEGGED_COMMAND)  # a shipped legged policy
    args = (_robot_argument(bp.robot), str(bp.path), duration, extra)
    spawn = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(1, mp_context=spawn) as pool:
        report, outer = pool.submit(_session_process, *args).result()
    sim_s, wall_s = float(report["duration_s"]), float(report["wall_s"])
    start_s = float(report["start_s"])
    loop_s = wall_s - start_s
    setup_s = max(outer - loop_s, 0.0)
    per_sim_s = loop_s / sim_s
    return {
        "simulated_s": sim_s,
        "wall_s": wall_s,
        "start_s": start_s,
        "loop_s": loop_s,
        "setup_s": setup_s,
        "real_time_factor": sim_s / loop_s,
        "wall_per_simulated_s": per_sim_s,
        "estimate_8h_s": setup_s + per_sim_s * EIGHT_HOURS_S,
        "extrapolation": "setup_s + loop_s * 28800 / simulated_s (linear in simulated time)",
        "control_rate_hz": report["control_rate_hz"],
        "physics_rate_hz": 1.0 / bp.robot.physics_timestep,
        "tick_cost_us": report["tick_cost_us"],
        "stage_p50_us": {k: v["p50_us"] for k, v in report["stage_cost_us"].items()},
        "final_state": report["final_state"],
        "goals": report["goals"],
        "exit_code": report["exit_code"],
    }


def _session_process(
    robot: str, policy: str, duration: float, extra: tuple[str, ...]
) -> tuple[dict, float]:
    """In a fresh process, as a user's ``deploy-run`` runs: a short run first (imports, numba's
    cache, ONNX Runtime's first session; the module docstring's "done once per process"), then
    the measured one. Returns its report and outer wall time (s). In the benchmark's own
    process a session pays for the items before it (their MuJoCo data, sessions and heap;
    docs/speed.md)."""
    _deploy_run_on(robot, policy, SESSION_WARMUP_S, False, extra)
    report, outer, _ = _deploy_run_on(robot, policy, duration, False, extra)
    return report, outer


def wallclock(bp: BenchPolicy, duration: float, modes: list[str] | None = None) -> dict:
    """The ``wallclock`` entry of results.json (see the module docstring): one row per name
    of ``modes`` (default ``DEFAULT_WALLCLOCK_MODES``), run one after the other.

    Raises:
        ValueError: a name not in ``WALLCLOCK_MODES``.
    """
    modes = list(DEFAULT_WALLCLOCK_MODES) if modes is None else modes
    unknown = [m for m in modes if m not in WALLCLOCK_MODES]
    if unknown:
        raise ValueError(f"wallclock modes {unknown}: expected some of {list(WALLCLOCK_MODES)}")
    rows = []
    for name in modes:
        report, _, _ = _deploy_run(bp, duration, realtime=True, extra=WALLCLOCK_MODES[name])
        d = report["deadline"]
        rts = report["realtime_settings"]
        rows.append(
            {
                "mode": name,
                "options": list(WALLCLOCK_MODES[name]),
                "wait": d["wait"],
                "scheduler": rts["scheduler"],
                "priority": rts["priority"],
                "cpus": rts["cpus"],
                "memory_locked": rts["memory_locked"],
                "notes": rts["notes"],
                "duration_s": float(report["duration_s"]),
                "wall_s": float(report["wall_s"]),
                **deadline_figures(report),
                "jitter_us": d["jitter_us"],
                "tick_cost_us": report["tick_cost_us"],
                "final_state": report["final_state"],
                "final_cause": report["final_cause"],
                "exit_code": report["exit_code"],
            }
        )
    return {
        "robot": bp.robot.name,
        "period_s": bp.robot.control_period,
        "duration_s": float(duration),
        "target": WALLCLOCK_TARGET,
        "rows": rows,
    }
