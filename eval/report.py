"""Soak reports: report.json, report.html, junit.xml, and the comparison with a baseline.

``report.json`` (``schema_version`` ``SCHEMA_VERSION``)::

    schema_version, tool, created (UTC, ISO 8601)
    campaign        robot, policy, policy_sha256, hours, sessions, seed, options of the sessions,
                    executor, sessions_per_process, wall_s
    thresholds      min_success_rate and the baseline tolerances (:class:`Thresholds`)
    sessions[]      one per session (eval.soak's result):
        id, seed, status ('complete' | 'diverged'), simulated_s, simulated_hours, ticks,
        control_mode, randomization {dynamics, sensors, drift, faults[]},
        violations {total {check: n}, per_hour [{hour, start_s, end_s, counts}], rate_per_hour},
        goals {issued, reached, success_rate, median_time_to_reach_s, within_s, period_s},
        faults {scheduled, injected, survived, responses {held, safe_stop, resumed, latched,
                not_running}, events [{kind, start_s, duration_s, magnitude, response, survived,
                causes, ...}]},
        runtime {safe_stops, by_cause, non_finite_actions, resyncs, latched_faults, latches[],
                 operator_resets, final_mode, final_cause},
        estimator {missing_readings, stale_readings, reinitializations},
        thermal {joints, derating_start_c, max_winding_c, peak_c, derating_band_s,
                 over_temperature_s, curve {t_s, winding_c {joint: [...]}}},
        curves {t_s, goals_issued, goals_reached, violations {check: [...]}, mode},
        drift {friction_final_nm}, diverged (message or null),
        checks {name: {passed, message}},
        wall {wall_s, speed, batch, tick_cost_us, tick_cost_histogram, stage_cost_us}
    totals          over every session: simulated_hours, violations {total, rate_per_hour,
                    per_hour}, goals, faults {injected, survived, responses, by_kind},
                    latched_faults, operator_resets, thermal {peak_c, derating_band_s,
                    over_temperature_s}, diverged [ids], tick_cost_us
    checks          {name: {passed, failed_sessions}}
    baseline        null, or {path, passed, regressions [{metric, baseline, current, allowed,
                    message}], compared {metric: {baseline, current}}}
    passed          every check and the baseline comparison passed

Everything in a session except ``wall`` (wall-clock time, tick cost) follows from the session's
seed and options: a repeated or resumed session reproduces it exactly.

Session checks (``CHECKS``): no hard-limit violation, no latched fault, no over-temperature (a
winding above its maximum, or an over-temperature safe stop), goal success rate at least
``min_success_rate``, no simulator divergence. junit.xml has one testcase per session and check,
and one for the baseline comparison.

Baseline comparison (:func:`compare_with_baseline`, campaign totals): a regression is a violation
rate per hour (any check) above ``baseline * (1 + violation_tolerance) + violation_slack``, a
success rate below ``baseline - success_tolerance``, a peak winding temperature above
``baseline + temperature_tolerance`` (any joint), or more latched faults per simulated hour than
the baseline.

Every file is written to a temporary file and moved into place with ``os.replace``. The HTML is
self-contained (plots are matplotlib PNGs embedded as base64; no scripts, no external resources).
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

from eval.checkpoint import atomic_write

SCHEMA_VERSION = 1
CHECKS = (
    "no_hard_violation",
    "no_latched_fault",
    "no_over_temperature",
    "success_rate",
    "no_divergence",
)


class ReportError(ValueError):
    """A report (or baseline) cannot be read or compared; the message names the file and field."""


@dataclass(frozen=True)
class Thresholds:
    """Pass/fail thresholds.

    Attributes:
        min_success_rate: Lowest goal success rate a session passes with (our default: 0.5).
        violation_tolerance: Relative rise of a violation rate per hour over the baseline that is
            still no regression (0.10: +10 %).
        violation_slack: Absolute rise, violations per hour, also allowed (noise of short runs).
        success_tolerance: Drop of the success rate (absolute) still allowed.
        temperature_tolerance: Rise of a joint's peak winding temperature still allowed, K.
    """

    min_success_rate: float = 0.5
    violation_tolerance: float = 0.10
    violation_slack: float = 1.0
    success_tolerance: float = 0.02
    temperature_tolerance: float = 2.0

    def __post_init__(self):
        for name, value in asdict(self).items():
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ReportError(f"thresholds: {name}: expected a number >= 0, got {value!r}")
        if self.min_success_rate > 1:
            raise ReportError(
                f"thresholds: min_success_rate: expected a value in [0, 1], got "
                f"{self.min_success_rate}"
            )


# ---------------------------------------------------------------------- checks and totals
def session_checks(result: dict, thresholds: Thresholds) -> dict[str, dict]:
    """The checks of one session result: ``{name: {"passed": bool, "message": str}}``."""
    hard = result["violations"]["total"].get("hard_limit", 0)
    latched = result["runtime"]["latched_faults"]
    th = result["thermal"]
    hot = [j for j in th["joints"] if th["peak_c"][j] > th["max_winding_c"][j]]
    thermal_stops = result["runtime"]["by_cause"].get("over_temperature", 0)
    rate = result["goals"]["success_rate"]
    causes = sorted({x["cause"] for x in result["runtime"]["latches"] if x.get("cause")})
    checks = {
        "no_hard_violation": (
            hard == 0,
            f"{hard} hard-limit violations" if hard else "no hard-limit violation",
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
                f"{result['goals']['reached']}/{result['goals']['issued']} goals)"
                if rate is not None
                else "no goal was issued"
            ),
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


def totals(results: list[dict]) -> dict:
    """Campaign totals over session results (see the module docstring)."""
    hours = sum(r["simulated_hours"] for r in results)
    checks_names = list(results[0]["violations"]["total"]) if results else []
    total = {k: sum(r["violations"]["total"][k] for r in results) for k in checks_names}
    per_hour: dict[int, dict] = {}
    for r in results:
        for h in r["violations"]["per_hour"]:
            row = per_hour.setdefault(h["hour"], {k: 0 for k in checks_names})
            for k, v in h["counts"].items():
                row[k] += v
    issued = sum(r["goals"]["issued"] for r in results)
    reached = sum(r["goals"]["reached"] for r in results)
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
        "violations": {
            "total": total,
            "rate_per_hour": {k: (v / hours if hours > 0 else 0.0) for k, v in total.items()},
            "per_hour": [{"hour": h, "counts": per_hour[h]} for h in sorted(per_hour)],
        },
        "goals": {
            "issued": issued,
            "reached": reached,
            "success_rate": reached / issued if issued else None,
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
        ReportError: the baseline is of another robot.
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
def load_report(path: str | os.PathLike) -> dict:
    """Read a report.json written by this module (e.g. a baseline).

    Raises:
        ReportError: unreadable file, invalid JSON, or a missing or unsupported
            ``schema_version`` or a missing field the comparison needs (named).
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
    version = doc.get("schema_version")
    if version != SCHEMA_VERSION:
        raise ReportError(
            f"{path}: field 'schema_version': expected {SCHEMA_VERSION}, got {version!r}"
        )
    for field_path in (
        ("campaign", "robot"),
        ("totals", "simulated_hours"),
        ("totals", "violations", "rate_per_hour"),
        ("totals", "goals", "success_rate"),
        ("totals", "thermal", "peak_c"),
        ("totals", "latched_faults_per_hour"),
    ):
        node = doc
        for key in field_path:
            if not isinstance(node, dict) or key not in node:
                raise ReportError(f"{path}: field '{'.'.join(field_path)}' is missing")
            node = node[key]
    return doc


