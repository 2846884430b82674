"""Sim-to-sim comparison: the soak reports of one policy on several physics engines, figure by
figure.

:func:`compare` reads each engine's soak folder (its ``report.json``, read and checked by
:mod:`sim2real.eval.sim2sim.reports`), matches the sessions by seed and returns, per session and over the
campaign, each figure's value per engine, the gap between the engines and whether that gap makes
the result engine-dependent, and the verdict (:data:`VERDICT_SAME`, :data:`VERDICT_DEPENDS`).
The figures (:data:`~sim2real.eval.sim2sim.reports.FIGURE_FIELDS` names the report.json field each is read
from) are the soak's own: goals reached (arm) or tracking success, falls and mean forward speed
(legged robot), true violations by type, guard interventions, peak winding temperature, safe
stops, latched faults and diverged sessions. Each threshold is a module constant below, with the
reason for its value.

A gap is the spread of the engines' values (largest minus smallest, in the figure's unit); the
relative gap is the spread over the largest magnitude (0 when every value is 0). A figure that is
defined on some engines and not on others (no goal issued, never RUNNING) is engine-dependent.

Errors: :class:`~sim2real.eval.sim2sim.reports.Sim2SimError` (a ``ValueError``, importable from here too)
names the file, the field and the value expected: a report that cannot be read or checked
(:mod:`sim2real.eval.sim2sim.reports`), or reports of different robots, policies, durations or seeds (such
gaps are not the engines'). Option differences that do not prevent the comparison are returned as
``warnings``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from sim2real.eval.sim2sim.reports import (
    FIGURE_FIELDS,
    VIOLATION_LABELS,
    FigureValue,
    Sim2SimError,
    SoakReport,
    is_number,
    option_warnings,
    read_figures,
    report_info,
)

__all__ = [
    "COUNT_MAX_RATIO",
    "FIGURE_FIELDS",
    "GOALS_MAX_RELATIVE_GAP",
    "INTERVENTIONS_MAX_GAP_PP",
    "PEAK_WINDING_MAX_GAP_C",
    "SPEED_MAX_GAP_M_S",
    "TRACKING_MAX_GAP_PP",
    "VERDICT_DEPENDS",
    "VERDICT_SAME",
    "VIOLATION_LABELS",
    "Sim2SimError",
    "compare",
]

#: Largest gap of a legged robot's tracking success (share of RUNNING time within the soak's
#: tracking tolerance of the command), percentage points, that is still the same result: twice
#: the distance between the soak's session and window thresholds (95 % and 90 %). Below it the
#: contact models' different slip at the feet; above it a gait that works on one engine's
#: contacts and not on the other's.
TRACKING_MAX_GAP_PP = 10.0

#: Largest relative gap of an arm's goal success rate (goals reached / goals issued) that is still
#: the same result: one goal in ten. The goals and their timing are the same on every engine (the
#: seed draws them), so a larger gap is the arm reaching differently, not a different task.
GOALS_MAX_RELATIVE_GAP = 0.10

#: Largest gap of the peak winding temperature (the hottest joint's, degC) that is still the same
#: result: less than the derating band of any shipped motor (15 K or more from derating start to
#: the winding's maximum) and five times the soak's own baseline tolerance (2 K). A larger gap
#: moves a motor into or out of derating: the engines load the joints differently.
PEAK_WINDING_MAX_GAP_C = 10.0

#: Largest gap of the guard's interventions (ticks with any intervention, percentage points of
#: the ticks) that is still the same result: half the soak's pass threshold of 1 % of the ticks,
#: so that a gap flagged is one that can move a policy across that check on its own.
INTERVENTIONS_MAX_GAP_PP = 0.5

#: Largest gap of a legged robot's mean forward speed (m/s over RUNNING time) that is still the
#: same result: a quarter of the soak's tracking tolerance (0.2 m/s). The commands are the same on
#: every engine (the seed draws them), so a steady gap this large over a session is a robot that
#: walks differently, even when both stay within the tolerance.
SPEED_MAX_GAP_M_S = 0.05

#: Counts of rare events (falls, true-violation ticks of each type, safe stops of each cause,
#: latched faults, diverged sessions) are engine-dependent when they are zero on some engines and
#: not on others (the soak's checks judge falls, hard-limit ticks and latched faults by their
#: presence), or when the largest is more than this factor times the smallest: an order of
#: magnitude, as a few simulated hours hold too few rare events for a finer comparison.
COUNT_MAX_RATIO = 10.0

VERDICT_SAME = "same on both"
VERDICT_DEPENDS = "the policy's result depends on the engine"


# ---------------------------------------------------------------------- judging


def _count_reason(values: Mapping[str, float], what: str = "") -> str | None:
    """Why counts differ beyond :data:`COUNT_MAX_RATIO` or by presence (None: they agree)."""
    zero = [e for e, v in values.items() if v == 0]
    some = [e for e, v in values.items() if v != 0]
    prefix = f"{what}: " if what else ""
    if zero and some:
        on = ", ".join(f"{values[e]:g} on {e}" for e in some)
        return f"{prefix}{on}, none on {', '.join(zero)}"
    if some:
        low, high = min(values.values()), max(values.values())
        if high > COUNT_MAX_RATIO * low:
            return f"{prefix}{high:g} vs {low:g}: more than {COUNT_MAX_RATIO:g} times"
    return None


def _gap_rule(limit: float, unit: str, decimals: int) -> Callable[..., str | None]:
    def rule(values, gap, relative, breakdowns):
        return f"gap {gap:.{decimals}f} {unit} > {limit:g} {unit}" if gap > limit else None

    return rule


def _relative_rule(limit: float) -> Callable[..., str | None]:
    def rule(values, gap, relative, breakdowns):
        if relative > limit:
            return f"relative gap {100 * relative:.1f} % > {100 * limit:g} %"
        return None

    return rule


def _count_rule(values, gap, relative, breakdowns) -> str | None:
    return _count_reason(values)


def _breakdown_rule(values, gap, relative, breakdowns) -> str | None:
    """Safe stops: the count rule on each cause, then on the total."""
    reasons = []
    kinds = sorted({k for b in breakdowns.values() for k in (b or {})})
    for kind in kinds:
        reason = _count_reason({e: (b or {}).get(kind, 0) for e, b in breakdowns.items()}, kind)
        if reason:
            reasons.append(reason)
    return "; ".join(reasons) or _count_reason(values)


@dataclass(frozen=True)
class _Spec:
    label: str
    unit: str
    threshold: str
    rule: Callable[..., str | None]


_COUNT_THRESHOLD = f"present on one engine only, or more than {COUNT_MAX_RATIO:g} times"


def _spec(name: str) -> _Spec:
    """The label, unit, threshold text and rule of figure ``name``."""
    if name.startswith("violations."):
        kind = name.split(".", 1)[1]
        label = VIOLATION_LABELS.get(kind, f"{kind} violations")
        return _Spec(label, "ticks", _COUNT_THRESHOLD, _count_rule)
    specs = {
        "goals_reached": _Spec(
            "goals reached",
            "%",
            f"relative gap > {100 * GOALS_MAX_RELATIVE_GAP:g} %",
            _relative_rule(GOALS_MAX_RELATIVE_GAP),
        ),
        "tracking_success": _Spec(
            "tracking success",
            "%",
            f"gap > {TRACKING_MAX_GAP_PP:g} percentage points",
            _gap_rule(TRACKING_MAX_GAP_PP, "points", 1),
        ),
        "falls": _Spec("falls", "count", _COUNT_THRESHOLD, _count_rule),
        "mean_speed": _Spec(
            "mean forward speed",
            "m/s",
            f"gap > {SPEED_MAX_GAP_M_S:g} m/s",
            _gap_rule(SPEED_MAX_GAP_M_S, "m/s", 3),
        ),
        "interventions": _Spec(
            "guard interventions",
            "% of ticks",
            f"gap > {INTERVENTIONS_MAX_GAP_PP:g} percentage points",
            _gap_rule(INTERVENTIONS_MAX_GAP_PP, "points", 3),
        ),
        "peak_winding": _Spec(
            "peak winding temperature",
            "degC",
            f"gap > {PEAK_WINDING_MAX_GAP_C:g} degC",
            _gap_rule(PEAK_WINDING_MAX_GAP_C, "degC", 1),
        ),
        "safe_stops": _Spec(
            "safe stops", "count", _COUNT_THRESHOLD + " (in total or of a cause)", _breakdown_rule
        ),
        "latched_faults": _Spec("latched faults", "count", _COUNT_THRESHOLD, _count_rule),
        "diverged": _Spec("diverged sessions", "count", _COUNT_THRESHOLD, _count_rule),
    }
    return specs[name]


def _judge(name: str, per_engine: dict[str, FigureValue]) -> dict:
    """One figure's entry: values per engine, gap, relative gap, flag and its reason."""
    spec = _spec(name)
    values = {e: v.value for e, v in per_engine.items()}
    defined = {e: float(v) for e, v in values.items() if v is not None}
    gap = relative = reason = None
    if defined and len(defined) < len(values):
        missing = [e for e in values if e not in defined]
        reason = f"defined on {', '.join(defined)} only (not on {', '.join(missing)})"
    elif defined:
        gap = max(defined.values()) - min(defined.values())
        scale = max(abs(v) for v in defined.values())
        relative = gap / scale if scale > 0 else 0.0
        breakdowns = {e: v.breakdown for e, v in per_engine.items()}
        reason = spec.rule(defined, gap, relative, breakdowns)
    entry = {
        "name": name,
        "label": spec.label,
        "unit": spec.unit,
        "values": values,
        "gap": gap,
        "relative_gap": relative,
        "threshold": spec.threshold,
        "engine_dependent": reason is not None,
        "reason": reason,
    }
    notes = {e: v.note for e, v in per_engine.items()}
    if any(n is not None for n in notes.values()):
        entry["notes"] = notes
    breakdowns = {e: v.breakdown for e, v in per_engine.items()}
    if any(b is not None for b in breakdowns.values()):
        entry["breakdown"] = breakdowns
    return entry


