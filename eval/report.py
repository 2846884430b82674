"""Soak reports: report.json, report.html, junit.xml, and the comparison with a baseline.

Two words (DESIGN.md): a **violation** is the robot's *true* state past a limit, counted from the
simulator's ground truth (:mod:`deploy.violations`); an **intervention** is a command the guard or
the smoother changed (:mod:`deploy.interventions`). They are reported apart: a guard that clamps
often is a policy leaning on it, not a robot beyond its limits.

``report.json`` (``schema_version`` ``SCHEMA_VERSION`` = 2)::

    schema_version, tool, created (UTC, ISO 8601)
    campaign        robot, policy, policy_sha256, hours, sessions, seed, options of the sessions,
                    executor, sessions_per_process, wall_s
    thresholds      the pass/fail thresholds and baseline tolerances (:class:`Thresholds`)
    sessions[]      one per session (eval.soak's result):
        id, seed, status ('complete' | 'diverged'), simulated_s, simulated_hours, ticks,
        control_mode, randomization {dynamics, sensors, drift, faults[]},
        violations {source, total {type: ticks}, any, per_hour [{hour, start_s, end_s,
                    counts {type: ticks}, any}], rate_per_hour {type: ticks per hour}}
                    (types: hard_limit, soft_limit, velocity, effort, workspace, self_collision;
                    a tick counts once per type)
        interventions {ticks, checks {check: {count, fraction}}, any {count, fraction},
                    warnings {soft_band_estimate: {count, fraction}}, per_hour [{hour, start_s,
                    end_s, ticks, counts {check: ticks}, any, warnings}]}
                    (checks: hard_limit, soft_limit, velocity, workspace, self_collision, effort,
                    stopping_distance, target_clamp; count = ticks on which the check changed a
                    command, fraction = count / ticks)
        goals {issued, reached, success_rate, median_time_to_reach_s, within_s, period_s,
               window_s, windows [{start_s, end_s, issued, reached, success_rate}],
               min_window_success_rate, missed [{t_s, issued_s, goal, q, dq, q_estimate,
               distance_m, best_distance_m, interventions {check: ticks, any}}],
               missed_dropped}
        faults {scheduled, injected, survived, responses {held, safe_stop, resumed, latched,
                not_running}, events [{kind, start_s, duration_s, magnitude, response, survived,
                causes, ...}]},
        runtime {safe_stops, by_cause, non_finite_actions, resyncs, anchors, latched_faults,
                 latches[], operator_resets, final_mode, final_cause},
        estimator {missing_readings, stale_readings, reinitializations},
        thermal {joints, derating_start_c, max_winding_c, peak_c, derating_band_s,
                 over_temperature_s, curve {t_s, winding_c {joint: [...]}}},
        curves {t_s, goals_issued, goals_reached, violations {type | any: [...]},
                interventions {check | any: [...]}, mode}   (cumulative counts)
        drift {friction_final_nm}, diverged (message or null),
        checks {name: {passed, message}},
        wall {wall_s, speed, batch, tick_cost_us, tick_cost_histogram, stage_cost_us},
        film (only with the film strip, :mod:`eval.film`) {clips [{kind, kinds, label, moments,
              t_s, start_s, end_s, video, still (paths relative to the report's folder),
              frames, bytes, replay_exact, checked, from_tick}], moments {kind: found},
              not_filmed, fps, size, frames_per_s, error (why there is no film, or null)}
    totals          over every session: simulated_hours, ticks, violations {total, any,
                    rate_per_hour, per_hour [{hour, counts, any}]}, interventions {ticks, checks
                    {check: {count, fraction}}, any {count, fraction}, warnings, per_hour [{hour,
                    ticks, counts, any, fraction}]}, goals {issued, reached, success_rate,
                    min_window_success_rate, missed, missed_dropped}, faults {injected, survived,
                    responses, by_kind}, latched_faults, operator_resets, thermal {peak_c,
                    derating_band_s, over_temperature_s}, diverged [ids], tick_cost_us
    checks          {name: {passed, failed_sessions}}
    baseline        null, or {path, passed, regressions [{metric, baseline, current, allowed,
                    message}], compared {metric: {baseline, current, allowed}},
                    known_failures [{check, sessions, message}]: checks failed in the same
                    sessions of the baseline too (:func:`known_failures`)}
    passed          every check and the baseline comparison passed

Everything in a session except ``wall`` (wall-clock time, tick cost) follows from the session's
seed and options: a repeated or resumed session reproduces it exactly.

Session checks (``CHECKS``): ``no_hard_violation`` (no true-state hard-limit violation and no
hard-limit safe stop of the runtime), ``no_latched_fault``, ``no_over_temperature`` (a winding
above its maximum, or an over-temperature safe stop), ``success_rate`` (at least
``min_success_rate`` over the session), ``window_success`` (at least ``min_window_success_rate``
in every window of ``window_minutes`` with a goal), ``interventions`` (ticks with any
intervention at most ``max_intervention_rate`` of the ticks), ``no_divergence``. junit.xml has one
testcase per session and check, and one for the baseline comparison.

Baseline comparison (:func:`compare_with_baseline`, campaign totals; the baseline must be of schema
2): a regression is a true-state violation rate per hour (any type) above ``baseline * (1 +
violation_tolerance) + violation_slack``, an intervention fraction of ticks (any check, or all
together) above ``baseline * (1 + violation_tolerance) + intervention_slack``, a success rate or a
minimum window success rate below ``baseline - success_tolerance``, a peak winding temperature
above ``baseline + temperature_tolerance`` (any joint), or more latched faults per simulated hour
than the baseline.

Every file is written to a temporary file and moved into place with ``os.replace``. The HTML is
self-contained (plots are matplotlib PNGs embedded as base64; no scripts, no external resources),
and so is the film strip: each session's clips (H.264 MP4 in ``<video>``, the still at the
moment as its poster) embedded as base64 from ``film/<id>/`` beside the report (at most
``eval.film.MAX_CLIPS`` short clips per session). In junit.xml a failed check names the still
frame of its first clip (``still frame: film/<id>/NN-<kind>.png``, also as a
``[[ATTACHMENT|...]]`` line in the testcase's system-out).
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from deploy.errors import Sim2RealError
from deploy.files import atomic_write

SCHEMA_VERSION = 2
CHECKS = (
    "no_hard_violation",
    "no_latched_fault",
    "no_over_temperature",
    "success_rate",
    "window_success",
    "interventions",
    "no_divergence",
)


class ReportError(Sim2RealError, ValueError):
    """A report (or baseline) cannot be read or compared; the message names the file and field."""


@dataclass(frozen=True)
class Thresholds:
    """Pass/fail thresholds.

    Attributes:
        min_success_rate: Lowest goal success rate over a session that passes (0.95).
        min_window_success_rate: Lowest goal success rate in any window of a session (0.90).
        max_intervention_rate: Highest fraction of ticks with any intervention (0.01).
        violation_tolerance: Relative rise of a violation rate per hour, or of an intervention
            fraction, over the baseline that is still no regression (0.10: +10 %).
        violation_slack: Absolute rise, violations per hour, also allowed (noise of short runs).
        intervention_slack: Absolute rise of an intervention fraction of ticks also allowed.
        success_tolerance: Drop of the success rate, or of the minimum window success rate
            (absolute), still allowed.
        temperature_tolerance: Rise of a joint's peak winding temperature still allowed, K.

    Raises:
        ReportError: a negative or non-finite value, or a rate above 1 (named).
    """

    min_success_rate: float = 0.95
    min_window_success_rate: float = 0.90
    max_intervention_rate: float = 0.01
    violation_tolerance: float = 0.10
    violation_slack: float = 1.0
    intervention_slack: float = 0.002
    success_tolerance: float = 0.02
    temperature_tolerance: float = 2.0

    def __post_init__(self):
        for name, value in asdict(self).items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ReportError(f"thresholds: {name}: expected a number >= 0, got {value!r}")
        for name in ("min_success_rate", "min_window_success_rate", "max_intervention_rate"):
            if getattr(self, name) > 1:
                raise ReportError(
                    f"thresholds: {name}: expected a value in [0, 1], got {getattr(self, name)}"
                )


# ---------------------------------------------------------------------- checks and totals
def session_checks(result: dict, thresholds: Thresholds) -> dict[str, dict]:
    """The checks of one session result: ``{name: {"passed": bool, "message": str}}``."""
    hard = result["violations"]["total"].get("hard_limit", 0)
    hard_stops = result["runtime"]["by_cause"].get("hard_limit", 0)
    latched = result["runtime"]["latched_faults"]
    th = result["thermal"]
    hot = [j for j in th["joints"] if th["peak_c"][j] > th["max_winding_c"][j]]
    thermal_stops = result["runtime"]["by_cause"].get("over_temperature", 0)
    goals = result["goals"]
    rate = goals["success_rate"]
    window = goals["min_window_success_rate"]
    iv = result["interventions"]
    share = iv["any"]["fraction"]
    causes = sorted({x["cause"] for x in result["runtime"]["latches"] if x.get("cause")})
    worst = sorted(
        ((c["fraction"], k) for k, c in iv["checks"].items() if c["count"]), reverse=True
    )[:3]
    checks = {
        "no_hard_violation": (
            hard == 0 and hard_stops == 0,
            f"{hard} ticks with a joint beyond a hard limit (true state), {hard_stops} "
            "hard-limit safe stops"
            if hard or hard_stops
            else "no hard-limit violation (true state), no hard-limit safe stop",
        ),
        "no_latched_fault": (
            latched == 0,
            f"{latched} latched faults ({', '.join(causes)})" if latched else "no latched fault",
        ),
        "no_over_temperature": (
            not hot and thermal_stops == 0,
            (
                f"winding above its maximum: {', '.join(hot) or 'none'}; over-temperature safe "
                f"stops: {thermal_stops}"
            )
            if hot or thermal_stops
            else f"peak winding {max(th['peak_c'].values()):.1f} degC",
        ),
        "success_rate": (
            rate is not None and rate >= thresholds.min_success_rate,
            (
                f"success rate {rate:.3f} (threshold {thresholds.min_success_rate:.3f}, "
                f"{goals['reached']}/{goals['issued']} goals)"
                if rate is not None
                else "no goal was issued"
            ),
        ),
        "window_success": (
            window is not None and window >= thresholds.min_window_success_rate,
            (
                f"lowest success rate in a {goals['window_s'] / 60:g}-minute window {window:.3f} "
                f"(threshold {thresholds.min_window_success_rate:.3f}, "
                f"{len(goals['windows'])} windows)"
                if window is not None
                else "no goal was issued"
            ),
        ),
        "interventions": (
            share <= thresholds.max_intervention_rate,
            f"{100 * share:.3f} % of ticks with an intervention (threshold "
            f"{100 * thresholds.max_intervention_rate:.3f} %"
            + ("; " + ", ".join(f"{k} {100 * f:.3f} %" for f, k in worst) + ")" if worst else ")"),
        ),
        "no_divergence": (
            not result["diverged"],
            f"simulation diverged: {result['diverged']}" if result["diverged"] else "no divergence",
        ),
    }
    return {k: {"passed": bool(p), "message": m} for k, (p, m) in checks.items()}


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


def totals(results: list[dict]) -> dict:
    """Campaign totals over session results (see the module docstring)."""
    hours = sum(r["simulated_hours"] for r in results)
    types = list(results[0]["violations"]["total"]) if results else []
    total = {k: sum(r["violations"]["total"][k] for r in results) for k in types}
    ticks = sum(r["interventions"]["ticks"] for r in results)
    checks = list(results[0]["interventions"]["checks"]) if results else []
    warnings = list(results[0]["interventions"]["warnings"]) if results else []

    def entry(count: int) -> dict:
        return {"count": count, "fraction": count / ticks if ticks else 0.0}

    issued = sum(r["goals"]["issued"] for r in results)
    reached = sum(r["goals"]["reached"] for r in results)
    windows = [
        r["goals"]["min_window_success_rate"]
        for r in results
        if r["goals"]["min_window_success_rate"] is not None
    ]
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
        "ticks": ticks,
        "violations": {
            "source": results[0]["violations"]["source"] if results else None,
            "total": total,
            "any": sum(r["violations"]["any"] for r in results),
            "rate_per_hour": {k: (v / hours if hours > 0 else 0.0) for k, v in total.items()},
            "per_hour": _sum_rows(results, "violations", types),
        },
        "interventions": {
            "ticks": ticks,
            "checks": {
                k: entry(sum(r["interventions"]["checks"][k]["count"] for r in results))
                for k in checks
            },
            "any": entry(sum(r["interventions"]["any"]["count"] for r in results)),
            "warnings": {
                k: entry(sum(r["interventions"]["warnings"][k]["count"] for r in results))
                for k in warnings
            },
            "per_hour": _sum_rows(results, "interventions", checks),
        },
        "goals": {
            "issued": issued,
            "reached": reached,
            "success_rate": reached / issued if issued else None,
            "min_window_success_rate": min(windows) if windows else None,
            "missed": sum(len(r["goals"]["missed"]) for r in results),
            "missed_dropped": sum(r["goals"]["missed_dropped"] for r in results),
        },
        "faults": {
            "injected": sum(r["faults"]["injected"] for r in results),
            "survived": sum(r["faults"]["survived"] for r in results),
            "responses": responses,
            "by_kind": by_kind,
        },
        "latched_faults": latched,
        "latched_faults_per_hour": latched / hours if hours > 0 else 0.0,
        "operator_resets": sum(r["runtime"]["operator_resets"] for r in results),
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


def missed_states(report: dict) -> list[dict]:
    """The missed goals of every session of a report, in session order.

    Each is a session's ``goals.missed`` entry (``t_s``, ``issued_s``, ``goal`` m, ``q`` rad,
    ``dq`` rad/s, ``q_estimate`` rad, ``distance_m``, ``best_distance_m``, ``interventions``)
    with the session's ``session`` id and ``seed`` added: the true states where the policy missed,
    to start training episodes from (``q``).

    Raises:
        ReportError: a report without ``sessions[].goals.missed`` (named; schema 1 had none).
    """
    out = []
    for i, s in enumerate(report.get("sessions", [])):
        missed = s.get("goals", {}).get("missed")
        if missed is None:
            raise ReportError(
                f"report: field 'sessions[{i}].goals.missed' is missing (expected a list; "
                f"schema_version {SCHEMA_VERSION} reports have it)"
            )
        out.extend({**m, "session": s["id"], "seed": s["seed"]} for m in missed)
    return out


def build_report(
    campaign: dict,
    results: list[dict],
    thresholds: Thresholds | None = None,
    baseline: dict | None = None,
    baseline_path: str | None = None,
) -> dict:
    """The report.json document (see the module docstring).

    Args:
        campaign: Campaign description (robot, policy, options; see the schema).
        results: Session results from :func:`eval.soak.run_campaign`.
        thresholds: Pass/fail thresholds (default :class:`Thresholds`).
        baseline: An earlier report (:func:`load_report`) to compare with, or None.
        baseline_path: Where the baseline came from (recorded in the report).

    Raises:
        ReportError: the baseline is not of this schema, misses a field, or is of another robot.
    """
    thresholds = Thresholds() if thresholds is None else thresholds
    sessions = []
    for r in results:
        r = dict(r)
        r["checks"] = session_checks(r, thresholds)
        sessions.append(r)
    checks = {
        name: {
            "passed": all(s["checks"][name]["passed"] for s in sessions),
            "failed_sessions": [s["id"] for s in sessions if not s["checks"][name]["passed"]],
        }
        for name in CHECKS
    }
    report = {
        "schema_version": SCHEMA_VERSION,
        "tool": "soak-test",
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "campaign": campaign,
        "thresholds": asdict(thresholds),
        "sessions": sessions,
        "totals": totals(results),
        "checks": checks,
        "baseline": None,
    }
    if baseline is not None:
        report["baseline"] = compare_with_baseline(report, baseline, thresholds, baseline_path)
    report["passed"] = all(c["passed"] for c in checks.values()) and (
        report["baseline"] is None or report["baseline"]["passed"]
    )
    return report


# ---------------------------------------------------------------------- baseline
#: Fields of report.json the baseline comparison reads.
_BASELINE_FIELDS = (
    ("campaign", "robot"),
    ("totals", "simulated_hours"),
    ("totals", "violations", "rate_per_hour"),
    ("totals", "interventions", "checks"),
    ("totals", "interventions", "any", "fraction"),
    ("totals", "goals", "success_rate"),
    ("totals", "goals", "min_window_success_rate"),
    ("totals", "thermal", "peak_c"),
    ("totals", "latched_faults_per_hour"),
)


def _check_schema(doc: dict, where: str) -> None:
    """``doc`` is a report of this schema with every field the comparison reads.

    Raises:
        ReportError: naming ``where``, the field and the expected value.
    """
    version = doc.get("schema_version")
    if version != SCHEMA_VERSION:
        hint = ""
        if version == 1:
            hint = (
                " (schema 1 counted the guard's clamps as violations; its numbers cannot be "
                "compared with true-state violations and interventions: run the baseline "
                "campaign again with this version)"
            )
        raise ReportError(
            f"{where}: field 'schema_version': expected {SCHEMA_VERSION}, got {version!r}{hint}"
        )
    for field_path in _BASELINE_FIELDS:
        node = doc
        for key in field_path:
            if not isinstance(node, dict) or key not in node:
                raise ReportError(f"{where}: field '{'.'.join(field_path)}' is missing")
            node = node[key]


def load_report(path: str | os.PathLike) -> dict:
    """Read a report.json written by this module (e.g. a baseline).

    Raises:
        ReportError: unreadable file, invalid JSON, or a missing or unsupported
            ``schema_version`` (schema 1 is refused) or a missing field the comparison needs
            (the message names the file, the field and the expected value).
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise ReportError(f"{path}: cannot read the report: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReportError(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise ReportError(f"{path}: expected a JSON object (a soak report.json)")
    _check_schema(doc, str(path))
    return doc


def compare_with_baseline(
    report: dict, baseline: dict, thresholds: Thresholds, path: str | None = None
) -> dict:
    """Compare a report's totals with a baseline report's (see the module docstring).

    Returns:
        ``{"path", "passed", "regressions": [...], "compared": {...}}``.

    Raises:
        ReportError: the baseline is not of schema ``SCHEMA_VERSION`` (schema 1 is refused),
            misses a field, or is of another robot (the message names ``path``, the field and
            the expected value).
    """
    where = path or "baseline"
    _check_schema(baseline, where)
    robot, base_robot = report["campaign"].get("robot"), baseline["campaign"].get("robot")
    if robot != base_robot:
        raise ReportError(
            f"{where}: field 'campaign.robot': the baseline is of robot "
            f"'{base_robot}', this campaign of '{robot}'"
        )
    new, old = report["totals"], baseline["totals"]
    regressions, compared = [], {}

    def add(metric, base, current, allowed, worse, message):
        compared[metric] = {"baseline": base, "current": current, "allowed": allowed}
        if worse:
            regressions.append(
                {
                    "metric": metric,
                    "baseline": base,
                    "current": current,
                    "allowed": allowed,
                    "message": message,
                }
            )

    for kind, rate in new["violations"]["rate_per_hour"].items():
        base = old["violations"]["rate_per_hour"].get(kind, 0.0)
        allowed = base * (1 + thresholds.violation_tolerance) + thresholds.violation_slack
        add(
            f"violations.{kind}.per_hour",
            base,
            rate,
            allowed,
            rate > allowed,
            f"{kind} violations (true state) per hour rose from {base:.2f} to {rate:.2f} "
            f"(allowed {allowed:.2f})",
        )
    fractions = {k: c["fraction"] for k, c in new["interventions"]["checks"].items()}
    fractions["any"] = new["interventions"]["any"]["fraction"]
    base_fractions = {k: c["fraction"] for k, c in old["interventions"]["checks"].items()}
    base_fractions["any"] = old["interventions"]["any"]["fraction"]
    for check, share in fractions.items():
        base = base_fractions.get(check, 0.0)
        allowed = base * (1 + thresholds.violation_tolerance) + thresholds.intervention_slack
        add(
            f"interventions.{check}.fraction",
            base,
            share,
            allowed,
            share > allowed,
            f"{check} interventions rose from {100 * base:.3f} % to {100 * share:.3f} % of ticks "
            f"(allowed {100 * allowed:.3f} %)",
        )
    for key, label in (
        ("success_rate", "goal success rate"),
        ("min_window_success_rate", "lowest windowed goal success rate"),
    ):
        rate, base = new["goals"][key], old["goals"][key]
        if base is None:
            continue
        allowed = base - thresholds.success_tolerance
        current = 0.0 if rate is None else rate
        add(
            f"goals.{key}",
            base,
            rate,
            allowed,
            current < allowed,
            f"{label} fell from {base:.3f} to {current:.3f} (allowed {allowed:.3f})",
        )
    for joint, peak in new["thermal"]["peak_c"].items():
        base = old["thermal"]["peak_c"].get(joint)
        if base is None:
            continue
        allowed = base + thresholds.temperature_tolerance
        add(
            f"thermal.peak_c.{joint}",
            base,
            peak,
            allowed,
            peak > allowed,
            f"peak winding temperature of {joint} rose from {base:.1f} to {peak:.1f} degC "
            f"(allowed {allowed:.1f})",
        )
    rate, base = new["latched_faults_per_hour"], old["latched_faults_per_hour"]
    add(
        "latched_faults_per_hour",
        base,
        rate,
        base,
        rate > base * (1 + 1e-9) + 1e-12,
        f"new latched faults: {rate:.3f} per hour against {base:.3f} in the baseline",
    )
    return {
        "path": None if path is None else str(path),
        "passed": not regressions,
        "regressions": regressions,
        "compared": compared,
        "known_failures": known_failures(report, baseline),
    }


def known_failures(report: dict, baseline: dict) -> list[dict]:
    """The failed checks of ``report`` that failed in the baseline too, in the same sessions.

    A nightly campaign compares the shipped policy with its own earlier campaign: a check it
    already failed there (e.g. one session's success rate below the threshold) is a known failure,
    reported but not new; a check failing in a session where the baseline passed is new. Whether
    a known failure got worse is the regression comparison's business (campaign totals).

    Returns:
        ``[{"check", "sessions", "message"}]``, one per check whose failing sessions (by id) all
        failed that check in the baseline.
    """
    base_checks = baseline.get("checks") or {}
    out = []
    for name, c in report["checks"].items():
        if c["passed"]:
            continue
        before = set((base_checks.get(name) or {}).get("failed_sessions") or [])
        now = list(c["failed_sessions"])
        if now and set(now) <= before:
            out.append(
                {
                    "check": name,
                    "sessions": now,
                    "message": f"{name} failed in {', '.join(now)}, as in the baseline",
                }
            )
    return out


def failures(report: dict) -> list[str]:
    """Names of what failed: the failed checks, and ``'regression'`` for the baseline.

    With a baseline, a check that failed only where the baseline failed it too (its
    ``known_failures``) is left out: the exit code of a nightly campaign reports what is new.
    """
    b = report.get("baseline")
    known = {k["check"] for k in (b or {}).get("known_failures", [])}
    out = [name for name, c in report["checks"].items() if not c["passed"] and name not in known]
    if b and not b["passed"]:
        out.append("regression")
    return out


# ---------------------------------------------------------------------- files


def write_json(path: str | os.PathLike, report: dict) -> Path:
    """Write report.json atomically."""
    return atomic_write(path, json.dumps(report, indent=1))


def junit_xml(report: dict) -> str:
    """junit.xml text: one testcase per session and check, one for the baseline comparison."""
    robot = report["campaign"].get("robot", "robot")
    suites = ET.Element("testsuites", name="soak-test")
    suite = ET.SubElement(suites, "testsuite", name=f"soak.{robot}")
    tests = fails = 0
    for s in report["sessions"]:
        wall = s["wall"]["wall_s"] / max(len(CHECKS), 1)
        for name in CHECKS:
            c = s["checks"][name]
            case = ET.SubElement(
                suite, "testcase", classname=f"soak.{s['id']}", name=name, time=f"{wall:.3f}"
            )
            tests += 1
            if not c["passed"]:
                fails += 1
                message = c["message"]
                still = _check_still(s, name)
                if still:
                    message += f"; still frame: {still}"
                failure = ET.SubElement(case, "failure", message=message, type=name)
                failure.text = message
                if still:
                    ET.SubElement(case, "system-out").text = f"[[ATTACHMENT|{still}]]"
            else:
                ET.SubElement(case, "system-out").text = c["message"]
    if report.get("baseline") is not None:
        b = report["baseline"]
        case = ET.SubElement(suite, "testcase", classname="soak.baseline", name="no_regression")
        tests += 1
        if not b["passed"]:
            fails += 1
            text = "; ".join(r["message"] for r in b["regressions"])
            ET.SubElement(case, "failure", message=text, type="regression").text = text
    for node in (suites, suite):
        node.set("tests", str(tests))
        node.set("failures", str(fails))
        node.set("errors", "0")
    ET.indent(suites)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(suites, encoding="unicode")


#: The film's moments that show why a check failed (eval.film.KINDS).
_CHECK_FILM = {
    "no_hard_violation": "hard_violation",
    "no_latched_fault": "latched_fault",
    "no_over_temperature": "hottest_minute",
    "success_rate": "missed_goals",
    "window_success": "missed_goals",
}


def _check_still(session: dict, check: str) -> str | None:
    """The still frame (path relative to the report) of a session's first clip showing what
    made ``check`` fail, or None."""
    kind = _CHECK_FILM.get(check)
    for clip in (session.get("film") or {}).get("clips", []):
        if kind in clip.get("kinds", [clip.get("kind")]):
            return clip["still"]
    return None


def write_junit(path: str | os.PathLike, report: dict) -> Path:
    """Write junit.xml atomically."""
    return atomic_write(path, junit_xml(report) + "\n")


# ---------------------------------------------------------------------- HTML
def _png(fig) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(rows: int = 1, cols: int = 1, height: float = 3.2):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, height * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


def plot_temperatures(report: dict) -> str:
    """Winding temperature vs time per joint (one panel per session), base64 PNG."""
    sessions = report["sessions"]
    fig, axes = _figure(len(sessions), 1, 2.6)
    for ax, s in zip(axes[:, 0], sessions, strict=True):
        th = s["thermal"]
        t = np.asarray(th["curve"]["t_s"]) / 3600.0
        for joint in th["joints"]:
            ax.plot(t, th["curve"]["winding_c"][joint], label=joint)
        lo = min(th["derating_start_c"].values())
        hi = max(th["max_winding_c"].values())
        ax.axhspan(lo, hi, color="orange", alpha=0.15, label="derating band")
        ax.axhline(hi, color="red", lw=0.8, ls="--")
        ax.set_title(f"{s['id']}: winding temperature (max per interval)", fontsize=9)
        ax.set_ylabel("degC")
        ax.legend(fontsize=7, ncol=4, loc="upper left")
    axes[-1, 0].set_xlabel("simulated time (h)")
    return _png(fig)


def _stacked_hours(ax, rows: list[dict], scale, empty: str) -> None:
    """Stacked bars of ``rows[i]["counts"]`` per hour, each divided by ``scale(row)``."""
    if not rows:
        ax.text(0.5, 0.5, empty, ha="center", transform=ax.transAxes)
        return
    names = list(rows[0]["counts"])
    hours = np.array([r["hour"] for r in rows])
    bottom = np.zeros(len(rows))
    for name in names:
        values = np.array([r["counts"][name] / scale(r) for r in rows], dtype=float)
        if values.any():
            ax.bar(hours, values, bottom=bottom, label=name)
            bottom += values
    if not bottom.any():
        ax.text(0.5, 0.5, empty, ha="center", transform=ax.transAxes)
    else:
        ax.legend(fontsize=7)


def plot_violations(report: dict) -> str:
    """True-state violations per hour by type, summed over sessions (stacked bars), base64 PNG."""
    rows = report["totals"]["violations"]["per_hour"]
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    _stacked_hours(ax, rows, lambda r: 1.0, "no violations")
    ax.set_xlabel("hour of the session")
    ax.set_ylabel("ticks (all sessions)")
    ax.set_title("Violations (true state) per hour by type", fontsize=9)
    return _png(fig)


def plot_interventions(report: dict) -> str:
    """Interventions per hour as % of ticks by check, all sessions (stacked bars; a tick with
    several checks counts in each), with the threshold on any intervention, base64 PNG."""
    rows = report["totals"]["interventions"]["per_hour"]
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    _stacked_hours(ax, rows, lambda r: max(r["ticks"], 1) / 100.0, "no interventions")
    limit = report["thresholds"].get("max_intervention_rate")
    if limit is not None:
        ax.axhline(100 * limit, color="red", lw=0.8, ls="--", label="threshold (any)")
        ax.legend(fontsize=7)
    ax.set_xlabel("hour of the session")
    ax.set_ylabel("% of ticks")
    ax.set_title("Interventions (guard and smoother changed a command) per hour", fontsize=9)
    return _png(fig)


def plot_success(report: dict) -> str:
    """Goal success rate per curve interval over time, per session, base64 PNG."""
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    for s in report["sessions"]:
        c = s["curves"]
        t = np.asarray(c["t_s"]) / 3600.0
        issued = np.diff(np.asarray(c["goals_issued"], dtype=float))
        reached = np.diff(np.asarray(c["goals_reached"], dtype=float))
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = np.where(issued > 0, reached / np.maximum(issued, 1), np.nan)
        if len(t) > 1:
            ax.plot(t[1:], rate, marker=".", label=s["id"])
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel("simulated time (h)")
    ax.set_ylabel("success rate")
    ax.set_title("Goals reached / goals issued per interval", fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, ncol=4)
    return _png(fig)


def plot_windows(report: dict) -> str:
    """Goal success rate per window (by the goals' issue time), per session, with the
    threshold, base64 PNG."""
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    for i, s in enumerate(report["sessions"]):
        windows = s["goals"]["windows"]
        if windows:  # one segment per window: windows without a goal leave gaps
            ax.hlines(
                [w["success_rate"] for w in windows],
                [w["start_s"] / 3600.0 for w in windows],
                [w["end_s"] / 3600.0 for w in windows],
                colors=f"C{i % 10}",
                label=s["id"],
            )
    limit = report["thresholds"].get("min_window_success_rate")
    if limit is not None:
        ax.axhline(limit, color="red", lw=0.8, ls="--", label="threshold")
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel("simulated time (h)")
    ax.set_ylabel("success rate")
    ax.set_title("Goal success rate per window (windows without a goal left out)", fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, ncol=4)
    return _png(fig)


def plot_tick_cost(report: dict) -> str:
    """Histogram of the runtime's tick cost (without physics), all batches, base64 PNG."""
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    seen = set()
    for s in report["sessions"]:
        key = tuple(s["wall"]["batch"])
        if key in seen:  # every session of a batch shares the batch's histogram
            continue
        seen.add(key)
        h = s["wall"]["tick_cost_histogram"]
        if h["bin_us"]:
            edges = np.geomspace(10.0, 25_000.0, 80)  # the last bin holds the >= 20 ms overflow
            values = np.clip(np.asarray(h["bin_us"], dtype=float) + 0.5, edges[0], edges[-1])
            ax.hist(
                values, bins=edges, weights=h["count"], histtype="step", label=f"batch {list(key)}"
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("tick cost (us; sessions of a batch share one)")
    ax.set_ylabel("ticks")
    ax.set_title("Runtime tick cost (wall clock, without physics)", fontsize=9)
    if seen:
        ax.legend(fontsize=7)
    return _png(fig)


def _table(header: list[str], rows: list[list]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(_fmt(c))}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(_fmt(v) for v in value)
    return str(value)


def _data_uri(base: Path | None, rel: str, mime: str) -> str:
    """``data:`` URI of file ``base/rel``, or the relative path where it cannot be read."""
    if base is not None:
        try:
            data = (base / rel).read_bytes()
        except OSError:
            return html.escape(rel)
        return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"
    return html.escape(rel)


def film_html(report: dict, base: Path | None = None) -> str:
    """The film strip section: per session, its clips as ``<video>`` elements (embedded from
    ``base``, the report's folder; relative links without it), each captioned with its moments,
    the replayed span and whether the replay matched the run bit for bit."""
    sessions = [s for s in report["sessions"] if s.get("film") is not None]
    if not sessions:
        return ""
    parts = [
        "<h2>Film: the worst moments</h2>",
        "<p>Each clip is the session replayed from its nearest checkpoint with the same seed and "
        "fault schedule (env 0, true joint positions): the goal in green, the end-effector trail "
        "in orange, links tinted red where the guard changed the target.</p>",
    ]
    for s in sessions:
        f = s["film"]
        parts.append(f"<h3>{html.escape(s['id'])}</h3>")
        if f.get("error"):
            parts.append(f"<p class='fail'>no film: {html.escape(f['error'])}</p>")
            continue
        if not f["clips"]:
            parts.append("<p>nothing to film</p>")
        for c in f["clips"]:
            exact = {True: "replay exact", False: "REPLAY DIFFERS from the run", None: ""}[
                c.get("replay_exact")
            ]
            video = _data_uri(base, c["video"], "video/mp4")
            poster = _data_uri(base, c["still"], "image/png")
            parts.append(
                f"<figure class='clip' data-kind='{html.escape(c['kind'])}'>"
                f"<video controls muted loop playsinline preload='auto' poster='{poster}' "
                f"width='{f['size'][0]}' height='{f['size'][1]}'>"
                f"<source src='{video}' type='video/mp4'></video>"
                f"<figcaption>{html.escape(c['label'])} (clip {c['start_s']:.1f}-"
                f"{c['end_s']:.1f} s{'; ' + exact if exact else ''}; "
                f"<a href='{html.escape(c['still'])}'>still</a>)</figcaption></figure>"
            )
        if f.get("not_filmed"):
            parts.append(
                f"<p>{f['not_filmed']} more moments not filmed (at most {f.get('max_clips')} clips "
                "per session)</p>"
            )
    return "\n".join(parts)


def report_html(report: dict, base: str | os.PathLike | None = None) -> str:
    """The self-contained report.html text; ``base``: the report's folder, from which the film
    strip's clips are embedded (module docstring)."""
    c, t = report["campaign"], report["totals"]
    verdict = "PASSED" if report["passed"] else "FAILED"
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>soak-test {html.escape(str(c.get('robot')))}: {verdict}</title>",
        "<style>body{font-family:sans-serif;margin:1.5em;max-width:70em}"
        "table{border-collapse:collapse;margin:0.5em 0 1.5em;font-size:0.85em}"
        "td,th{border:1px solid #bbb;padding:2px 6px;text-align:left}"
        "th{background:#eee}.pass{color:#070}.fail{color:#b00;font-weight:bold}"
        "img{max-width:100%}figure.clip{display:inline-block;margin:0 1em 1em 0;"
        "max-width:30em;vertical-align:top}figure.clip video{max-width:100%}"
        "figcaption{font-size:0.85em}</style></head><body>",
        f"<h1>Soak test: <span class='{'pass' if report['passed'] else 'fail'}'>{verdict}"
        "</span></h1>",
        _table(
            ["robot", "policy", "sessions", "hours each", "seed", "simulated h", "created"],
            [
                [
                    c.get("robot"),
                    c.get("policy"),
                    t["sessions"],
                    c.get("hours"),
                    c.get("seed"),
                    t["simulated_hours"],
                    report["created"],
                ]
            ],
        ),
        "<h2>Checks</h2>",
    ]
    check_rows = [
        [s["id"]]
        + [
            ("pass: " if s["checks"][n]["passed"] else "FAIL: ") + s["checks"][n]["message"]
            for n in CHECKS
        ]
        for s in report["sessions"]
    ]
    failed = [
        f"{name} ({', '.join(c['failed_sessions'])})"
        for name, c in report["checks"].items()
        if not c["passed"]
    ]
    if failed:
        parts.append(f"<p class='fail'>Failed checks: {html.escape('; '.join(failed))}</p>")
    parts.append(_table(["session", *CHECKS], check_rows))
    parts.append(film_html(report, Path(base) if base is not None else None))
    b = report.get("baseline")
    if b is not None:
        parts.append(f"<h2>Baseline comparison: {'passed' if b['passed'] else 'REGRESSION'}</h2>")
        parts.append(f"<p>baseline: {html.escape(str(b['path']))}</p>")
        for k in b.get("known_failures", []):
            parts.append(f"<p class='fail'>Known failure: {html.escape(k['message'])}</p>")
        parts.append(
            _table(
                ["metric", "baseline", "current", "allowed", "regression"],
                [
                    [
                        m,
                        v["baseline"],
                        v["current"],
                        v["allowed"],
                        any(r["metric"] == m for r in b["regressions"]),
                    ]
                    for m, v in b["compared"].items()
                ],
            )
        )
    parts.append("<h2>Sessions</h2>")
    parts.append(
        _table(
            [
                "session",
                "status",
                "simulated h",
                "hard-limit violations (true, ticks)",
                "violations/h (true, all types)",
                "interventions (% of ticks)",
                "success rate",
                "lowest window success",
                "missed goals",
                "faults injected",
                "survived",
                "latched",
                "peak winding degC",
                "speed (sim/wall)",
            ],
            [
                [
                    s["id"],
                    s["status"],
                    s["simulated_hours"],
                    s["violations"]["total"].get("hard_limit", 0),
                    sum(s["violations"]["rate_per_hour"].values()),
                    100 * s["interventions"]["any"]["fraction"],
                    s["goals"]["success_rate"],
                    s["goals"]["min_window_success_rate"],
                    len(s["goals"]["missed"]) + s["goals"]["missed_dropped"],
                    s["faults"]["injected"],
                    s["faults"]["survived"],
                    s["runtime"]["latched_faults"],
                    max(s["thermal"]["peak_c"].values()),
                    s["wall"]["speed"],
                ]
                for s in report["sessions"]
            ],
        )
    )
    parts.append("<h2>Interventions by check (% of ticks)</h2>")
    checks = list(t["interventions"]["checks"])
    parts.append(
        _table(
            ["session", "any", *checks, "warning: estimate in soft band"],
            [
                [
                    s["id"],
                    100 * s["interventions"]["any"]["fraction"],
                    *(100 * s["interventions"]["checks"][k]["fraction"] for k in checks),
                    100 * s["interventions"]["warnings"]["soft_band_estimate"]["fraction"],
                ]
                for s in report["sessions"]
            ],
        )
    )
    for title, fn in (
        ("Winding temperature", plot_temperatures),
        ("Violations (true state) per hour", plot_violations),
        ("Interventions per hour", plot_interventions),
        ("Success over time", plot_success),
        ("Success per window", plot_windows),
        ("Tick cost", plot_tick_cost),
    ):
        parts.append(
            f"<h2>{title}</h2><img alt='{title}' src='data:image/png;base64,{fn(report)}'>"
        )
    parts.append("<h2>Injected faults and the runtime's response</h2>")
    parts.append(
        _table(
            [
                "session",
                "kind",
                "start (s)",
                "duration (s)",
                "magnitude",
                "mode at onset",
                "response",
                "survived",
                "causes",
                "held actions",
                "missing readings",
            ],
            [
                [
                    s["id"],
                    ev["kind"],
                    ev["start_s"],
                    ev["duration_s"],
                    ev["magnitude"],
                    ev["mode_at_onset"],
                    ev["response"],
                    ev["survived"],
                    ev["causes"],
                    ev["non_finite_actions_held"],
                    ev["missing_readings"],
                ]
                for s in report["sessions"]
                for ev in s["faults"]["events"]
            ],
        )
    )
    parts.append("<h2>Randomization drawn</h2>")
    rand_rows = []
    for s in report["sessions"]:
        r = s["randomization"]
        rand_rows.append(
            [
                s["id"],
                r["dynamics"]["link_length"],
                r["dynamics"]["mass"],
                r["dynamics"]["friction"],
                r["dynamics"]["damping"],
                r["dynamics"]["actuator_strength"],
                r["sensors"]["noise_sigma"],
                r["sensors"]["latency_ticks"],
                r["sensors"]["dropout_probability"],
                r["drift"]["friction_rate"],
            ]
        )
    parts.append(
        _table(
            [
                "session",
                "link length",
                "mass",
                "friction",
                "damping",
                "actuator",
                "encoder sigma (rad)",
                "latency (ticks)",
                "dropout",
                "friction rise (1/h)",
            ],
            rand_rows,
        )
    )
    parts.append("</body></html>")
    return "\n".join(parts)


def write_html(path: str | os.PathLike, report: dict) -> Path:
    """Write report.html atomically (the film strip embedded from the report's folder)."""
    return atomic_write(path, report_html(report, Path(path).parent))


def write_reports(out: str | os.PathLike, report: dict) -> dict[str, Path]:
    """Write report.json, report.html and junit.xml into ``out``; returns their paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return {
        "json": write_json(out / "report.json", report),
        "html": write_html(out / "report.html", report),
        "junit": write_junit(out / "junit.xml", report),
    }


def summary_text(report: dict) -> str:
    """A few lines for the console."""
    t = report["totals"]
    lines = [
        f"soak-test: {report['campaign'].get('robot')}, {t['sessions']} sessions, "
        f"{t['simulated_hours']:.3f} simulated h: {'PASSED' if report['passed'] else 'FAILED'}"
    ]
    rate = t["goals"]["success_rate"]
    lines.append(
        f"  goals        {t['goals']['reached']}/{t['goals']['issued']} reached"
        + (f" ({100 * rate:.1f} %)" if rate is not None else "")
    )
    w = t["goals"]["min_window_success_rate"]
    if w is not None:
        lines.append(f"  windows      lowest success rate in a window {100 * w:.1f} %")
    v = ", ".join(f"{k} {n}" for k, n in t["violations"]["total"].items())
    lines.append(f"  violations   (true state, ticks) {v}")
    iv = t["interventions"]
    used = ", ".join(
        f"{k} {100 * c['fraction']:.3f}" for k, c in iv["checks"].items() if c["count"]
    )
    lines.append(
        f"  interventions {100 * iv['any']['fraction']:.3f} % of ticks"
        + (f" ({used})" if used else "")
    )
    f = t["faults"]
    resp = ", ".join(f"{k} {n}" for k, n in f["responses"].items() if n)
    lines.append(
        f"  faults       {f['injected']} injected, {f['survived']} survived ({resp or 'none'}); "
        f"latched {t['latched_faults']}, operator resets {t['operator_resets']}"
    )
    peaks = ", ".join(f"{j} {p:.1f}" for j, p in t["thermal"]["peak_c"].items())
    lines.append(f"  peak winding degC {peaks}")
    tc = t["tick_cost_us"]
    if tc["samples"]:
        lines.append(f"  tick cost us p50 {tc['p50_us']:.0f}, p99 {tc['p99_us']:.0f}")
    b = report.get("baseline")
    known = {k["check"] for k in (b or {}).get("known_failures", [])}
    for name, c in report["checks"].items():
        if not c["passed"]:
            tag = "FAILED (known: in the baseline too)" if name in known else "FAILED"
            lines.append(f"  {tag} {name}: {', '.join(c['failed_sessions'])}")
    if b is not None:
        if b["passed"]:
            lines.append(f"  baseline     no regression against {b['path']}")
        for r in b["regressions"]:
            lines.append(f"  REGRESSION   {r['message']}")
    return "\n".join(lines)
