"""`make bench`: measure the runtime against a bare loop; write bench/results.json and a table.

Usage::

    python -m bench [--quick] [--only ITEM[,ITEM...]] [--robots arm3,arm6] [--out FILE]
                    [--wallclock-seconds S] [--wallclock-modes sleep,hybrid,spin,...]
                    [--legged-policy NAME=FILE.onnx]

Items (default: all but ``profile``, in this order; see bench/__init__.py for what each
measures, docs/speed.md for the JSON layout): plant, inference, tick, session, campaign,
wallclock, busy, ros2, bus, camera, profile.
``--quick`` shortens every item to a few seconds (a smoke test; its percentiles are rough).
With ``--only``, sections of an existing results file that were not run are kept (each section
records when it was measured and whether it was quick). The targets (:data:`bench.targets.TARGETS`) are
judged on ratios of figures measured in the same run; every run appends an entry (its commit,
the targets' values) to the file's ``history``, and the table compares each target with the last
full run, flagging a move of more than ``bench.targets.REGRESSION`` the wrong way; the
table is :func:`bench.render.render`.
"""

from __future__ import annotations

import os

os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from bench.common import (  # noqa: E402
    is_legged,
    machine_info,
    make_policy,
    policy_info,
    write_json_atomic,
)
from bench.render import render  # noqa: E402
from bench.targets import (  # noqa: E402
    HISTORY,
    HISTORY_FILE,
    append_history,
    evaluate_targets,
    git_commit,
    history_entry,
    history_line,
)

#: The results file of a checkout (and of an editable install, ``pip install -e .``): beside
#: the benchmarks, with the trend file ``history.jsonl`` and the baselines.
RESULTS = Path(__file__).resolve().parent / "results.json"
#: The results file's name in the working folder, where :data:`RESULTS`'s folder is not writable
#: (a wheel's install in a system's site-packages).
RESULTS_NAME = "results.json"
SCHEMA = "sim2real-deploy/bench/1"
ITEMS = (
    "plant",
    "inference",
    "tick",
    "session",
    "campaign",
    "wallclock",
    "busy",
    "ros2",
    "bus",
    "camera",
    "profile",
)
DEFAULT_ITEMS = ITEMS[:-1]

#: Settings of a full run and of a --quick run.
FULL = {
    "plant_ticks": 20_000,
    "inference_calls": 10_000,
    "tick_ticks": 30_000,
    "tick_rounds": 5,
    "session_s": 120.0,
    "campaign_s": 15.0,
    "campaign_envs": (1, 4, 16, 32, 64, 128),
    "wallclock_s": 60.0,
    "busy_s": 30.0,
    "ros2_s": 30.0,
    "bus_ticks": 3_000,
    "camera_frames": 300,
    "profile_ticks": 5_000,
}
QUICK = {
    "plant_ticks": 500,
    "inference_calls": 500,
    "tick_ticks": 2_000,
    "tick_rounds": 2,
    "session_s": 5.0,
    "campaign_s": 1.0,
    "campaign_envs": (1, 4),
    "wallclock_s": 2.0,
    "busy_s": 2.0,
    "ros2_s": 3.0,
    "bus_ticks": 200,
    "camera_frames": 20,
    "profile_ticks": 1_000,
}


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def _parser() -> argparse.ArgumentParser:
    """The bench's options (module docstring)."""
    p = argparse.ArgumentParser(
        prog="python -m bench",
        description="Benchmark the runtime against a bare sim2sim loop; writes bench/results.json.",
    )
    p.add_argument("--quick", action="store_true", help="a few seconds per item (smoke test)")
    p.add_argument(
        "--only",
        action="append",
        default=None,
        metavar="ITEM[,ITEM]",
        help=f"run only these items (repeatable): {', '.join(ITEMS)}",
    )
    p.add_argument(
        "--robots",
        default="arm3,arm6,go2",
        help="robots of plant, tick and session (comma list of names or robot folders; a legged "
        "robot runs its shipped policy, or its --legged-policy)",
    )
    p.add_argument(
        "--legged-policy",
        action="append",
        default=[],
        metavar="NAME=FILE",
        help="the ONNX policy a legged robot of --robots runs (by its name in robot.toml) in place "
        "of a shipped sim2real/policies/NAME.pt: an imported robot's (repeatable)",
    )
    p.add_argument("--campaign-robot", default="arm3", help="robot of the campaign item")
    p.add_argument(
        "--campaign-envs",
        default=None,
        help="envs per worker to try, comma list (default 1,4,16,32,64,128)",
    )
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="campaign processes")
    p.add_argument("--wallclock-robot", default="arm6", help="robot of the wallclock item")
    p.add_argument(
        "--wallclock-seconds",
        type=float,
        default=None,
        help="wall-clock seconds of each wallclock configuration (default 60, --quick 2; "
        "the target is stated for 600)",
    )
    p.add_argument(
        "--wallclock-modes",
        default=None,
        metavar="MODE[,MODE]",
        help="wallclock configurations to run: sleep, hybrid, spin, hybrid+fifo, spin+fifo, "
        "hybrid+fifo+cpu (these by default), spin+fifo+cpu",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="results file (JSON; history.jsonl is written beside it); default: bench/results.json "
        "of the checkout, or ./results.json where the installed bench/ is not writable",
    )
    return p