def _figure_table(per_engine: dict[str, dict[str, FigureValue]]) -> list[dict]:
    """Judge every figure any engine has (an engine without it has the value None)."""
    names: list[str] = []
    for figures in per_engine.values():
        names += [n for n in figures if n not in names]
    return [
        _judge(n, {e: figs.get(n, FigureValue(None)) for e, figs in per_engine.items()})
        for n in names
    ]


# ---------------------------------------------------------------------- compare


def compare(reports: Mapping[str, str | os.PathLike]) -> dict:
    """Compare the soak outputs of one policy on several engines, session by session (by seed)
    and in total.

    Args:
        reports: Engine name -> soak output folder (holding ``report.json``), two or more; any
            names (they label the columns), in the order given.

    Returns:
        The comparison (JSON-serializable)::

            tool ('sim2sim'), created (UTC, ISO 8601), engines [names], robot, kind ('arm' |
            'legged'), policy, policy_sha256, hours (simulated h per session), seeds [int],
            reports {engine: {path, engine (the report's own 'engine' or 'campaign.engine',
                     or null), passed, exit_code, failed_checks [names]}},
            thresholds {constant: value}, fields {figure: the report.json field read},
            totals [figure], sessions [{seed, ids {engine: session id}, figures [figure]}],
            flagged [{figure, label, where ('totals' | 'seed N'), reason}],
            dependent_figures [figure names, in figure order], engine_dependent (bool),
            verdict ('same on both' | "the policy's result depends on the engine: <labels>"),
            warnings [str]

        where a figure is ``{name, label, unit, values {engine: number or null}, gap (spread,
        the figure's unit, or null), relative_gap (spread / largest magnitude, or null),
        threshold (text), engine_dependent, reason (or null), notes {engine: text} (goals:
        'reached/issued'; peak winding: the joint; safe stops: by cause), breakdown {engine:
        {cause: count}} (safe stops)}``. Units: goals reached and tracking success in % (of goals,
        of RUNNING time), interventions in % of ticks, peak winding in degC, mean forward speed in
        m/s, the rest counts (violations in ticks).

    Raises:
        Sim2SimError: fewer than two engines; a folder without a readable report.json; another
            schema version; a field missing or of the wrong type; reports of different robots,
            policies (``campaign.policy_sha256``), hours or seeds, or with a seed twice (each
            message names the file, the field and the value expected).
    """
    if len(reports) < 2:
        raise Sim2SimError(
            f"reports: expected two engines or more (engine -> soak folder), got {list(reports)}"
        )
    loaded = [SoakReport(str(e), Path(folder)) for e, folder in reports.items()]
    first = loaded[0]
    robot = _same(loaded, "robot", "a robot name", lambda v: isinstance(v, str))
    sha = _same(loaded, "policy_sha256", "the policy's SHA-256", lambda v: isinstance(v, str))
    hours = _same(loaded, "hours", "a number > 0 (simulated h)", lambda v: is_number(v) and v > 0)
    policy = first.get(("campaign", "policy"), "a path", lambda v: isinstance(v, str))
    seeds = _seeds(loaded)
    ordered = sorted(seeds[first.engine])
    legged = _legged(first)
    totals = _figure_table(
        {r.engine: read_figures(r, ("totals",), legged, totals=True) for r in loaded}
    )
    session_rows = [_session_row(loaded, seeds, seed, legged) for seed in ordered]
    flagged = _flagged(totals, session_rows)
    order = [f["name"] for f in totals]
    dependent = sorted({f["figure"] for f in flagged}, key=order.index)

    return {
        "tool": "sim2sim",
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "engines": [r.engine for r in loaded],
        "robot": robot,
        "kind": "legged" if legged else "arm",
        "policy": policy,
        "policy_sha256": sha,
        "hours": hours,
        "seeds": ordered,
        "reports": {r.engine: report_info(r) for r in loaded},
        "thresholds": _thresholds(),
        "fields": dict(FIGURE_FIELDS),
        "totals": totals,
        "sessions": session_rows,
        "flagged": flagged,
        "dependent_figures": dependent,
        "engine_dependent": bool(dependent),
        "verdict": _verdict(dependent, len(loaded)),
        "warnings": option_warnings(loaded),
    }


