"""Command-line entry points: ``deploy-run`` and ``policy-export``.

``deploy-run`` exit codes:

====  =====================================================================================
0     clean: no hard violation, no latched fault
1     a hard-limit violation happened
2     a latched fault: some env ended FAULTED (or in a safe stop) after a fault of the table
3     bad input: unreadable robot, policy or spec, mismatching contract, bad option
4     the simulation diverged (MuJoCo reported a bad state)
====  =====================================================================================
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

EXIT_CLEAN, EXIT_HARD_VIOLATION, EXIT_FAULT, EXIT_BAD_INPUT, EXIT_DIVERGED = 0, 1, 2, 3, 4


def policy_export_main(argv: list[str] | None = None) -> int:
    """``policy-export``: see :func:`deploy.export.main`."""
    from deploy.export import main

    return main(argv)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="deploy-run",
        description="Run an exported ONNX policy through the safety runtime.",
        epilog="Exit codes: 0 clean, 1 hard violation, 2 latched fault, 3 bad input, "
        "4 simulation diverged.",
    )
    p.add_argument("--backend", choices=["sim"], default="sim", help="only 'sim' for now")
    p.add_argument("--robot", default="arm3", help="shipped robot name or robot.toml path")
    p.add_argument("--policy", required=True, help="ONNX policy (made by policy-export)")
    p.add_argument("--spec", default=None, help="PolicySpec JSON for an ONNX without our metadata")
    p.add_argument("--duration", type=float, default=60.0, help="seconds of (simulated) time")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--envs", type=int, default=1, help="robots simulated in lockstep")
    p.add_argument("--realtime", action="store_true", help="wall clock with absolute deadlines")
    p.add_argument("--goal-period", type=float, default=4.0, help="s between new goals")
    p.add_argument("--goal", default=None, help="fixed goal X,Y,Z (m, base frame)")
    p.add_argument(
        "--success-time",
        type=float,
        default=3.0,
        help="a goal counts as reached within this many seconds",
    )
    p.add_argument(
        "--inject",
        action="append",
        default=[],
        metavar="KIND@SECONDS[:DURATION]",
        help="fault injection (sim): dropout, stale, nan-action, latency, push",
    )
    p.add_argument("--report", type=Path, default=None, help="write the summary as JSON")
    p.add_argument("--telemetry", type=Path, default=None, help="write downsampled MCAP")
    return p


def sample_goal(robot, rng: np.random.Generator) -> np.ndarray:
    """A goal (m, base frame, (3,)) from the robot's task region."""
    task = robot.config.task
    if task.region == "planar_annulus":
        r = rng.uniform(*task.radius)
        a = rng.uniform(*task.angle)
        return np.array([r * np.cos(a), r * np.sin(a), 0.0])
    return rng.uniform(task.box_min, task.box_max)


class GoalScheduler:
    """New goals every ``period`` s (or one fixed goal); records when each was reached (sim).

    Only time in RUNNING counts: an env that is not running has its goal clock held, and gets its
    first goal when it starts running. A goal counts as reached when the end effector comes
    within ``task.success_radius`` of it at most ``success_time`` s after it was issued.

    Args:
        robot: The robot (task region, success radius).
        envs: Number of envs.
        period: s between new goals (ignored with ``fixed``).
        fixed: Optional fixed goal (3,) m, base frame, for every env.
        success_time: s.
        rng: One ``numpy.random.Generator`` for the batch (goals drawn in env order), or a
            sequence of ``envs`` generators, one goal stream per env (batched soak sessions, so
            that a session's goals do not depend on its neighbours).

    Attributes:
        t_goal: (envs,) s, when each env's goal was issued. reached: (envs,) bool.
        issued, hit_count: (envs,) int, goals issued and reached per env. hit_times: per env, the
        list of times to reach (s). goals, hits, times: the same summed over envs.
    """

    def __init__(self, robot, envs, period, fixed, success_time, rng):
        self.robot, self.period, self.fixed = robot, period, fixed
        self.streams = list(rng) if isinstance(rng, (list, tuple)) else None
        if self.streams is not None and len(self.streams) != envs:
            raise ValueError(f"rng: expected {envs} generators (one per env), got {len(rng)}")
        self.rng = rng if self.streams is None else None  # the batch's one stream
        self.success_radius = robot.config.task.success_radius
        self.success_time = success_time
        self.envs = envs
        self.t_goal = np.zeros(envs)
        self.reached = np.zeros(envs, dtype=bool)
        self.issued = np.zeros(envs, dtype=np.int64)
        self.hit_count = np.zeros(envs, dtype=np.int64)
        self.hit_times: list[list[float]] = [[] for _ in range(envs)]

    @property
    def goals(self) -> int:
        return int(self.issued.sum())

    @property
    def hits(self) -> int:
        return int(self.hit_count.sum())

    @property
    def times(self) -> list[float]:
        return [t for times in self.hit_times for t in times]

    def new_goal(self, rt, e: int) -> None:
        if self.fixed is not None:
            rt.goal[e] = self.fixed
        else:
            rt.goal[e] = sample_goal(self.robot, self.streams[e] if self.streams else self.rng)
        self.t_goal[e] = rt.time
        self.reached[e] = False
        self.issued[e] += 1

    def __call__(self, rt) -> None:
        t = rt.time
        running = rt.mode == 2
        if not running.all():  # only RUNNING time counts
            paused = ~running & ~self.reached
            self.t_goal[paused] = t
            if not running.any():
                return
        age = t - self.t_goal
        due = running & (self.issued == 0)
        if self.fixed is None:
            due |= running & (age >= self.period)
        if due.any():
            for e in np.flatnonzero(due):  # in env order (one stream for a batch)
                self.new_goal(rt, e)
        check = running & ~due & ~self.reached & (age <= self.success_time)
        if check.any():
            ee = rt.backend.end_effector_position()
            hit = check & (np.linalg.norm(ee - rt.goal, axis=1) <= self.success_radius)
            for e in np.flatnonzero(hit):
                self.reached[e] = True
                self.hit_count[e] += 1
                self.hit_times[e].append(float(age[e]))


