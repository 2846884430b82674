"""``soak-test``'s command line (:mod:`sim2real.eval.cli`): its options, grouped as the campaign, the
sessions and the checks' thresholds, and their checks before anything runs.

A bad command line is a :class:`BadInput` naming the option and the expected value (exit code 3;
argparse's own 2 means a latched fault here).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from sim2real.deploy.backends.sim.engines import add_engine_option
from sim2real.deploy.backends.sim.options import add_plant_motors_option
from sim2real.robots.errors import Sim2RealError


class BadInput(Sim2RealError, ValueError):
    """A bad command line; the message names the option."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # exit code 3, not argparse's 2 (which means a latched fault here)
        raise BadInput(message)


def parser() -> argparse.ArgumentParser:
    """``soak-test``'s argument parser; a bad command line raises :class:`BadInput` (exit 3)."""
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
    _add_campaign_options(p)
    _add_session_options(p)
    _add_threshold_options(p)
    return p


def _add_campaign_options(p: argparse.ArgumentParser) -> None:
    """What to soak, how many sessions and where they run."""
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
        "--motion",
        default=None,
        metavar="CLIP",
        help="a motion-tracking policy's clip in place of its contract's (any format "
        "deploy-run --motion plays); such a policy dances "
        "an exhibition: clip, --rest-s standing, clip again",
    )
    p.add_argument(
        "--rest-s", type=float, default=10.0, help="s standing between an exhibition's clips"
    )
    p.add_argument(
        "--own-loop-plays",
        type=int,
        default=3,
        metavar="N",
        help="plays of an exhibition's clip in the policy's own loop, whose hard-limit ticks and "
        "guard interventions the verdict judges the session's against (0: not compared)",
    )


def _add_session_options(p: argparse.ArgumentParser) -> None:
    """What each session does: checkpoints, goals, faults, ranges, the sweep, operator resets."""
    p.add_argument(
        "--checkpoint-minutes", type=float, default=5.0, help="simulated minutes (0: none)"
    )
    p.add_argument(
        "--goal-period",
        type=float,
        default=None,
        help="s between new goals, or a legged robot's velocity commands (default 4; a ranges "
        "file's commands.period sets the commands' instead)",
    )
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


def _add_threshold_options(p: argparse.ArgumentParser) -> None:
    """The checks' thresholds and the baseline's tolerances, progress and film."""
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


def check_args(args) -> None:
    """Refuse parsed options out of range, missing files and an ``--out`` that is a file.

    Raises:
        BadInput: naming the option, the expected value and the value given.
    """

    def number(name: str, minimum: float, strict: bool) -> None:
        value = getattr(args, name.lstrip("-").replace("-", "_"))
        ok = math.isfinite(value) and (value > minimum if strict else value >= minimum)
        if not ok:
            op = ">" if strict else ">="
            raise BadInput(f"{name}: expected a number {op} {minimum}, got {value}")

    number("--hours", 0, True)
    if args.goal_period is not None:
        number("--goal-period", 0, True)
    number("--success-time", 0, True)
    if args.fault_interval is not None:
        number("--fault-interval", 0, True)
    number("--curve-seconds", 0, True)
    number("--window-minutes", 0, True)
    number("--checkpoint-minutes", 0, False)
    number("--operator-reset", 0, False)
    number("--own-loop-plays", 0, False)
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
