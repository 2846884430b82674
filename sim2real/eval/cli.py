"""``soak-test``: run a soak campaign (:mod:`sim2real.eval.soak`) and write its reports
(:mod:`sim2real.eval.report.build`).

Usage::

    soak-test --robot arm3 --policy policies/arm.onnx --hours 8 --sessions 2 --seed 0 --out DIR
              [--resume] [--baseline OLD/report.json] [--executor local|ray] [--address ADDR]
              [--sessions-per-process K] [--workers N] [--checkpoint-minutes M]
              [--goal-period S] [--no-faults] [--fault-interval S] [--ranges FILE] [--min-success R]
              [--min-window-success R] [--window-minutes M] [--max-interventions F]
              [--max-falls-per-hour F] ...

It writes ``DIR/report.json``, ``DIR/report.html`` and ``DIR/junit.xml`` (atomically), the film
strip of each session's worst moments under ``DIR/film/<id>/`` (:mod:`sim2real.eval.film.strip`;
``--no-film``: none), keeps each session's checkpoints, progress and result under
``DIR/sessions/<id>/``, shows a progress bar of simulated hours and speed (simulated / wall time),
and prints a summary. A legged robot (:func:`sim2real.deploy.robot_kind.robot_kind`) follows velocity
commands instead of goals (:mod:`sim2real.eval.soak.batch`): ``--goal-period`` is their period; its
tracking success is reported, and judged only when ``--min-success`` or ``--min-window-success``
is given (how closely a policy follows every command is its training's measure; a baseline
still judges a drop).

Exit codes (``EXIT_*``; when several apply, the first of 4, 1, 5, 2, 6, 8, 9, 7): 0 passed (with
``--baseline``, a check that failed only where the baseline failed it too is a known failure, not
in the exit code), 1 hard-limit violation or hard-limit safe stop, 2 latched fault, 3 bad input
(the message names the file and the field), 4 simulation diverged, 5 over-temperature, 6 goal
success below ``--min-success`` (session) or ``--min-window-success`` (a window), 7 regression
against ``--baseline``, 8 interventions above ``--max-interventions``, 9 falls above
``--max-falls-per-hour``, 130 interrupted (Ctrl-C; ``--resume`` continues from the checkpoints).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

from sim2real.deploy.backends.sim.engines import add_engine_option
from sim2real.deploy.backends.sim.options import add_plant_motors_option
from sim2real.deploy.robot_kind import robot_kind
from sim2real.robots.errors import Sim2RealError

EXIT_PASSED = 0
EXIT_HARD_VIOLATION = 1
EXIT_LATCHED = 2
EXIT_BAD_INPUT = 3
EXIT_DIVERGED = 4
EXIT_OVER_TEMPERATURE = 5
EXIT_LOW_SUCCESS = 6
EXIT_REGRESSION = 7
EXIT_INTERVENTIONS = 8
EXIT_FALLS = 9
EXIT_INTERRUPTED = 130

#: Failure name (sim2real.eval.report.build.failures) -> exit code, in order of precedence.
_EXIT_ORDER = (
    ("no_divergence", EXIT_DIVERGED),
    ("no_hard_violation", EXIT_HARD_VIOLATION),
    ("no_over_temperature", EXIT_OVER_TEMPERATURE),
    ("no_latched_fault", EXIT_LATCHED),
    ("success_rate", EXIT_LOW_SUCCESS),
    ("window_success", EXIT_LOW_SUCCESS),
    ("interventions", EXIT_INTERVENTIONS),
    ("falls", EXIT_FALLS),
    ("regression", EXIT_REGRESSION),
)


class BadInput(Sim2RealError, ValueError):
    """A bad command line; the message names the option."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # exit code 3, not argparse's 2 (which means a latched fault here)
        raise BadInput(message)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="soak-test",
        description="Soak test: hours of the safety runtime with an ONNX policy against a "
        "randomized, faulty MuJoCo plant; reports of violations (true state), interventions, "
        "faults and motor heat.",
        epilog="Exit codes: 0 passed, 1 hard violation, 2 latched fault, 3 bad input, "
        "4 divergence, 5 over-temperature, 6 success below threshold (session or window), "
        "7 regression, 8 interventions above threshold, 9 falls above threshold (legged), "
        "130 interrupted.",
    )
    p.add_argument("--robot", default="arm3", help="shipped robot name or robot.toml path")
    p.add_argument("--policy", default="policies/arm.onnx", help="ONNX policy (policy-export)")
    p.add_argument("--spec", default=None, help="PolicySpec JSON for an ONNX without our metadata")
    p.add_argument("--hours", type=float, default=8.0, help="simulated hours per session")
    p.add_argument("--sessions", type=int, default=1, help="number of seeded sessions")
    p.add_argument("--seed", type=int, default=0, help="seed of the first session (then +1...)")
    p.add_argument("--out", type=Path, required=True, help="campaign folder")
    p.add_argument(
        "--resume", action="store_true", help="continue an interrupted campaign in --out"
    )
    p.add_argument("--baseline", type=Path, default=None, help="earlier report.json to compare")
    p.add_argument("--executor", choices=["local", "ray"], default="local")
    p.add_argument("--address", default=None, help="Ray cluster address (default: local Ray)")
    p.add_argument(
        "--sessions-per-process", type=int, default=1, help="sessions batched in one runtime"
    )
    p.add_argument("--workers", type=int, default=None, help="processes (default: one per core)")
    add_engine_option(p, "; the same sessions on a second engine: sim2sim")
    add_plant_motors_option(p)
    p.add_argument(
        "--checkpoint-minutes", type=float, default=5.0, help="simulated minutes (0: none)"
    )
    p.add_argument("--goal-period", type=float, default=4.0, help="s between new goals")
    p.add_argument(
        "--success-time", type=float, default=3.0, help="a goal counts as reached within s"
    )
    p.add_argument("--no-faults", action="store_true", help="no fault injection")
    p.add_argument(
        "--fault-interval",
        type=float,
        default=None,
        help="mean s between injected faults (default 120, or the --ranges file's "
        "faults.mean_interval)",
    )
    p.add_argument(
        "--ranges",
        type=Path,
        default=None,
        metavar="FILE",
        help="TOML file overriding the randomization ranges of the robot kind (README: soak); "
        "replaces the policy's training domain",
    )
    p.add_argument(
        "--sweep",
        action="store_true",
        help="after the campaign, the robustness sweep: widen each randomized quantity in turn "
        "until the policy fails (sim2real.eval.soak.sweep); its margins go into report.json and .html",
    )
    p.add_argument(
        "--sweep-minutes",
        type=float,
        default=5.0,
        help="simulated minutes of each session of a level of the sweep (default 5)",
    )
    p.add_argument(
        "--sweep-sessions",
        type=int,
        default=2,
        help="sessions per level of the sweep (default 2; seeds SEED..)",
    )
    p.add_argument(
        "--no-domain",
        action="store_true",
        help="the robot kind's own ranges even where the policy carries its training domain "
        "(policy-export --domain)",
    )
    p.add_argument(
        "--operator-reset",
        type=float,
        default=10.0,
        help="s before an operator clears a latched fault (0: never)",
    )
    p.add_argument(
        "--curve-seconds", type=float, default=60.0, help="simulated s per point of the curves"
    )
    p.add_argument(
        "--min-success",
        type=float,
        default=None,
        help="lowest passing success rate (session; default 0.95); a legged robot's tracking "
        "success is judged only when this or --min-window-success is given",
    )
    p.add_argument(
        "--min-window-success",
        type=float,
        default=None,
        help="lowest passing success rate in any window of --window-minutes (default 0.90)",
    )
    p.add_argument(
        "--window-minutes", type=float, default=10.0, help="simulated minutes per success window"
    )
    p.add_argument(
        "--max-interventions",
        type=float,
        default=0.01,
        help="highest passing fraction of ticks on which the guard or smoother changed a command",
    )
    p.add_argument(
        "--max-falls-per-hour",
        type=float,
        default=0.0,
        help="highest passing falls per simulated hour of a legged session",
    )
    p.add_argument(
        "--tolerance-violations",
        type=float,
        default=0.10,
        help="relative rise of violations per hour over the baseline still allowed",
    )
    p.add_argument(
        "--violation-slack",
        type=float,
        default=1.0,
        help="absolute rise of violations per hour still allowed",
    )
    p.add_argument(
        "--intervention-slack",
        type=float,
        default=0.002,
        help="absolute rise of an intervention fraction of ticks over the baseline still allowed",
    )
    p.add_argument(
        "--tolerance-success", type=float, default=0.02, help="drop of the success rate allowed"
    )
    p.add_argument(
        "--tolerance-temperature", type=float, default=2.0, help="rise of peak winding, K"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--no-film",
        action="store_true",
        help="no film strip (clips of each session's worst moments in report.html)",
    )
    return p


