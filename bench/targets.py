"""The bench's speed targets and their trend: each target's figure from the measured sections
(:func:`evaluate_targets`), the history entry every run keeps in results.json, the line a full
run appends to ``bench/history.jsonl``, and the comparison with the last full run
(:func:`compare_history`). The layout is in docs/speed.md."""

from __future__ import annotations

import json
import math
from pathlib import Path

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
    (
        "busy_stops",
        "runs beside a CPU-bound job per core that stopped",
        "go2+arm6+hil",
        0.0,
        "<=",
        "",
    ),
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
    (  # an imported robot: --robots ...,ROBOT_DIR --legged-policy g1=POLICY (docs/speed.md)
        "session_over_floor",
        "8-h session / (ticks x floor tick incl. mj_step)",
        "g1",
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