def run(args) -> int:
    from deploy.backends.sim import SimBackend, SimulationDivergedError
    from deploy.faults import Fault, FaultInjector
    from deploy.policy import OnnxPolicy
    from deploy.runtime import STAGES, Runtime, SimClock, WallClock
    from deploy.spec import PolicySpec
    from deploy.telemetry import Telemetry
    from robots import load_robot

    robot = load_robot(args.robot)
    spec = None
    if args.spec:
        spec = PolicySpec.from_json(Path(args.spec).read_text(), source=args.spec)
    policy = OnnxPolicy(args.policy, robot, spec=spec)
    faults = [Fault.parse(s) for s in args.inject]
    fixed = None
    if args.goal:
        try:
            fixed = np.array([float(x) for x in args.goal.split(",")])
            assert fixed.shape == (3,)
        except (ValueError, AssertionError):
            raise ValueError(f"--goal {args.goal!r}: expected X,Y,Z in metres") from None
    backend = SimBackend(robot, mode=policy.spec.action.mode, envs=args.envs, seed=args.seed)
    injector = FaultInjector(faults, backend) if faults else None
    clock = WallClock(robot.control_period) if args.realtime else SimClock(robot.control_period)
    telemetry = Telemetry(args.telemetry, args.envs, robot.n_joints) if args.telemetry else None
    rt = Runtime(robot, policy, backend, clock=clock, injector=injector, telemetry=telemetry)
    goals = GoalScheduler(
        robot,
        args.envs,
        args.goal_period,
        fixed,
        args.success_time,
        np.random.default_rng(args.seed + 1),
    )
    ticks = int(round(args.duration / robot.control_period))
    peak = np.full((args.envs, robot.n_joints), -np.inf)
    max_speed = np.zeros(robot.n_joints)

    def on_tick(r):
        goals(r)
        np.maximum(peak, backend.thermal.winding_temperature, out=peak)
        np.maximum(max_speed, np.abs(backend.true_velocity()).max(axis=0), out=max_speed)

    wall = time.perf_counter()
    diverged = None
    rt.start()
    try:
        rt.run(ticks, on_tick=on_tick)
    except SimulationDivergedError as exc:
        diverged = str(exc)
    wall = time.perf_counter() - wall
    if telemetry is not None:
        telemetry.close()

    violations = rt.guard.totals()
    report = {
        "robot": robot.name,
        "policy": str(args.policy),
        "control_mode": policy.spec.action.mode,
        "control_rate_hz": 1.0 / robot.control_period,
        "duration_s": rt.time,
        "wall_s": wall,
        "realtime": bool(args.realtime),
        "envs": args.envs,
        "seed": args.seed,
        "goals": {
            "issued": goals.goals,
            "reached": goals.hits,
            "success_rate": goals.hits / goals.goals if goals.goals else None,
            "median_time_to_reach_s": float(np.median(goals.times)) if goals.times else None,
            "within_s": args.success_time,
        },
        "violations": violations,
        "faults": {
            "non_finite_actions": int(rt.counters.non_finite_actions.sum()),
            "safe_stops": int(rt.counters.safe_stops.sum()),
            "by_cause": {k: int(v.sum()) for k, v in rt.counters.faults.items()},
            "estimator": {
                "stale_readings": int(rt.estimator.stale_readings.sum()),
                "missing_readings": int(rt.estimator.missing_readings.sum()),
                "reinitializations": int(rt.estimator.reinitializations.sum()),
            },
            "injected": injector.log if injector else [],
        },
        "final_state": rt.mode_names(),
        "final_cause": rt.cause_names(),
        "peak_winding_temperature_c": dict(
            zip(robot.joint_names, peak.max(axis=0).tolist(), strict=True)
        ),
        "max_joint_speed_rad_s": dict(zip(robot.joint_names, max_speed.tolist(), strict=True)),
        "tick_cost_us": rt.tick_cost.summary(),
        "stage_cost_us": {s: rt.latency.summary(i) for i, s in enumerate(STAGES)},
        "deadline": {
            "overruns": clock.overruns,
            "missed_periods": clock.missed_periods,
            "jitter_us": clock.jitter.summary() if args.realtime else None,
        },
        "diverged": diverged,
    }
    if violations["hard_limit"] > 0:
        code = EXIT_HARD_VIOLATION
    elif any(m in ("FAULTED", "SAFE_STOP") for m in report["final_state"]):
        code = EXIT_FAULT
    else:
        code = EXIT_CLEAN
    if diverged:
        code = EXIT_DIVERGED
    report["exit_code"] = code
    print_summary(report)
    if args.report:
        tmp = args.report.with_name(args.report.name + ".part")
        tmp.write_text(json.dumps(report, indent=2))
        os.replace(tmp, args.report)
    return code