def _check_args(args) -> None:
    def number(name: str, minimum: float, strict: bool) -> None:
        value = getattr(args, name.lstrip("-").replace("-", "_"))
        ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
        if not ok:
            op = ">" if strict else ">="
            raise BadInput(f"{name}: expected a number {op} {minimum}, got {value}")

    number("--hours", 0, True)
    number("--goal-period", 0, True)
    number("--success-time", 0, True)
    if args.fault_interval is not None:
        number("--fault-interval", 0, True)
    number("--curve-seconds", 0, True)
    number("--window-minutes", 0, True)
    number("--checkpoint-minutes", 0, False)
    number("--operator-reset", 0, False)
    for name in (
        "--tolerance-violations",
        "--violation-slack",
        "--intervention-slack",
        "--tolerance-success",
        "--tolerance-temperature",
        "--max-falls-per-hour",
    ):
        number(name, 0, False)
    for name in ("--min-success", "--min-window-success", "--max-interventions"):
        value = getattr(args, name.lstrip("-").replace("-", "_"))
        if value is not None and not 0.0 <= value <= 1.0:
            raise BadInput(f"{name}: expected a value in [0, 1], got {value}")
    for name in ("sessions", "sessions_per_process"):
        if getattr(args, name) < 1:
            raise BadInput(f"--{name.replace('_', '-')}: expected an integer >= 1")
    if args.workers is not None and args.workers < 1:
        raise BadInput(f"--workers: expected an integer >= 1, got {args.workers}")
    if args.seed < 0:
        raise BadInput(f"--seed: expected an integer >= 0, got {args.seed}")
    if args.address and args.executor != "ray":
        raise BadInput("--address: only with --executor ray")
    if not Path(args.policy).is_file():
        raise BadInput(f"--policy: {args.policy} is not a file")
    if args.spec is not None and not Path(args.spec).is_file():
        raise BadInput(f"--spec: {args.spec} is not a file")
    out = Path(args.out)
    for folder in (out, *out.parents):
        if folder.exists() and not folder.is_dir():
            raise BadInput(
                f"--out: {folder} is a file; expected the campaign folder (new or existing)"
            )


