"""`make bench`: measure the runtime against a bare loop; write bench/results.json and a table.

Usage::

    python -m bench [--quick] [--only ITEM[,ITEM...]] [--robots arm3,arm6] [--out FILE]
                    [--wallclock-seconds S] [--wallclock-modes sleep,hybrid,spin,...]

Items (default: all but ``profile``, in this order; see bench/__init__.py for what each
measures, docs/speed.md for the JSON layout): plant, inference, tick, session, campaign,
wallclock, busy, ros2, bus, profile.
``--quick`` shortens every item to a few seconds (a smoke test; its percentiles are rough).
With ``--only``, sections of an existing results file that were not run are kept (each section
records when it was measured and whether it was quick). The targets (``TARGETS``) are
judged on ratios of figures measured in the same run; every run appends an entry (its commit,
the targets' values) to the file's ``history``, and the table compares each target with the last
full run, flagging a move of more than ``REGRESSION`` the wrong way.
"""

from __future__ import annotations

import os

os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

import argparse  # noqa: E402
import datetime  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
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
from bench.tick import FLOORS_OF_STAGE  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results.json"
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
    "profile_ticks": 1_000,
}

#: The targets the table ends with, each judged on figures of one run (these machines
#: differ by 4x; a ratio of two figures measured side by side does not): (key, label, robot,
#: limit (None: stated, not judged), comparison, unit).
TARGETS = (
    ("tick_ratio", "full tick / bare loop, p50, physics included", "arm6", 0.8, "<=", "x"),
    ("overhead_ratio", "runtime overhead / the plant's own step, p50", "arm6", 0.5, "<=", "x"),
    ("overhead_p50", "runtime overhead per tick excl. physics, p50", "arm6", None, "", "us"),
    (
        "floor_ratio",
        "its floor (ORT + Ruckig + Pinocchio alone) / plant step",
        "arm6",
        None,
        "",
        "x",
    ),
    ("session_8h", "8-hour-equivalent session, wall time", "arm3", 300.0, "<=", "s"),
    ("session_8h", "8-hour-equivalent session, wall time", "arm6", 900.0, "<=", "s"),
    ("campaign", "campaign throughput, whole machine", "arm3", 500.0, ">=", "x"),
    ("campaign_physics", "campaign / physics-only stepping, same run", "arm3", None, "", ""),
    (
        "campaign_physics_ceiling",
        "(physics + library calls alone) / physics-only: the ceiling",
        "arm3",
        None,
        "",
        "",
    ),
    ("campaign_over_floor", "campaign / (physics + library calls alone)", "arm3", 0.8, ">=", ""),
    ("wallclock_stops", "wall-clock configurations that ended stopped", "arm6", 0.0, "<=", ""),
    ("busy_stops", "runs beside a CPU-bound job per core that stopped", "go2+arm6", 0.0, "<=", ""),
    ("ros2_overruns", "overruns with --ros2 and a slow ROS 2 peer", "go2", 0.0, "<=", ""),
    # the floor targets: our own code against the library calls it makes (bench.floors), same run
    ("tick_ours_over_floor", "(overhead - its floor) / floor, p50", "arm6", 1.0, "<=", "x"),
    ("tick_ours_over_floor", "(overhead - its floor) / floor, p50", "arm3", 1.0, "<=", "x"),
    (
        "plant_extras_over_mj_step",
        "(physics stage - mj_step) / mj_step, p50",
        "arm6",
        0.5,
        "<=",
        "x",
    ),
    (
        "session_over_floor",
        "8-h session / (ticks x floor tick incl. mj_step)",
        "arm3",
        2.0,
        "<=",
        "x",
    ),
    (
        "session_over_floor",
        "8-h session / (ticks x floor tick incl. mj_step)",
        "arm6",
        None,
        "",
        "x",
    ),
    (
        "session_over_floor",
        "8-h session / (ticks x floor tick incl. mj_step)",
        "go2",
        None,
        "",
        "x",
    ),
    ("busy_overrun_rate", "overruns beside a CPU-bound job per core", "arm6", 0.1, "<=", "%"),
)
#: The keys of the floor ratios, the ones bench/history.jsonl keeps.
FLOOR_TARGETS = (
    "tick_ours_over_floor",
    "plant_extras_over_mj_step",
    "session_over_floor",
    "campaign_physics",
    "campaign_over_floor",
    "busy_overrun_rate",
)
#: Seconds in the 8-hour session of ``session_over_floor``.
EIGHT_HOURS_S = 8 * 3600.0
#: The trend file beside the results file: one JSON line per full run (``history_line``).
HISTORY_FILE = "history.jsonl"
#: Entries of results.json's history kept (oldest dropped first).
HISTORY = 200
#: A target that moved this much the wrong way since the last full run is a regression.
REGRESSION = 0.10


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
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
        help="robots of plant, tick and session (comma list; a legged robot runs its shipped policy)",
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
    p.add_argument("--out", type=Path, default=RESULTS, help="results file (JSON)")
    args = p.parse_args(argv)
    items = [i for chunk in (args.only or [",".join(DEFAULT_ITEMS)]) for i in _csv(chunk)]
    unknown = sorted(set(items) - set(ITEMS))
    if unknown:
        p.error(f"--only: unknown item(s) {unknown}; expected some of {list(ITEMS)}")
    args.items = [i for i in ITEMS if i in items]
    args.robot_names = _csv(args.robots)
    if not args.robot_names:
        p.error("--robots: at least one robot")
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


