"""Campaign totals of a soak report: sums, rates and worst windows over the sessions' results.

:func:`totals` is report.json's ``totals`` section (layout: :func:`sim2real.eval.report.build.build_report`):
violations (ticks) and interventions (ticks, fraction of ticks) in total and per hour, goals,
locomotion (falls per hour, tracking success, m, m/s, degC; by terrain: :mod:`~.by_terrain`),
faults, latched faults, thermal (degC, s) and the tick cost's percentiles (us).
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.eval.report.by_terrain import terrain_rows


def _histogram_summary(bins: list[int], counts: list[int]) -> dict:
    """Percentiles (us) of a sparse 1-us-bin histogram, as LatencyHistogram.summary."""
    if not counts:
        return {"p50_us": None, "p99_us": None, "p99.9_us": None, "samples": 0}
    order = np.argsort(bins)
    b = np.asarray(bins)[order]
    c = np.cumsum(np.asarray(counts)[order])
    total = int(c[-1])

    def pct(p):
        return float(b[np.searchsorted(c, math.ceil(p / 100.0 * total))] + 0.5)

    return {"p50_us": pct(50), "p99_us": pct(99), "p99.9_us": pct(99.9), "samples": total}


def _sum_rows(results: list[dict], section: str, keys: list[str]) -> list[dict]:
    """Per-hour rows of ``section`` summed over sessions by hour index."""
    rows: dict[int, dict] = {}
    for r in results:
        for h in r[section]["per_hour"]:
            row = rows.setdefault(h["hour"], {"counts": dict.fromkeys(keys, 0), "any": 0})
            for k, v in h["counts"].items():
                row["counts"][k] = row["counts"].get(k, 0) + v
            row["any"] += h["any"]
            if "ticks" in h:
                row["ticks"] = row.get("ticks", 0) + h["ticks"]
    out = []
    for hour in sorted(rows):
        row = {"hour": hour, **rows[hour]}
        if "ticks" in row:
            row["fraction"] = row["any"] / row["ticks"] if row["ticks"] else 0.0
        out.append(row)
    return out


def _pair_ticks(results: list[dict], key: str = "self_collision_pairs") -> dict[str, int]:
    """Ticks per collision pair (or per joint beyond a hard limit: ``key`` =
    ``hard_limit_joints``) over the sessions (``violations.<key>``; absent in a report written
    before it), most first."""
    pairs: dict[str, int] = {}
    for r in results:
        for pair, n in r["violations"].get(key, {}).items():
            pairs[pair] = pairs.get(pair, 0) + n
    return dict(sorted(pairs.items(), key=lambda kv: -kv[1]))


def _interventions_down(results: list[dict]) -> dict:
    """The interventions of legged robots' ticks lying damped after a stop, over the sessions
    (``interventions.while_down``: ``ticks``, ``checks``, ``any``, ``safety``, counts and
    fractions of those ticks; absent in a report written before it: zeros)."""
    downs = [r["interventions"].get("while_down") for r in results]
    ticks = sum(d["ticks"] for d in downs if d)
    checks = list(results[0]["interventions"]["checks"]) if results else []

    def entry(get) -> dict:
        n = sum(get(d)["count"] for d in downs if d)
        return {"count": n, "fraction": n / ticks if ticks else 0.0}

    return {
        "ticks": ticks,
        "checks": {k: entry(lambda d, k=k: d["checks"][k]) for k in checks},
        "any": entry(lambda d: d["any"]),
        "safety": entry(lambda d: d["safety"]),
    }


def _while_down(results: list[dict]) -> dict[str, int]:
    """Violation ticks per type (and ``any``) of legged robots lying damped after a stop, over
    the sessions (``violations.while_down``; absent in a report written before it: zeros)."""
    out: dict[str, int] = {}
    for r in results:
        for k, n in r["violations"].get("while_down", {}).items():
            out[k] = out.get(k, 0) + n
    return out


def totals(results: list[dict]) -> dict:
    """Campaign totals over session results (the ``totals`` of
    :func:`sim2real.eval.report.build.build_report`'s layout)."""
    hours = sum(r["simulated_hours"] for r in results)
    types = list(results[0]["violations"]["total"]) if results else []
    total = {k: sum(r["violations"]["total"][k] for r in results) for k in types}
    joints = results[0]["thermal"]["joints"] if results else []
    bins: dict[int, int] = {}
    for r in results:
        hist = r["wall"]["tick_cost_histogram"]
        for b, c in zip(hist["bin_us"], hist["count"], strict=True):
            bins[b] = bins.get(b, 0) + c
    latched = sum(r["runtime"]["latched_faults"] for r in results)
    return {
        "sessions": len(results),
        "simulated_hours": hours,
        "ticks": sum(r["interventions"]["ticks"] for r in results),
        "violations": {
            "source": results[0]["violations"]["source"] if results else None,
            "total": total,
            "any": sum(r["violations"]["any"] for r in results),
            "rate_per_hour": {k: (v / hours if hours > 0 else 0.0) for k, v in total.items()},
            "per_hour": _sum_rows(results, "violations", types),
            "self_collision_pairs": _pair_ticks(results),
            "hard_limit_joints": _pair_ticks(results, "hard_limit_joints"),
            "while_down": _while_down(results),
        },
        "interventions": _intervention_totals(results),
        "goals": _goal_totals(results),
        "locomotion": _locomotion_totals(results),
        "by_terrain": terrain_rows(results),
        "base_estimate": _base_estimate_totals(results),
        "faults": _fault_totals(results),
        "latched_faults": latched,
        # of them, a stop an injected fault was to cause (a camera's): not failed
        "latched_injected": sum(
            1 for r in results for x in r["runtime"]["latches"] if x.get("injected")
        ),
        "latched_faults_per_hour": latched / hours if hours > 0 else 0.0,
        "operator_resets": sum(r["runtime"]["operator_resets"] for r in results),
        "wheels": _wheel_totals(results),
        "thermal": {
            "peak_c": {j: max(r["thermal"]["peak_c"][j] for r in results) for j in joints},
            "derating_band_s": {
                j: sum(r["thermal"]["derating_band_s"][j] for r in results) for j in joints
            },
            "over_temperature_s": {
                j: sum(r["thermal"]["over_temperature_s"][j] for r in results) for j in joints
            },
        },
        "diverged": [r["id"] for r in results if r["diverged"]],
        "tick_cost_us": _histogram_summary(list(bins), list(bins.values())),
    }


def _intervention_totals(results: list[dict]) -> dict:
    """The sessions' interventions summed: ``{ticks, checks, any, safety, by_design, warnings,
    per_hour, while_down}``, each count with its fraction of the ticks up."""
    ticks = sum(r["interventions"]["ticks"] for r in results)
    checks = list(results[0]["interventions"]["checks"]) if results else []
    warnings = list(results[0]["interventions"]["warnings"]) if results else []

    def entry(count: int) -> dict:
        return {"count": count, "fraction": count / ticks if ticks else 0.0}

    return {
        "ticks": ticks,
        "checks": {
            k: entry(sum(r["interventions"]["checks"][k]["count"] for r in results)) for k in checks
        },
        "any": entry(sum(r["interventions"]["any"]["count"] for r in results)),
        "safety": entry(
            sum(
                r["interventions"].get("safety", r["interventions"]["any"])["count"]
                for r in results
            )
        ),
        "by_design": results[0]["interventions"].get("by_design", []) if results else [],
        "warnings": {
            k: entry(sum(r["interventions"]["warnings"][k]["count"] for r in results))
            for k in warnings
        },
        "per_hour": _sum_rows(results, "interventions", checks),
        "while_down": _interventions_down(results),
    }


def _goal_totals(results: list[dict]) -> dict:
    """The arm sessions' goals summed: issued, reached, success rate, the lowest window's."""
    arms = [r for r in results if r["goals"] is not None]
    issued = sum(r["goals"]["issued"] for r in arms)
    reached = sum(r["goals"]["reached"] for r in arms)
    windows = [
        r["goals"]["min_window_success_rate"]
        for r in arms
        if r["goals"]["min_window_success_rate"] is not None
    ]
    return {
        "issued": issued,
        "reached": reached,
        "success_rate": reached / issued if issued else None,
        "min_window_success_rate": min(windows) if windows else None,
        "missed": sum(len(r["goals"]["missed"]) for r in arms),
        "missed_dropped": sum(r["goals"]["missed_dropped"] for r in arms),
    }


def _fault_totals(results: list[dict]) -> dict:
    """The sessions' faults summed, with each response's count and each kind's."""
    responses: dict[str, int] = {}
    by_kind: dict[str, dict] = {}
    for r in results:
        for k, v in r["faults"]["responses"].items():
            responses[k] = responses.get(k, 0) + v
        for ev in r["faults"]["events"]:
            kind = by_kind.setdefault(ev["kind"], {"injected": 0, "survived": 0, "responses": {}})
            kind["injected"] += 1
            kind["survived"] += int(ev["survived"])
            kind["responses"][ev["response"]] = kind["responses"].get(ev["response"], 0) + 1
    return {
        "injected": sum(r["faults"]["injected"] for r in results),
        "skipped_pushes": sum(len(r["faults"].get("skipped_pushes", [])) for r in results),
        "survived": sum(r["faults"]["survived"] for r in results),
        "responses": responses,
        "by_kind": by_kind,
    }


def _base_estimate_totals(results: list[dict]) -> dict | None:
    """The sessions' base estimate against the truth (``base_estimate``), RUNNING-tick weighted:
    the attitude error's mean, the planar RMS, the vertical bias and RMS; the worst session's
    attitude p95. None without a legged session that ran."""
    rows = [r["base_estimate"] for r in results if r.get("base_estimate")]
    if not rows:
        return None
    n = sum(x["ticks"] for x in rows)

    def mean(f) -> float:
        return sum(f(x) * x["ticks"] for x in rows) / n

    return {
        "ticks": n,
        "attitude_error_deg": {
            "mean": mean(lambda x: x["attitude_error_deg"]["mean"]),
            "worst_session_p95": max(x["attitude_error_deg"]["p95"] for x in rows),
        },
        "velocity_rms_m_s": mean(lambda x: x["velocity_rms_m_s"] ** 2) ** 0.5,
        "vertical_velocity_m_s": {
            "bias": mean(lambda x: x["vertical_velocity_m_s"]["bias"]),
            "rms": mean(lambda x: x["vertical_velocity_m_s"]["rms"] ** 2) ** 0.5,
        },
        "after_push": _after_push_totals([x.get("after_push") for x in rows]),
    }


def _after_push_totals(rows: list[dict | None]) -> dict | None:
    """The sessions' planar velocity error in the second after each push (``after_push``):
    pushes and ticks summed, the mean and RMS tick weighted, the worst tick's and the worst
    push's; None without any."""
    rows = [x for x in rows if x]
    if not rows:
        return None
    n = sum(x["ticks"] for x in rows)
    return {
        "pushes": sum(x["pushes"] for x in rows),
        "ticks": n,
        "mean_m_s": sum(x["mean_m_s"] * x["ticks"] for x in rows) / n,
        "rms_m_s": (sum(x["rms_m_s"] ** 2 * x["ticks"] for x in rows) / n) ** 0.5,
        "worst_m_s": max(x["worst_m_s"] for x in rows),
        "worst_push_mean_m_s": max(x["worst_push_mean_m_s"] for x in rows),
        "window_s": rows[0]["window_s"],
    }


def _locomotion_totals(results: list[dict]) -> dict | None:
    """Totals of the legged sessions' ``locomotion`` sections (None without any)."""
    legs = [r["locomotion"] for r in results if r.get("locomotion") is not None]
    if not legs:
        return None
    hours = sum(r["simulated_hours"] for r in results if r.get("locomotion") is not None)
    falls = sum(x["falls"] for x in legs)
    running = sum(x["running_s"] for x in legs)
    # the velocity-tracking figures of the sessions a velocity commands (a clip's mean nothing)
    vel = [x for x in legs if x.get("commanded_by", "velocity") == "velocity"]
    vel_running = sum(x["running_s"] for x in vel)
    windows = [
        x["min_window_success_rate"] for x in vel if x["min_window_success_rate"] is not None
    ]
    kinds = sorted({k for x in legs for k in x["peak_winding_c"]})
    from sim2real.eval.soak.falls import ORIGINS

    origins = {o: sum(x.get("falls_by_origin", {}).get(o, 0) for x in legs) for o in ORIGINS}
    causes: dict[str, int] = {}
    for x in legs:
        for cause, n in x.get("falls_by_cause", {}).items():
            causes[cause] = causes.get(cause, 0) + n
    return {
        "sessions": len(legs),
        "falls": falls,
        "falls_per_hour": falls / hours if hours > 0 else 0.0,
        "falls_by_origin": origins,
        "stops_while_falling": sum(x.get("stops_while_falling", 0) for x in legs),
        "false_fall_stops": sum(x.get("false_fall_stops", 0) for x in legs),
        "fall_replays": {
            k: sum(x.get("fall_replays", {}).get(k, 0) for x in legs)
            for k in ("falls", "own_loop", "own_loop_fell", "redraw", "redraw_fell")
        },
        "falls_by_cause": causes,
        "commands_issued": sum(x.get("commands_issued", 0) for x in legs),
        "clip_sessions": len(legs) - len(vel),
        "tracking_success": (
            sum(x["tracked_s"] for x in vel) / vel_running if vel_running else None
        ),
        "min_window_success_rate": min(windows) if windows else None,
        "yaw_tracking_success": _yaw_tracking(vel, vel_running),
        "heading": _heading_totals(vel),
        "distance_m": sum(x["distance_m"] for x in legs),
        "mean_forward_speed_m_s": (
            sum(x["forward_m"] for x in vel) / vel_running if vel_running else None
        ),
        "running_s": running,
        "standing_fraction": running / (3600.0 * hours) if hours > 0 else None,
        "peak_winding_c": {
            k: max(x["peak_winding_c"][k] for x in legs if k in x["peak_winding_c"]) for k in kinds
        },
    }


def _yaw_tracking(vel: list[dict], running: float) -> float | None:
    """The velocity-commanded sessions' yaw-rate tracking success (tracked / RUNNING s); None
    without RUNNING time or when a session's result has no yaw figure (written before it)."""
    if not running or any("yaw_tracked_s" not in x for x in vel):
        return None
    return sum(x["yaw_tracked_s"] for x in vel) / running


def _heading_totals(vel: list[dict]) -> dict | None:
    """The heading commands of the sessions that ran them: ``heading_commands_ended`` and their
    ``mean_heading_error_deg`` at their end (weighted by commands); None without any."""
    rows = [x["heading"] for x in vel if x.get("heading")]
    if not rows:
        return None
    n = sum(h["heading_commands_ended"] for h in rows)
    error = sum(
        h["mean_heading_error_deg"] * h["heading_commands_ended"]
        for h in rows
        if h["heading_commands_ended"]
    )
    return {"heading_commands_ended": n, "mean_heading_error_deg": error / n if n else None}


def _wheel_totals(results: list[dict]) -> dict | None:
    """The wheels' largest true speed over the sessions against their limits (the sessions'
    ``wheels``, :func:`sim2real.eval.soak.result.wheel_speeds`); None without wheels."""
    wheels = [r["wheels"] for r in results if (r.get("wheels") or {}).get("joints")]
    if not wheels:
        return None
    joints = wheels[0]["joints"]
    return {
        "joints": joints,
        "peak_speed_rad_s": {j: max(w["peak_speed_rad_s"][j] for w in wheels) for j in joints},
        "velocity_limit_rad_s": wheels[0]["velocity_limit_rad_s"],
        "soft_velocity_limit_rad_s": wheels[0]["soft_velocity_limit_rad_s"],
    }
