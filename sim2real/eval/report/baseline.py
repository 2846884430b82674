"""The comparison of a soak report with a baseline report (an earlier campaign's report.json).

Baseline comparison (:func:`compare_with_baseline`, campaign totals; the baseline must be of schema
2): a regression is a true-state violation rate per hour (any type; over the baseline's same
first hours for a shorter run: :func:`violation_basis`) above ``baseline * (1 +
violation_tolerance) + violation_slack``, an intervention fraction of ticks (any check, or all
together) above ``baseline * (1 + violation_tolerance) + intervention_slack``, a success rate or a
minimum window success rate below ``baseline - success_tolerance`` (a legged campaign's velocity
tracking only where a velocity commands sessions on both sides, not a motion clip), a peak winding temperature
above ``baseline + temperature_tolerance`` (any joint), or more latched faults per simulated hour
than the baseline. A check that failed in the same sessions of the baseline is a known failure
(:func:`known_failures`): reported, but not new.
"""

from __future__ import annotations

from sim2real.eval.report.schema import ReportError, Thresholds, check_schema


def compare_with_baseline(
    report: dict, baseline: dict, thresholds: Thresholds, path: str | None = None
) -> dict:
    """Compare a report's totals with a baseline report's (see the module docstring).

    Returns:
        ``{"path", "passed", "regressions": [...], "compared": {...}, "violation_basis"}``
        (what the violation rates were compared with, :func:`violation_basis`).

    Raises:
        ReportError: the baseline is not of schema ``SCHEMA_VERSION`` (schema 1 is refused),
            misses a field, or is of another robot (the message names ``path``, the field and
            the expected value).
    """
    where = path or "baseline"
    check_schema(baseline, where)
    robot, base_robot = report["campaign"].get("robot"), baseline["campaign"].get("robot")
    if robot != base_robot:
        raise ReportError(
            f"{where}: field 'campaign.robot': the baseline is of robot "
            f"'{base_robot}', this campaign of '{robot}'"
        )
    new, old = report["totals"], baseline["totals"]
    c = _Comparison(thresholds)
    base_rates, basis = violation_basis(report, baseline)
    for kind, rate in new["violations"]["rate_per_hour"].items():
        base = base_rates.get(kind, 0.0)
        c.rose(
            f"violations.{kind}.per_hour",
            base,
            rate,
            thresholds.violation_slack,
            f"{kind} violations (true state) per hour rose from {base:.2f} ({basis}) to "
            f"{rate:.2f} (allowed {{allowed:.2f}})",
        )
    _interventions(c, new, old)
    _success(c, new, old)
    _thermal(c, new, old)
    rate, base = new["latched_faults_per_hour"], old["latched_faults_per_hour"]
    c.add(
        "latched_faults_per_hour",
        base,
        rate,
        base,
        rate > base * (1 + 1e-9) + 1e-12,
        f"new latched faults: {rate:.3f} per hour against {base:.3f} in the baseline",
    )
    return {
        "path": None if path is None else str(path),
        "passed": not c.regressions,
        "regressions": c.regressions,
        "compared": c.compared,
        "violation_basis": basis,
        "known_failures": known_failures(report, baseline),
    }


class _Comparison:
    """The metrics compared so far (``compared``) and those that regressed (``regressions``)."""

    def __init__(self, thresholds: Thresholds):
        self.thresholds = thresholds
        self.regressions: list[dict] = []
        self.compared: dict[str, dict] = {}

    def add(self, metric, base, current, allowed, worse, message) -> None:
        self.compared[metric] = {"baseline": base, "current": current, "allowed": allowed}
        if worse:
            self.regressions.append(
                {
                    "metric": metric,
                    "baseline": base,
                    "current": current,
                    "allowed": allowed,
                    "message": message,
                }
            )

    def rose(self, metric, base, current, slack, message) -> None:
        """A rate above ``base * (1 + violation_tolerance) + slack``; ``message`` a template of
        ``allowed`` (the bound) and ``allowed_percent`` (100 x the bound)."""
        allowed = base * (1 + self.thresholds.violation_tolerance) + slack
        words = message.format(allowed=allowed, allowed_percent=100 * allowed)
        self.add(metric, base, current, allowed, current > allowed, words)

    def fell(self, metric, label, base, rate) -> None:
        """A success rate (None: none, 0) below ``base - success_tolerance``."""
        allowed = base - self.thresholds.success_tolerance
        current = 0.0 if rate is None else rate
        self.add(
            metric,
            base,
            rate,
            allowed,
            current < allowed,
            f"{label} fell from {base:.3f} to {current:.3f} (allowed {allowed:.3f})",
        )