# ---------------------------------------------------------------------- targets
def _get(d: dict, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _target_value(key: str, robot: str, sections: dict):
    """A target's figure from the measured sections (None: not measured)."""
    tick = _get(sections, "tick", "robots", robot)
    if key == "tick_ratio":
        return _get(tick, "ratio", "tick_p50")
    if key == "overhead_p50":
        return _get(tick, "full", "overhead", "p50_us")
    if key == "overhead_ratio":
        over = _get(tick, "full", "overhead", "p50_us")
        step = _get(tick, "full", "stages", "physics", "p50_us")
        return over / step if over is not None and step else None
    if key == "floor_ratio":
        floor = _get(tick, "floors", "overhead", "p50_us")
        step = _get(tick, "full", "stages", "physics", "p50_us")
        return floor / step if floor is not None and step else None
    if key == "tick_ours_over_floor":
        over = _get(tick, "full", "overhead", "p50_us")
        floor = _get(tick, "floors", "overhead", "p50_us")
        return (over - floor) / floor if over is not None and floor else None
    if key == "plant_extras_over_mj_step":
        physics = _get(tick, "full", "stages", "physics", "p50_us")
        step = _get(tick, "floors", "stages", "mj_step", "p50_us")
        return (physics - step) / step if physics is not None and step else None
    if key == "session_over_floor":
        s = _get(sections, "session", "robots", robot)
        floor = _get(tick, "floors", "overhead", "p50_us")
        step = _get(tick, "floors", "stages", "mj_step", "p50_us")
        if s is None or floor is None or step is None:
            return None
        floor_s = EIGHT_HOURS_S * s["control_rate_hz"] * (floor + step) * 1e-6
        return s["estimate_8h_s"] / floor_s if floor_s > 0 else None
    if key == "busy_overrun_rate":
        rows = {r["robot"]: r for r in _get(sections, "busy", "rows") or []}
        return 100.0 * rows[robot]["overrun_rate"] if robot in rows else None
    if key == "session_8h":
        return _get(sections, "session", "robots", robot, "estimate_8h_s")
    if key == "busy_stops":
        rows = _get(sections, "busy", "rows")
        stopped = ("FAULTED", "SAFE_STOP")
        return (
            None
            if rows is None
            else float(sum(any(m in stopped for m in r["final_state"]) for r in rows))
        )
    if key == "ros2_overruns":
        rows = {r["config"]: r for r in _get(sections, "ros2", "rows") or []}
        return float(rows["on+slow"]["overruns"]) if "on+slow" in rows else None
    if key == "wallclock_stops":
        w = sections.get("wallclock")
        if w is None or w.get("robot") != robot:
            return None
        stopped = ("FAULTED", "SAFE_STOP")
        return float(sum(any(m in stopped for m in r["final_state"]) for r in w.get("rows", [])))
    c = sections.get("campaign")
    if _get(c, "robot") != robot:
        return None
    best = _get(c, "best") or {}
    if key == "campaign_physics_ceiling":
        floor, physics = best.get("floor_only_x"), best.get("physics_only_x")
        return floor / physics if floor is not None and physics else None
    field = {"campaign_physics": "physics_fraction", "campaign_over_floor": "floor_fraction"}
    return best.get(field.get(key, "throughput_x"))


def evaluate_targets(sections: dict) -> list[dict]:
    """The PASS/FAIL rows of results.json from the measured sections (``pass`` None: the figure
    was not measured in the file, or the row is stated only, ``limit`` None)."""
    out = []
    for key, label, robot, limit, cmp, unit in TARGETS:
        value = _target_value(key, robot, sections)
        ok = None
        if limit is not None and value is not None and math.isfinite(value):
            ok = bool(value <= limit) if cmp == "<=" else bool(value >= limit)
        out.append(
            {
                "key": key,
                "label": label,
                "robot": robot,
                "value": value,
                "limit": limit,
                "comparison": cmp,
                "unit": unit,
                "pass": ok,
            }
        )
    return out


def git_commit() -> str | None:
    """The repository's commit (``-dirty`` with uncommitted changes), None without git."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("-dirty" if dirty else "")


def history_entry(results: dict) -> dict:
    """One entry of results.json's ``history``: when, which commit, quick or not, the items and
    every target's value (``key/robot``)."""
    return {
        "generated": results["generated"],
        "commit": results.get("commit"),
        "quick": results["quick"],
        "items": results["items"],
        "targets": {f"{t['key']}/{t['robot']}": t["value"] for t in results["targets"]},
    }


def history_line(results: dict, measured: dict) -> dict:
    """One line of bench/history.jsonl: the commit, the date, the machine's facts and the
    ratios of ``FLOOR_TARGETS`` (``key/robot``), each from sections ``measured`` in this run
    only (a ratio whose figures were not all measured in it is None), with its limit and
    verdict."""
    m = results["machine"]
    ratios = {}
    for t in evaluate_targets(measured):
        if t["key"] in FLOOR_TARGETS:
            ratios[f"{t['key']}/{t['robot']}"] = {
                "value": t["value"],
                "limit": t["limit"],
                "pass": t["pass"],
            }
    return {
        "generated": results["generated"],
        "commit": results.get("commit"),
        "items": results["items"],
        "machine": {
            "platform": m["platform"],
            "processor": m["processor"],
            "cpu_count": m["cpu_count"],
            "python": m["python"],
            "load_average_at_start": m["load_average_at_start"],
            "versions": m["versions"],
        },
        "ratios": ratios,
    }


def append_history(path: Path, line: dict) -> None:
    """Append ``line`` to the JSON-lines file ``path`` (NaN written as null)."""
    from bench.common import json_safe

    with path.open("a") as f:
        f.write(json.dumps(json_safe(line), sort_keys=True) + "\n")


def compare_history(results: dict) -> list[dict]:
    """Each target against the last full (not ``--quick``) run before this one in the history:
    ``{key, robot, value, previous, commit, change (fraction), regression}``; a regression moved
    more than ``REGRESSION`` the wrong way (a stated-only row: up is worse)."""
    past = [h for h in results.get("history", [])[:-1] if not h["quick"]]
    out = []
    for t in results["targets"]:
        name = f"{t['key']}/{t['robot']}"
        prev = next((h for h in reversed(past) if h["targets"].get(name) is not None), None)
        if prev is None or t["value"] is None:
            continue
        old = prev["targets"][name]
        change = (t["value"] - old) / abs(old) if old else None
        worse = t["comparison"] != ">="  # lower is better unless the goal is a floor
        regression = change is not None and (change > REGRESSION if worse else change < -REGRESSION)
        out.append(
            {
                "key": t["key"],
                "robot": t["robot"],
                "value": t["value"],
                "previous": old,
                "commit": prev["commit"],
                "change": change,
                "regression": regression,
            }
        )
    return out


# ---------------------------------------------------------------------- text report
def _f(x, spec: str = ".1f") -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:{spec}}"