def compare_with_baseline(
    report: dict, baseline: dict, thresholds: Thresholds, path: str | None = None
) -> dict:
    """Compare a report's totals with a baseline report's (see the module docstring).

    Returns:
        ``{"path", "passed", "regressions": [...], "compared": {...}}``.

    Raises:
        ReportError: the baseline is of another robot.
    """
    robot, base_robot = report["campaign"].get("robot"), baseline["campaign"].get("robot")
    if robot != base_robot:
        raise ReportError(
            f"{path or 'baseline'}: field 'campaign.robot': the baseline is of robot "
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

    for check, rate in new["violations"]["rate_per_hour"].items():
        base = old["violations"]["rate_per_hour"].get(check, 0.0)
        allowed = base * (1 + thresholds.violation_tolerance) + thresholds.violation_slack
        add(
            f"violations.{check}.per_hour",
            base,
            rate,
            allowed,
            rate > allowed,
            f"{check} violations per hour rose from {base:.2f} to {rate:.2f} (allowed "
            f"{allowed:.2f})",
        )
    rate, base = new["goals"]["success_rate"], old["goals"]["success_rate"]
    if base is not None:
        allowed = base - thresholds.success_tolerance
        current = 0.0 if rate is None else rate
        add(
            "goals.success_rate",
            base,
            rate,
            allowed,
            current < allowed,
            f"goal success rate fell from {base:.3f} to {current:.3f} (allowed {allowed:.3f})",
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
    }


def failures(report: dict) -> list[str]:
    """Names of what failed: the failed checks, and ``'regression'`` for the baseline."""
    out = [name for name, c in report["checks"].items() if not c["passed"]]
    if report.get("baseline") and not report["baseline"]["passed"]:
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
                failure = ET.SubElement(case, "failure", message=c["message"], type=name)
                failure.text = c["message"]
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


def plot_violations(report: dict) -> str:
    """Violations per hour by check, summed over sessions (stacked bars), base64 PNG."""
    rows = report["totals"]["violations"]["per_hour"]
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    if rows:
        names = list(rows[0]["counts"])
        hours = np.array([r["hour"] for r in rows])
        bottom = np.zeros(len(rows))
        for name in names:
            values = np.array([r["counts"][name] for r in rows], dtype=float)
            if values.any():
                ax.bar(hours, values, bottom=bottom, label=name)
                bottom += values
        if not bottom.any():
            ax.text(0.5, 0.5, "no violations", ha="center", transform=ax.transAxes)
        else:
            ax.legend(fontsize=7)
    ax.set_xlabel("hour of the session")
    ax.set_ylabel("violations (all sessions)")
    ax.set_title("Violations per hour by type", fontsize=9)
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


def report_html(report: dict) -> str:
    """The self-contained report.html text."""
    c, t = report["campaign"], report["totals"]
    verdict = "PASSED" if report["passed"] else "FAILED"
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>soak-test {html.escape(str(c.get('robot')))}: {verdict}</title>",
        "<style>body{font-family:sans-serif;margin:1.5em;max-width:70em}"
        "table{border-collapse:collapse;margin:0.5em 0 1.5em;font-size:0.85em}"
        "td,th{border:1px solid #bbb;padding:2px 6px;text-align:left}"
        "th{background:#eee}.pass{color:#070}.fail{color:#b00;font-weight:bold}"
        "img{max-width:100%}</style></head><body>",
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
    parts.append(_table(["session", *CHECKS], check_rows))
    b = report.get("baseline")
    if b is not None:
        parts.append(f"<h2>Baseline comparison: {'passed' if b['passed'] else 'REGRESSION'}</h2>")
        parts.append(f"<p>baseline: {html.escape(str(b['path']))}</p>")
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
                "hard-limit violations",
                "violations/h (all)",
                "success rate",
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
                    s["goals"]["success_rate"],
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
    for title, fn in (
        ("Winding temperature", plot_temperatures),
        ("Violations per hour", plot_violations),
        ("Success over time", plot_success),
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
    """Write report.html atomically."""
    return atomic_write(path, report_html(report))


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
    v = ", ".join(f"{k} {n}" for k, n in t["violations"]["total"].items())
    lines.append(f"  violations   {v}")
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
    for name, c in report["checks"].items():
        if not c["passed"]:
            lines.append(f"  FAILED {name}: {', '.join(c['failed_sessions'])}")
    b = report.get("baseline")
    if b is not None:
        if b["passed"]:
            lines.append(f"  baseline     no regression against {b['path']}")
        for r in b["regressions"]:
            lines.append(f"  REGRESSION   {r['message']}")
    return "\n".join(lines)
