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
commands instead of goals (:mod:`sim2real.eval.soak.batch`), on the schedule the report names
(:mod:`sim2real.eval.world.command_schedule`; ``--goal-period`` is refused with a ranges file's
``commands.period``); its tracking success is reported, and judged only when ``--min-success``
or ``--min-window-success`` is given (how closely a policy follows every command is its
training's measure; a baseline still judges a drop).

Exit codes: :func:`exit_code`; 3 bad input (the message names the file and the field), 130
interrupted (Ctrl-C; ``--resume`` continues from the checkpoints).
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time
from pathlib import Path

from sim2real.deploy.kinds import robot_kind
from sim2real.deploy.tasks.task import follows_velocity_commands
from sim2real.eval.cli_options import BadInput, check_args, parser
from sim2real.eval.world.world_faces import WORLD_OF_KIND

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
EXIT_LEFT_SPOT = 10
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
    ("on_spot", EXIT_LEFT_SPOT),
    ("regression", EXIT_REGRESSION),
)


def exit_code(report: dict) -> int:
    """The exit code of a report (``EXIT_*``; when several apply, the first of 4, 1, 5, 2, 6, 8,
    9, 10, 7).

    0 passed (with ``--baseline``, a check that failed only where the baseline failed it too is
    a known failure, not in the exit code), 1 hard-limit violation or hard-limit safe stop, 2
    latched fault, 4 simulation diverged, 5 over-temperature, 6 goal success below
    ``--min-success`` (session) or ``--min-window-success`` (a window), 7 regression against
    ``--baseline``, 8 interventions above ``--max-interventions``, 9 falls above
    ``--max-falls-per-hour``, 10 an exhibition's base left its spot (a clip ended, or a rest
    went, more than 0.5 m from where the clip's root path ends: check ``on_spot``). The command
    itself also exits 3 on bad input and 130 when interrupted (module docstring).
    """
    from sim2real.eval.report.build import failures

    failed = set(failures(report))
    for name, code in _EXIT_ORDER:
        if name in failed:
            return code
    return EXIT_PASSED


def _first_line(text: str) -> str:
    """The first line of a training domain's text without its comment mark."""
    return text.strip().splitlines()[0].lstrip("# ").strip() if text.strip() else ""


def _thresholds(args):
    """The checks' thresholds (:class:`sim2real.eval.report.schema.Thresholds`) of the options."""
    from sim2real.eval.report.schema import Thresholds

    judge_tracking = args.min_success is not None or args.min_window_success is not None
    return Thresholds(
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


def _ranges(args, robot) -> tuple:
    """The sessions' randomization ranges: the policy's training domain, the robot kind's or
    ``--ranges``; ``(ranges, domain text or None, {"given": the [commands] keys its file sets,
    "source": that file})``. Raises :class:`BadInput`."""
    from sim2real.eval.world.domain import DomainError, training_domain
    from sim2real.eval.world.ranges_file import (
        load_ranges,
        load_ranges_text,
        parse_overrides,
        read_overrides,
    )
    from sim2real.eval.world.session_ranges import session_ranges

    domain = None
    if args.ranges is None and not args.no_domain:
        try:
            domain = training_domain(args.policy)
        except DomainError as exc:
            raise BadInput(f"{exc}; or run --no-domain (the robot kind's ranges)") from None
    if domain is not None:
        overrides = parse_overrides(domain, "training domain")
        if args.fault_interval is not None and "mean_interval" in overrides.get("faults", {}):
            raise BadInput("--fault-interval: the policy's training domain sets it too")
        source = f"{args.policy} (training_domain)"
        ranges = load_ranges_text(domain, source, robot, args.fault_interval)
        print(f"soak-test: ranges: the policy's training domain ({_first_line(domain)})")
    elif args.ranges is None:
        overrides, source = {}, None
        ranges = session_ranges(robot, args.fault_interval)
    else:
        overrides, source = read_overrides(args.ranges), str(args.ranges)
        if args.fault_interval is not None and "mean_interval" in overrides.get("faults", {}):
            raise BadInput(
                f"--fault-interval: {args.ranges} sets faults.mean_interval too; give one of them"
            )
        ranges = load_ranges(args.ranges, robot, args.fault_interval)
    return ranges, domain, {"given": overrides.get("commands", {}), "source": source}


def _commands(args, robot, ranges, file: dict) -> tuple:
    """A legged robot's command schedule (:func:`sim2real.eval.world.command_schedule.
    command_schedule`): the ranges file's ``[commands]`` over the policy's contract over the
    defaults, printed; ``(ranges, its account or None)``. Raises :class:`BadInput`."""
    from sim2real.eval.world.command_schedule import RANGE_KEYS, command_schedule, schedule_text
    from sim2real.eval.world.domain import contract_commands

    if not follows_velocity_commands(robot):
        return ranges, None
    if _reads_clip(args, robot):  # an exhibition: the task draws no velocity command
        print("soak-test: commands: none (a motion clip commands the policy: an exhibition)")
        return ranges, None
    contract = (None, None)
    if not all(k in file["given"] for k in RANGE_KEYS):
        # with --spec the file's own contract need not map: only what it records is read
        contract = contract_commands(args.policy, strict=args.spec is None)
    try:
        commands, account = command_schedule(
            ranges.commands, file["given"], file["source"], contract, args.goal_period
        )
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    print(f"soak-test: commands: {schedule_text(account)}")
    return dataclasses.replace(ranges, commands=commands), account


def _reads_clip(args, robot) -> bool:
    """Whether the policy (with ``--spec``'s contract when given) reads a motion clip."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.policy_spec import PolicySpec
    from sim2real.deploy.tasks.motion.source import reads_motion

    spec = None
    if args.spec is not None:
        spec = PolicySpec.from_json(Path(args.spec).read_text(), source=str(args.spec))
    return reads_motion(OnnxPolicy(args.policy, robot, spec=spec).spec)


def _template(args, ranges):
    """The sessions' :class:`~sim2real.eval.soak.session.SessionConfig` (the first's seed)."""
    from sim2real.eval.soak.session import SessionConfig

    return SessionConfig(
        robot=args.robot,
        policy=str(args.policy),
        seed=args.seed,
        hours=args.hours,
        goal_period=4.0 if args.goal_period is None else args.goal_period,
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
        motion=args.motion,
        rest_s=args.rest_s,
    )


def _run_sessions(args, template) -> tuple[list[dict], float]:
    """Run the campaign's sessions, then film them (unless ``--no-film``); their results and the
    wall-clock s both took."""
    from sim2real.eval.film.strip import FilmRecorder
    from sim2real.eval.soak.campaign import run_campaign

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
    return results, time.perf_counter() - wall


def _campaign(args, robot, template, found: dict, results: list[dict], wall: float) -> dict:
    """The report's ``campaign`` entry; ``found``: ``training_domain`` and ``commands`` (the
    schedule's account, :func:`sim2real.eval.world.command_schedule.command_schedule`)."""
    from sim2real.robots.files import sha256_file

    options = template.to_dict()
    options.pop("seed")
    simulated = sum(r["simulated_s"] for r in results)
    return {
        "robot": robot.name,
        "engine": args.engine,
        "policy": str(args.policy),
        "policy_sha256": sha256_file(args.policy),
        "hours": args.hours,
        "sessions": args.sessions,
        "seed": args.seed,
        "session_options": options,
        "ranges_file": None if args.ranges is None else str(args.ranges),
        "training_domain": found["training_domain"],
        "commands": found["commands"],
        "executor": args.executor,
        "address": args.address,
        "sessions_per_process": args.sessions_per_process,
        "resumed": bool(args.resume),
        "wall_s": wall,
        "simulated_per_wall": simulated / wall if wall > 0 else None,
    }