def _interventions(c: _Comparison, new: dict, old: dict) -> None:
    """Each check's share of ticks (and any check's) against the baseline's."""
    fractions = {k: v["fraction"] for k, v in new["interventions"]["checks"].items()}
    fractions["any"] = new["interventions"]["any"]["fraction"]
    base_fractions = {k: v["fraction"] for k, v in old["interventions"]["checks"].items()}
    base_fractions["any"] = old["interventions"]["any"]["fraction"]
    for check, share in fractions.items():
        base = base_fractions.get(check, 0.0)
        c.rose(
            f"interventions.{check}.fraction",
            base,
            share,
            c.thresholds.intervention_slack,
            f"{check} interventions rose from {100 * base:.3f} % to {100 * share:.3f} % of ticks "
            "(allowed {allowed_percent:.3f} %)",
        )


def _success(c: _Comparison, new: dict, old: dict) -> None:
    """Goal success (an arm's) and tracking success (a legged robot's), overall and windowed."""
    for key, label in (
        ("success_rate", "goal success rate"),
        ("min_window_success_rate", "lowest windowed goal success rate"),
    ):
        if old["goals"][key] is not None:
            c.fell(f"goals.{key}", label, old["goals"][key], new["goals"][key])
    new_loco, old_loco = new.get("locomotion"), old.get("locomotion")
    if not (_velocity_sessions(new_loco) and _velocity_sessions(old_loco)):
        return  # a motion clip commands one side's sessions: no velocity tracking to compare
    for key, label in (
        ("tracking_success", "tracking success (legged)"),
        ("yaw_tracking_success", "yaw-rate tracking success (legged)"),
        ("min_window_success_rate", "lowest windowed tracking success (legged)"),
    ):
        if old_loco.get(key) is not None:
            c.fell(f"locomotion.{key}", label, old_loco[key], new_loco.get(key))


def _velocity_sessions(loco: dict | None) -> int:
    """The legged sessions a velocity commands in ``totals.locomotion`` (its ``clip_sessions``
    a motion clip commands; 0 without locomotion)."""
    return 0 if not loco else loco["sessions"] - loco.get("clip_sessions", 0)


def _thermal(c: _Comparison, new: dict, old: dict) -> None:
    """Each winding's peak temperature against the baseline's plus ``temperature_tolerance``."""
    for joint, peak in new["thermal"]["peak_c"].items():
        base = old["thermal"]["peak_c"].get(joint)
        if base is None:
            continue
        allowed = base + c.thresholds.temperature_tolerance
        c.add(
            f"thermal.peak_c.{joint}",
            base,
            peak,
            allowed,
            peak > allowed,
            f"peak winding temperature of {joint} rose from {base:.1f} to {peak:.1f} degC "
            f"(allowed {allowed:.1f})",
        )


def violation_basis(report: dict, baseline: dict) -> tuple[dict[str, float], str]:
    """The baseline's true violation rates per hour to compare ``report``'s with, and what they
    are: like with like. A campaign of whole hours shorter than its baseline is compared with the
    baseline's same first hours (its ``totals.violations.per_hour`` rows over its sessions): a
    1-hour run against an 8-hour baseline's mean judged the first hour, whose rate differs from
    the mean (the go2 baseline's first hour 1,193 velocity ticks against a mean of 1,126). A run
    of a fraction of an hour cannot be matched hour for hour: it is compared with the mean, and
    the basis says so.

    Returns:
        ``({violation type: rate per hour}, basis)``, the basis a phrase for the messages.
    """
    old = baseline["totals"]["violations"]
    hours = float(report["campaign"].get("hours") or 0.0)
    base_hours = float(baseline["campaign"].get("hours") or 0.0)
    mean = dict(old["rate_per_hour"])
    if not hours or not base_hours or hours >= base_hours - 1e-9:
        return mean, f"the baseline's {base_hours:g} h"
    whole = round(hours)
    rows = sorted(old.get("per_hour") or [], key=lambda r: r["hour"])[:whole]
    sessions = int(baseline["campaign"].get("sessions") or 1)
    if whole < 1 or abs(hours - whole) > 1e-6 or len(rows) < whole:
        return mean, (
            f"the baseline's mean over {base_hours:g} h: a {hours:g}-h run cannot be matched "
            "hour for hour"
        )
    rates = {k: sum(r["counts"].get(k, 0) for r in rows) / (whole * sessions) for k in mean}
    return rates, f"the baseline's first {whole} h"


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