def print_summary(r: dict) -> None:
    g = r["goals"]
    rate = f"{100 * g['success_rate']:.1f} %" if g["success_rate"] is not None else "n/a"
    print(
        f"deploy-run: {r['robot']}, {r['control_mode']} control at {r['control_rate_hz']:.0f} Hz, "
        f"{r['duration_s']:.1f} s {'wall-clock' if r['realtime'] else 'simulated'} "
        f"in {r['wall_s']:.2f} s"
    )
    print(f"  goals reached     {g['reached']}/{g['issued']} within {g['within_s']:.1f} s ({rate})")
    v = ", ".join(f"{k} {n}" for k, n in r["violations"].items())
    print(f"  guard             {v}")
    f = r["faults"]
    causes = ", ".join(f"{k} {n}" for k, n in f["by_cause"].items() if n) or "none"
    print(
        f"  faults            non-finite actions {f['non_finite_actions']}, safe stops "
        f"{f['safe_stops']} ({causes}); estimator: stale {f['estimator']['stale_readings']}, "
        f"missing {f['estimator']['missing_readings']}, re-inits "
        f"{f['estimator']['reinitializations']}"
    )
    temps = ", ".join(f"{k} {t:.1f}" for k, t in r["peak_winding_temperature_c"].items())
    print(f"  peak winding degC {temps}")
    speed = max(r["max_joint_speed_rad_s"].values())
    print(f"  max joint speed   {speed:.2f} rad/s")
    t = r["tick_cost_us"]
    print(
        f"  tick cost (us)    p50 {t['p50_us']:.1f}  p99 {t['p99_us']:.1f}  "
        f"p99.9 {t['p99.9_us']:.1f}  (runtime, without physics)"
    )
    stages = "  ".join(f"{k} {s['p50_us']:.0f}" for k, s in r["stage_cost_us"].items())
    print(f"  stages p50 (us)   {stages}")
    d = r["deadline"]
    line = f"  deadlines         overruns {d['overruns']}, missed periods {d['missed_periods']}"
    if d["jitter_us"]:
        j = d["jitter_us"]
        line += f", jitter p50 {j['p50_us']:.1f} p99 {j['p99_us']:.1f} p99.9 {j['p99.9_us']:.1f} us"
    print(line)
    print(
        f"  final state       {', '.join(r['final_state'])}"
        + (f" ({', '.join(c for c in r['final_cause'] if c)})" if any(r["final_cause"]) else "")
    )
    if r["diverged"]:
        print(f"  SIMULATION DIVERGED: {r['diverged']}")
    print(f"  exit code         {r['exit_code']}")


def deploy_run_main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    args = _parser().parse_args(argv)
    try:
        return run(args)
    except (
        ValueError,
        OSError,
    ) as exc:  # RobotSpecError, SpecError, PolicyLoadError are ValueErrors
        print(f"deploy-run: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    raise SystemExit(deploy_run_main())