def _pct(s: dict) -> str:
    return f"{_f(s['p50_us']):>8} {_f(s['p99_us']):>8} {_f(s['p99.9_us']):>9} {_f(s['mean_us']):>8}"


def _ran(sections: dict, name: str, add) -> bool:
    """Whether item ``name`` has figures to render: False when it is not in ``sections``, or
    when it was skipped (its section then one line, ``== name: skipped: why``); a section that
    is there starts with a blank line."""
    if name not in sections:
        return False
    add("")
    why = sections[name].get("skipped")
    if why:
        add(f"== {name}: skipped: {why}")
    return not why


def render(results: dict) -> str:
    """The results as a plain-text report (what ``python -m bench`` prints)."""
    lines: list[str] = []
    add = lines.append
    m = results["machine"]
    add(
        f"bench: {m['platform']}, python {m['python']}, {m['cpu_count']} CPUs, load average at "
        f"start {m['load_average_at_start']}{' [QUICK: rough figures]' if results['quick'] else ''}"
    )
    sec = results["sections"]
    pct_head = f"{'p50 us':>8} {'p99 us':>8} {'p99.9 us':>9} {'mean us':>8}"

    if _ran(sec, "plant", add):
        add(f"== plant: MuJoCo alone, per control tick ({sec['plant']['ticks']} ticks)")
        add(f"{'robot':6} {'mode':9} {'what':8} {'dec':>3} {pct_head}")
        for r in sec["plant"]["rows"]:
            add(f"{r['robot']:6} {r['mode']:9} {r['what']:8} {r['decimation']:>3} {_pct(r)}")

    if _ran(sec, "inference", add):
        r = sec["inference"]
        add(f"== inference: batch-1 policy calls ({r['policy']}; {r['calls']} calls)")
        for e in r["exports"]:
            add(f"   export ({e['name']}) {e['seconds']:.2f} s")
        add(f"   {'':36} {'median us':>10} {'p99 us':>8}")
        for row in r["rows"]:
            add(f"   {row['name']:36} {row['median_us']:10.1f} {row['p99_us']:8.1f}")

    for robot, t in sec.get("tick", {}).get("robots", {}).items():
        add("")
        add(
            f"== tick: {robot}, {t['control_rate_hz']:.0f} Hz, decimation {t['decimation']}, "
            f"{t['ticks']} ticks of each loop in {t['rounds']} alternating rounds"
        )
        full, bare = t["full"], t["bare"]
        add(f"   full runtime (rt.latency)        {pct_head}")
        for s, v in full["stages"].items():
            add(f"     {s:30} {_pct(v)}")
        add(f"     {'= overhead (rt.tick_cost)':30} {_pct(full['overhead'])}")
        add(f"     {'= tick incl. physics':30} {_pct(full['tick'])}")
        if bare["tick"]["samples"]:
            add(f"   bare loop (torch eager, PD)      {pct_head}")
            for s, v in bare["stages"].items():
                add(f"     {s:30} {_pct(v)}")
            add(f"     {'= overhead (tick - mj_step)':30} {_pct(bare['overhead'])}")
            add(f"     {'= tick incl. physics':30} {_pct(bare['tick'])}")
        else:
            add("   bare loop: none (a shipped legged policy; the bare loop has no base state)")
        fl = t.get("floors")
        if fl is not None:
            add(f"   floors: the library calls alone  {pct_head}   stage p50 - floor p50")
            last = {fs[-1]: s for s, fs in FLOORS_OF_STAGE.items()}  # glue on a stage's last
            for s, v in fl["stages"].items():
                stage = last.get(s)
                glue = f"   {stage} {fl['glue_p50_us'][stage]:+.1f} us" if stage else ""
                add(f"     {s:30} {_pct(v)}{glue}")
            add(f"     {'= overhead floor (no mj_step)':30} {_pct(fl['overhead'])}")
        r = t["ratio"]
        add(
            f"   full / bare: tick p50 {_f(r['tick_p50'], '.2f')}x, mean "
            f"{_f(r['tick_mean'], '.2f')}x; overhead p50 {_f(r['overhead_p50'], '.2f')}x, "
            f"mean {_f(r['overhead_mean'], '.2f')}x   (runtime final state "
            f"{','.join(full['final_state'])}, {full['ticks_not_running']} ticks not RUNNING)"
        )

    for robot, s in sec.get("session", {}).get("robots", {}).items():
        add("")
        add(
            f"== session: {robot} deploy-run, {s['control_rate_hz']:.0f} Hz control, "
            f"{s['physics_rate_hz']:.0f} Hz physics: {s['simulated_s']:.0f} s simulated in "
            f"{s.get('loop_s', s['wall_s']):.2f} s ({s['real_time_factor']:.0f}x real time), set-up "
            f"{s['setup_s']:.2f} s"
        )
        add(
            f"   8-hour equivalent: {s['estimate_8h_s']:.0f} s = {s['estimate_8h_s'] / 60:.1f} min "
            f"(extrapolated: {s['extrapolation']})"
        )

    if _ran(sec, "campaign", add):
        c = sec["campaign"]
        add(
            f"== campaign: {c['robot']}, {c['workers']} worker processes x k envs "
            f"(batched Runtime); {c['method']}"
        )
        add(
            f"   {'k':>3} {'sessions':>8} {'sim s/session':>13} {'wall s':>7} "
            f"{'throughput':>10} {'tick p50 us':>11} {'physics only':>12} {'fraction':>8} "
            f"{'floor only':>10} {'fraction':>8}"
        )
        for row in c["configs"]:
            add(
                f"   {row['envs_per_worker']:>3} {row['sessions']:>8} "
                f"{row['simulated_s_per_session']:>13.1f} {row['wall_s']:>7.2f} "
                f"{row['throughput_x']:>9.0f}x {row['tick_cost_p50_us']:>11.1f} "
                f"{row.get('physics_only_x', float('nan')):>11.0f}x "
                f"{row.get('physics_fraction', float('nan')):>8.2f} "
                f"{row.get('floor_only_x', float('nan')):>9.0f}x "
                f"{row.get('floor_fraction', float('nan')):>8.2f}"
            )
        b = c["best"]
        add(
            f"   best: k = {b['envs_per_worker']}, {b['throughput_x']:.0f}x real time, "
            f"{b.get('physics_fraction', float('nan')):.2f} of physics-only stepping, "
            f"{b.get('floor_fraction', float('nan')):.2f} of physics + library calls alone"
        )

    if _ran(sec, "wallclock", add):
        w = sec["wallclock"]
        target = w.get("target", {})
        add(
            f"== wallclock: {w['robot']}, WallClock period {1e3 * w['period_s']:.1f} ms, "
            f"{w['duration_s']:.0f} s per configuration (target: overruns < "
            f"{100 * target.get('overrun_rate', float('nan')):g} % over "
            f"{target.get('duration_s', float('nan')):.0f} s)"
        )
        add(
            f"   {'mode':16} {'scheduler':14} {'cpus':>5} {'mlock':>5} {'ticks':>7} "
            f"{'overruns':>8} {'rate %':>7} {'missed':>6}  {'jitter p50/p99/p99.9/max us':>29}  "
            f"{'tick p50/p99 us':>15}  final"
        )
        for r in w.get("rows", [w]):  # a results file from before the wait modes has no rows
            j = r["jitter_us"] or {}
            sched = r.get("scheduler") or "?"
            if sched == "SCHED_FIFO":
                sched += f" {r['priority']}"
            jit = "/".join(_f(j.get(k), ".0f") for k in ("p50_us", "p99_us", "p99.9_us", "max_us"))
            tc = r["tick_cost_us"]
            add(
                f"   {r.get('mode', 'hybrid'):16} {sched:14} "
                f"{','.join(map(str, r.get('cpus', []))):>5} "
                f"{'yes' if r.get('memory_locked') else 'no':>5} {r['ticks']:>7} "
                f"{r['overruns']:>8} {100 * r['overrun_rate']:>7.3f} {r['missed_periods']:>6}  "
                f"{jit:>29}  {_f(tc['p50_us'], '.0f') + '/' + _f(tc['p99_us'], '.0f'):>15}  "
                f"{','.join(r['final_state'])}"
            )
            for note in r.get("notes", []):
                add(f"     {note}")

    if _ran(sec, "busy", add):
        b = sec["busy"]
        add(
            f"== busy: deploy-run --realtime beside {b['burners']} CPU-bound processes, "
            f"{b['duration_s']:.0f} s each"
        )
        for r in b["rows"]:
            falls = "" if r["falls"] is None else f", falls {r['falls']}"
            causes = ", ".join(f"{c} {n}" for c, n in r["overrun_causes"].items()) or "none"
            longest = ", ".join(f"{t['period_us'] / 1e3:.1f} ms" for t in r["longest"])
            add(
                f"   {r['robot']:6} ticks {r['ticks']}, overruns {r['overruns']} "
                f"({100 * r['overrun_rate']:.3f} %), missed {r['missed_periods']}; final "
                f"{','.join(r['final_state'])}{falls}; longest {longest}; overruns by cause: "
                f"{causes}"
            )

    if _ran(sec, "ros2", add):
        r2 = sec["ros2"]
        add(
            f"== ros2: deploy-run --realtime on {r2['robot']}, {r2['duration_s']:.0f} s per "
            "row; us p50/p99 (tick without physics, wake-up jitter, the node's after_tick)"
        )
        for r in r2["rows"]:
            tc, jit, at = r["tick_cost_us"], r["jitter_us"], r["after_tick_us"] or {}
            sent = sum((r["published"] or {}).values())
            add(
                f"   {r['config']:8} tick {_f(tc['p50_us'], '.0f')}/{_f(tc['p99_us'], '.0f')}"
                f"  jitter {_f(jit['p50_us'], '.0f')}/{_f(jit['p99_us'], '.0f')}"
                f"  after_tick {_f(at.get('p50_us'), '.0f')}/{_f(at.get('p99_us'), '.0f')}"
                f"  overruns {r['overruns']}  published {sent}"
                f"  skipped {r['ticks_skipped'] if r['ticks_skipped'] is not None else '-'}"
                f"  final {','.join(r['final_state'])}"
            )

    if _ran(sec, "bus", add):
        b = sec["bus"]
        add(
            f"== bus: one SYNC READ + one SYNC WRITE per tick, vendor SDK against the emulator "
            f"(own process), {b['ticks']} ticks back to back"
        )
        add(f"{'robot':10} {'protocol':9} {'servos':>6} {pct_head} {'Hz':>7} {'wire us':>8}")
        for r in b["rows"]:
            add(
                f"{r['robot']:10} {r['protocol']:9} {r['servos']:>6} {_pct(r)} "
                f"{r['sustained_hz']:>7.0f} {r['wire_model_us']:>8.0f}"
            )

    for robot, pr in sec.get("profile", {}).get("robots", {}).items():
        add("")
        add(f"== profile: {robot}, cProfile over {pr['ticks']} ticks, most own time first")
        add(f"   {'own us/tick':>11} {'cum us/tick':>11} {'calls/tick':>10}  function")
        for r in pr["rows"]:
            add(
                f"   {r['own_us_per_tick']:>11.1f} {r['cumulative_us_per_tick']:>11.1f} "
                f"{r['calls_per_tick']:>10.1f}  {r['function']}"
            )

    add("")
    add("== targets (ratios of figures measured in this run)")
    add(f"   {'target':50} {'robot':6} {'measured':>10} {'goal':>10}  result")
    for t in results["targets"]:
        verdict = {True: "PASS", False: "FAIL", None: "n/a"}[t["pass"]]
        if t["limit"] is None:
            verdict = "stated"
        v = _f(t["value"], {"x": ".2f", "": ".2f", "%": ".3f"}.get(t["unit"], ".1f"))
        lim = "" if t["limit"] is None else f"{t['comparison']} {t['limit']:g}"
        add(
            f"   {t['label']:50} {t['robot']:6} {v:>7} {t['unit']:<2} {lim:>7} {t['unit']:<2} "
            f"{verdict}"
        )
    trend = compare_history(results)
    if trend:
        add("")
        add("== against the last full run (bench/results.json history)")
        for c in trend:
            change = "n/a" if c["change"] is None else f"{100 * c['change']:+.1f} %"
            flag = "  REGRESSION" if c["regression"] else ""
            add(
                f"   {c['key'] + '/' + c['robot']:28} {_f(c['value'], '.2f'):>10} was "
                f"{_f(c['previous'], '.2f'):>10} at {str(c['commit'])[:12]:12} {change}{flag}"
            )
    return "\n".join(lines)