def _own_loop(args, template, results: list[dict]) -> dict | None:
    """An exhibition's own-loop reference
    (:func:`sim2real.eval.soak.own_loop_limits.own_loop_reference`), its line printed; None for
    a campaign no clip commands."""
    if not any(r.get("exhibition") for r in results):
        return None
    from sim2real.eval.soak.own_loop_limits import own_loop_reference

    wall = time.perf_counter()
    own = own_loop_reference(template, args.own_loop_plays)
    if own["compared"]:
        joints = ", ".join(f"{j} {n}" for j, n in own["hard_limit_joints"].items())
        print(
            f"soak-test: own loop: {own['plays']} play(s) of the clip in {own['stack']}'s loop "
            f"({'pushes: ' + own['pushes'] if own['pushes'] else 'no pushes'}), "
            f"{own['clip_s']:.0f} s, {own['falls']} falls; hard-limit ticks "
            f"{own['hard_limit_ticks']} ({joints or 'none'}); the replayed guard would change "
            f"{own['guard_ticks']} of {own['ticks']} ticks ({time.perf_counter() - wall:.0f} s wall)"
        )
    else:
        print(f"soak-test: own loop: not compared: {own['why']}")
    return own


def _sweep(args, template, report: dict) -> None:
    """The robustness sweep (``--sweep``) into ``report["robustness"]``, its margins printed."""
    from sim2real.eval.soak.executors import default_workers
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


def run(args) -> int:
    """Run the campaign of the parsed options, write its reports, print its summary; the exit
    code (module docstring). Raises :class:`BadInput` (and the loaders' ValueError, OSError)."""
    from sim2real.eval.report.build import build_report, write_reports
    from sim2real.eval.report.schema import load_report
    from sim2real.eval.report.summary import summary_text
    from sim2real.robots import load_robot

    check_args(args)
    thresholds = _thresholds(args)
    baseline = load_report(args.baseline) if args.baseline else None
    robot = load_robot(args.robot)
    ranges, domain, file = _ranges(args, robot)
    pushes = WORLD_OF_KIND.get(robot_kind(robot)).domain_pushes(ranges)
    if pushes is not None:
        print(f"soak-test: pushes: {pushes.describe()}")
    if getattr(ranges, "terrain", None) is not None and not ranges.terrain.flat:
        print(f"soak-test: terrain: {ranges.terrain.describe()}")
    ranges, commands = _commands(args, robot, ranges, file)
    template = _template(args, ranges)
    results, wall = _run_sessions(args, template)
    found = {"training_domain": domain, "commands": commands}
    campaign = _campaign(args, robot, template, found, results, wall)
    report = build_report(
        campaign,
        results,
        thresholds,
        baseline,
        str(args.baseline) if args.baseline else None,
        own_loop=_own_loop(args, template, results),
    )
    if args.sweep:
        _sweep(args, template, report)
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
        args = parser().parse_args(argv)
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