def _thresholds() -> dict[str, float]:
    """The constants a figure's gap is judged by, by name (recorded in the comparison)."""
    return {
        "TRACKING_MAX_GAP_PP": TRACKING_MAX_GAP_PP,
        "GOALS_MAX_RELATIVE_GAP": GOALS_MAX_RELATIVE_GAP,
        "PEAK_WINDING_MAX_GAP_C": PEAK_WINDING_MAX_GAP_C,
        "INTERVENTIONS_MAX_GAP_PP": INTERVENTIONS_MAX_GAP_PP,
        "SPEED_MAX_GAP_M_S": SPEED_MAX_GAP_M_S,
        "COUNT_MAX_RATIO": COUNT_MAX_RATIO,
    }


def _legged(first: SoakReport) -> bool:
    """Whether the reports are a legged robot's (``totals.locomotion`` an object, not null)."""
    loco = first.get(
        ("totals", "locomotion"), "an object or null", lambda v: v is None or isinstance(v, dict)
    )
    return loco is not None


def _verdict(dependent: list[str], engines: int) -> str:
    """The comparison's verdict: the figures that depend on the engine, or the same."""
    if dependent:
        return f"{VERDICT_DEPENDS}: {', '.join(_spec(n).label for n in dependent)}"
    return VERDICT_SAME if engines == 2 else "same on every engine"