# ---------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    cfg = args.settings
    t_start = time.perf_counter()
    stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    results = {
        "schema": SCHEMA,
        "generated": stamp,
        "quick": args.quick,
        "argv": sys.argv[1:] if argv is None else list(argv),
        "items": args.items,
        "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.items()},
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

    from sim2real.robots import load_robot

    robots: dict = {}
    policies: dict = {}

    def robot(name: str):
        if name not in robots:
            robots[name] = load_robot(name)
        return robots[name]

    with tempfile.TemporaryDirectory(prefix="bench-") as tmp:

        def policy(name: str):
            if name not in policies:
                policies[name] = make_policy(robot(name), Path(tmp))
                results["policies"][name] = policy_info(policies[name])
            return policies[name]

        sections = results["sections"]
        for item in args.items:
            t = time.perf_counter()
            print(f"[bench] {item} ...", file=sys.stderr, flush=True)
            if item == "plant":
                from bench import plant

                arms = [robot(n) for n in args.robot_names if not is_legged(robot(n))]
                sec = plant.measure(arms, cfg["plant_ticks"])  # a fixed base's qpos is its joints
            elif item == "inference":
                from bench import policy_inference

                sec = policy_inference.measure(cfg["inference_calls"])
            elif item == "tick":
                from bench import tick

                sec = {
                    "robots": {
                        n: tick.measure(policy(n), cfg["tick_ticks"], cfg["tick_rounds"])
                        for n in args.robot_names
                    }
                }
            elif item == "session":
                from bench import session

                sec = {
                    "robots": {
                        n: session.session(policy(n), cfg["session_s"]) for n in args.robot_names
                    }
                }
            elif item == "campaign":
                from bench import campaign

                bp = policy(args.campaign_robot)
                sec = campaign.measure(
                    args.campaign_robot,
                    bp.path,
                    list(cfg["campaign_envs"]),
                    cfg["campaign_s"],
                    args.workers,
                )
            elif item == "wallclock":
                from bench import session

                sec = session.wallclock(
                    policy(args.wallclock_robot), cfg["wallclock_s"], args.wallclock_modes
                )
            elif item == "busy":
                from bench import busy

                sec = busy.measure(policy("arm6"), Path(tmp), cfg["busy_s"])
            elif item == "ros2":
                from bench import ros2

                sec = ros2.measure(Path(tmp), cfg["ros2_s"])
            elif item == "bus":
                from bench import bus

                sec = bus.run(cfg["bus_ticks"])
            else:
                from bench import profiling

                sec = {
                    "robots": {
                        n: profiling.measure(policy(n), cfg["profile_ticks"])
                        for n in args.robot_names
                    }
                }
            sec["measured_at"] = datetime.datetime.now(datetime.timezone.utc).isoformat(
                timespec="seconds"
            )
            sec["quick"] = args.quick
            sec["section_wall_s"] = time.perf_counter() - t
            sections[item] = sec

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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