def default_out(results: Path = RESULTS) -> Path:
    """The results file of a run without ``--out``: ``results`` (the checkout's
    ``bench/results.json``) where its folder is writable, else :data:`RESULTS_NAME` in the
    working folder."""
    if os.access(results.parent, os.W_OK):
        return results
    return Path.cwd() / RESULTS_NAME


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The parsed options, with ``items``, ``robot_names``, ``legged_policies`` and
    ``settings`` (FULL or QUICK with the options' overrides); a bad option exits (argparse)."""
    p = _parser()
    args = p.parse_args(argv)
    if args.out is None:
        args.out = default_out()
    items = [i for chunk in (args.only or [",".join(DEFAULT_ITEMS)]) for i in _csv(chunk)]
    unknown = sorted(set(items) - set(ITEMS))
    if unknown:
        p.error(f"--only: unknown item(s) {unknown}; expected some of {list(ITEMS)}")
    args.items = [i for i in ITEMS if i in items]
    args.robot_names = _csv(args.robots)
    if not args.robot_names:
        p.error("--robots: at least one robot")
    args.legged_policies = {}
    for item in args.legged_policy:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            p.error(f"--legged-policy {item!r}: expected NAME=FILE")
        args.legged_policies[name.strip()] = Path(path.strip())
    if args.workers < 1:
        p.error("--workers: must be >= 1")
    args.settings = dict(QUICK if args.quick else FULL)
    if args.wallclock_seconds is not None:
        if not args.wallclock_seconds > 0:
            p.error("--wallclock-seconds: must be > 0")
        args.settings["wallclock_s"] = args.wallclock_seconds
    from bench.session import WALLCLOCK_MODES

    args.wallclock_modes = _csv(args.wallclock_modes) if args.wallclock_modes else None
    if args.wallclock_modes is not None:
        bad = sorted(set(args.wallclock_modes) - set(WALLCLOCK_MODES))
        if bad or not args.wallclock_modes:
            p.error(f"--wallclock-modes: unknown {bad}; expected some of {list(WALLCLOCK_MODES)}")
    if args.campaign_envs:
        try:
            envs = tuple(int(k) for k in _csv(args.campaign_envs))
        except ValueError:
            p.error(f"--campaign-envs {args.campaign_envs!r}: expected integers")
        if not envs or min(envs) < 1:
            p.error("--campaign-envs: positive integers")
        args.settings["campaign_envs"] = envs
    return args


def _start_results(args, argv: list[str] | None) -> tuple[dict, list]:
    """The run's results document before any item, and the history of the existing results file
    (with ``--only``, its sections and policies not re-measured are kept)."""
    stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    results = {
        "schema": SCHEMA,
        "generated": stamp,
        "quick": args.quick,
        "argv": sys.argv[1:] if argv is None else list(argv),
        "items": args.items,
        "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in args.settings.items()},
        "machine": machine_info(),
        "policies": {},
        "sections": {},
    }
    old = {}
    if args.out.is_file():  # its history is kept; with --only, the sections not re-measured too
        try:
            old = json.loads(args.out.read_text())
        except (OSError, ValueError):
            old = {}
    history = list(old.get("history", [])) if isinstance(old.get("history"), list) else []
    if args.only and old.get("schema") == SCHEMA:
        results["sections"].update(old.get("sections", {}))
        results["policies"].update(old.get("policies", {}))
    return results, history


class _Fixtures:
    """The run's robots and policies, each loaded or made once (the policies in ``tmp``; each
    policy's description recorded in ``results["policies"]``)."""

    def __init__(self, args, results: dict, tmp: Path):
        self.args, self.results, self.tmp = args, results, tmp
        self.robots: dict = {}
        self.policies: dict = {}

    def robot(self, name: str):
        from sim2real.robots import load_robot

        if name not in self.robots:
            self.robots[name] = load_robot(name)
        return self.robots[name]

    def policy(self, name: str):
        if name not in self.policies:
            r = self.robot(name)
            onnx = self.args.legged_policies.get(r.name)
            self.policies[name] = make_policy(r, self.tmp, onnx=onnx)
            self.results["policies"][r.name] = policy_info(self.policies[name])
        return self.policies[name]

    def key(self, name: str) -> str:
        """A robot's key in the sections: its name (``--robots`` may give its folder)."""
        return self.robot(name).name


def _measure(item: str, args, fx: _Fixtures) -> dict:
    """One item's section (bench/__init__.py says what each measures)."""
    cfg = args.settings
    if item == "plant":
        from bench import plant

        arms = [fx.robot(n) for n in args.robot_names if not is_legged(fx.robot(n))]
        return plant.measure(arms, cfg["plant_ticks"])  # a fixed base's qpos is its joints
    if item == "inference":
        from bench import policy_inference

        return policy_inference.measure(cfg["inference_calls"])
    if item == "tick":
        from bench import tick

        return {
            "robots": {
                fx.key(n): tick.measure(fx.policy(n), cfg["tick_ticks"], cfg["tick_rounds"])
                for n in args.robot_names
            }
        }
    if item == "session":
        from bench import session

        return {
            "robots": {
                fx.key(n): session.session(fx.policy(n), cfg["session_s"]) for n in args.robot_names
            }
        }
    if item == "campaign":
        from bench import campaign

        bp = fx.policy(args.campaign_robot)
        return campaign.measure(
            args.campaign_robot,
            bp.path,
            list(cfg["campaign_envs"]),
            cfg["campaign_s"],
            args.workers,
        )
    if item == "wallclock":
        from bench import session

        return session.wallclock(
            fx.policy(args.wallclock_robot), cfg["wallclock_s"], args.wallclock_modes
        )
    if item == "busy":
        from bench import busy

        return busy.measure(fx.policy("arm6"), fx.tmp, cfg["busy_s"])
    if item == "ros2":
        from bench import ros2

        return ros2.measure(fx.tmp, cfg["ros2_s"])
    if item == "bus":
        from bench import bus

        return bus.run(cfg["bus_ticks"])
    if item == "camera":
        from bench import camera_cost

        return camera_cost.measure(fx.tmp / "camera", cfg["camera_frames"])
    from bench import profiling

    return {
        "robots": {
            fx.key(n): profiling.measure(fx.policy(n), cfg["profile_ticks"])
            for n in args.robot_names
        }
    }


def _finish(args, results: dict, history: list, t_start: float) -> None:
    """Judge the targets, write the results file and print its table; a full run appends its
    floor ratios to the history file."""
    results["targets"] = evaluate_targets(results["sections"])
    results["commit"] = git_commit()
    results["history"] = (history + [history_entry(results)])[-HISTORY:]
    results["wall_s"] = time.perf_counter() - t_start
    write_json_atomic(args.out, results)
    print(render(results))
    print(f"\nwritten {args.out} in {results['wall_s']:.0f} s")
    if not args.quick:  # a quick run's figures are rough: not part of the trend
        line = history_line(results, {i: results["sections"][i] for i in args.items})
        hist = args.out.parent / HISTORY_FILE
        append_history(hist, line)
        print(f"appended the floor ratios to {hist}")


# ---------------------------------------------------------------------- targets
def main(argv: list[str] | None = None) -> int:
    """Run the items of the options, write the results file, print its table; 0."""
    args = parse_args(argv)
    t_start = time.perf_counter()
    results, history = _start_results(args, argv)
    with tempfile.TemporaryDirectory(prefix="bench-") as tmp:
        fx = _Fixtures(args, results, Path(tmp))
        sections = results["sections"]
        for item in args.items:
            t = time.perf_counter()
            print(f"[bench] {item} ...", file=sys.stderr, flush=True)
            sec = _measure(item, args, fx)
            sec["measured_at"] = datetime.datetime.now(datetime.timezone.utc).isoformat(
                timespec="seconds"
            )
            sec["quick"] = args.quick
            sec["section_wall_s"] = time.perf_counter() - t
            sections[item] = sec
    _finish(args, results, history, t_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