def _same(loaded: list[SoakReport], key: str, expected: str, ok: Callable[[Any], bool]) -> Any:
    """``campaign.<key>`` of the first report, checked equal in every other (``Sim2SimError``
    naming the file and both values where not)."""
    first = loaded[0]
    value = first.get(("campaign", key), expected, ok)
    for r in loaded[1:]:
        other = r.get(("campaign", key), expected, ok)
        if other != value:
            raise Sim2SimError(
                f"{r.path}: field 'campaign.{key}': expected {value!r} as in "
                f"{first.engine}'s report {first.path}, got {other!r} (a sim-to-sim "
                "comparison runs the same campaign on every engine)"
            )
    return value


def _seeds(loaded: list[SoakReport]) -> dict[str, dict[int, int]]:
    """Engine -> seed -> index in its report's sessions; every engine the same seeds, none twice
    (``Sim2SimError`` naming the file and field where not)."""
    seeds: dict[str, dict[int, int]] = {}
    for r in loaded:
        sessions = r.get(("sessions",), "a list of sessions", lambda v: isinstance(v, list))
        by_seed: dict[int, int] = {}
        for i in range(len(sessions)):
            seed = r.count(("sessions", i, "seed"))
            if seed in by_seed:
                raise Sim2SimError(
                    f"{r.path}: field 'sessions[{i}].seed': expected a seed no other session "
                    f"has, got {seed} (also sessions[{by_seed[seed]}])"
                )
            by_seed[seed] = i
        seeds[r.engine] = by_seed
    first = loaded[0]
    ordered = sorted(seeds[first.engine])
    if not ordered:
        raise Sim2SimError(f"{first.path}: field 'sessions': expected one session or more, got []")
    for r in loaded[1:]:
        if sorted(seeds[r.engine]) != ordered:
            raise Sim2SimError(
                f"{r.path}: field 'sessions[].seed': expected the seeds {ordered} as in "
                f"{first.engine}'s report {first.path}, got {sorted(seeds[r.engine])}"
            )
    return seeds


def _session_row(loaded: list[SoakReport], seeds: dict, seed: int, legged: bool) -> dict:
    """One seed's row: ``{seed, ids {engine: session id}, figures [figure]}``."""
    per_engine, ids = {}, {}
    for r in loaded:
        i = seeds[r.engine][seed]
        per_engine[r.engine] = read_figures(r, ("sessions", i), legged, totals=False)
        ids[r.engine] = r.get(("sessions", i, "id"), "a session id", lambda v: isinstance(v, str))
    return {"seed": seed, "ids": ids, "figures": _figure_table(per_engine)}


def _flagged(totals: list[dict], session_rows: list[dict]) -> list[dict]:
    """The engine-dependent figures, in totals then seed by seed: ``{figure, label, where,
    reason}``."""
    rows = [("totals", totals)] + [(f"seed {row['seed']}", row["figures"]) for row in session_rows]
    return [
        {"figure": f["name"], "label": f["label"], "where": where, "reason": f["reason"]}
        for where, figures in rows
        for f in figures
        if f["engine_dependent"]
    ]