def exit_code(report: dict) -> int:
    """The exit code of a report (see the module docstring)."""
    from sim2real.eval.report.build import failures

    failed = set(failures(report))
    for name, code in _EXIT_ORDER:
        if name in failed:
            return code
    return EXIT_PASSED


def _first_line(text: str) -> str:
    """The first line of a training domain's text without its comment mark."""
    return text.strip().splitlines()[0].lstrip("# ").strip() if text.strip() else ""


def run(args) -> int:
    from sim2real.eval.report.build import build_report, write_reports
    from sim2real.eval.report.schema import Thresholds, load_report
    from sim2real.eval.report.summary import summary_text
    from sim2real.eval.soak.campaign import run_campaign
    from sim2real.eval.soak.executors import default_workers
    from sim2real.eval.soak.session import SessionConfig
    from sim2real.eval.world.domain import DomainError, contract_commands, training_domain
    from sim2real.eval.world.ranges_file import (
        load_ranges,
        load_ranges_text,
        parse_overrides,
        read_overrides,
    )
    from sim2real.eval.world.session_ranges import session_ranges
    from sim2real.robots import load_robot
    from sim2real.robots.files import sha256_file

    _check_args(args)
    judge_tracking = args.min_success is not None or args.min_window_success is not None
    thresholds = Thresholds(
        min_success_rate=0.95 if args.min_success is None else args.min_success,
        min_window_success_rate=(
            0.90 if args.min_window_success is None else args.min_window_success
        ),
        judge_tracking=judge_tracking,
        max_intervention_rate=args.max_interventions,
        violation_tolerance=args.tolerance_violations,
        violation_slack=args.violation_slack,
        intervention_slack=args.intervention_slack,
        success_tolerance=args.tolerance_success,
        temperature_tolerance=args.tolerance_temperature,
        max_falls_per_hour=args.max_falls_per_hour,
    )
    baseline = load_report(args.baseline) if args.baseline else None
    robot = load_robot(args.robot)
    domain = None
    if args.ranges is None and not args.no_domain:
        try:
            domain = training_domain(args.policy)
        except DomainError as exc:
            raise BadInput(f"{exc}; or run --no-domain (the robot kind's ranges)") from None
    if domain is not None:
        if args.fault_interval is not None and "mean_interval" in parse_overrides(
            domain, "training domain"
        ).get("faults", {}):
            raise BadInput("--fault-interval: the policy's training domain sets it too")
        source = f"{args.policy} (training_domain)"
        ranges = load_ranges_text(domain, source, robot, args.fault_interval)
        print(f"soak-test: ranges: the policy's training domain ({_first_line(domain)})")
    elif args.ranges is None:
        ranges = session_ranges(robot, args.fault_interval)
    else:
        if args.fault_interval is not None and "mean_interval" in read_overrides(args.ranges).get(
            "faults", {}
        ):
            raise BadInput(
                f"--fault-interval: {args.ranges} sets faults.mean_interval too; give one of them"
            )
        ranges = load_ranges(args.ranges, robot, args.fault_interval)
    commands_source = None
    if robot_kind(robot).task == "locomotion" and ranges.commands is None:
        # with --spec the file's own contract need not map: only what it records is read
        commands, commands_source = contract_commands(args.policy, strict=args.spec is None)
        if commands is not None:
            ranges = dataclasses.replace(ranges, commands=commands)
            print(
                f"soak-test: commands: the policy's training ranges ({commands_source}): vx "
                f"{list(commands.vx)} m/s, vy {list(commands.vy)} m/s, yaw rate "
                f"{list(commands.yaw_rate)} rad/s, zero {commands.zero_fraction:g} of the time"
            )
    template = SessionConfig(
        robot=args.robot,
        policy=str(args.policy),
        seed=args.seed,
        hours=args.hours,
        goal_period=args.goal_period,
        success_time=args.success_time,
        checkpoint_minutes=args.checkpoint_minutes,
        curve_seconds=args.curve_seconds,
        operator_reset=args.operator_reset,
        faults=not args.no_faults,
        ranges=ranges,
        window_minutes=args.window_minutes,
        spec=None if args.spec is None else str(args.spec),
        engine=args.engine,
        plant_motors=args.plant_motors,
    )
    from sim2real.eval.film.strip import FilmRecorder

    wall = time.perf_counter()
    results = run_campaign(
        template,
        args.sessions,
        args.out,
        resume=args.resume,
        executor=args.executor,
        address=args.address,
        sessions_per_process=args.sessions_per_process,
        workers=args.workers,
        progress=not args.no_progress,
        recorders=() if args.no_film else (FilmRecorder,),
    )
    if (
        not args.no_film
    ):  # replayed from the kept checkpoints and rendered (sim2real.eval.film.render)
        from sim2real.eval.film.render import film_campaign

        results = film_campaign(template, results, args.out, workers=args.workers)
    wall = time.perf_counter() - wall
    options = template.to_dict()
    options.pop("seed")
    simulated = sum(r["simulated_s"] for r in results)
    campaign = {
        "robot": robot.name,
        "engine": args.engine,
        "policy": str(args.policy),
        "policy_sha256": sha256_file(args.policy),
        "hours": args.hours,
        "sessions": args.sessions,
        "seed": args.seed,
        "session_options": options,
        "ranges_file": None if args.ranges is None else str(args.ranges),
        "training_domain": domain,
        "commands_source": commands_source,
        "executor": args.executor,
        "address": args.address,
        "sessions_per_process": args.sessions_per_process,
        "resumed": bool(args.resume),
        "wall_s": wall,
        "simulated_per_wall": simulated / wall if wall > 0 else None,
    }
    report = build_report(
        campaign,
        results,
        thresholds,
        baseline,
        str(args.baseline) if args.baseline else None,
    )
    if args.sweep:
        from sim2real.eval.soak.sweep import margin_text, run_sweep

        sweep = run_sweep(
            template,
            Path(args.out) / "sweep",
            minutes=args.sweep_minutes,
            workers=args.workers or default_workers(),
            sessions=args.sweep_sessions,
        )
        report["robustness"] = sweep
        print(f"soak-test: robustness sweep ({sweep['wall_s']:.0f} s wall)")
        for row in sweep["quantities"]:
            print(f"  {row['label']:24} {margin_text(row)}")
    code = exit_code(report)
    report["exit_code"] = code
    paths = write_reports(args.out, report)
    print(summary_text(report))
    print(
        f"  speed        {campaign['simulated_per_wall'] or 0:.1f}x real time ({wall:.1f} s wall)"
    )
    print(f"  reports      {paths['json']}, {paths['html']}, {paths['junit']}")
    print(f"  exit code    {code}")
    return code


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``soak-test``; returns the exit code (see the module docstring)."""
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    os.environ.setdefault("MPLBACKEND", "Agg")
    try:
        args = _parser().parse_args(argv)
        return run(args)
    except KeyboardInterrupt:
        print(
            "soak-test: interrupted; the checkpoints are kept: run again with --resume",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    except (ValueError, OSError) as exc:  # RobotSpecError, PolicyLoadError, CheckpointError, ...
        print(f"soak-test: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    raise SystemExit(main())
