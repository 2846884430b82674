"""Sim-to-sim reports: one engine's soak ``report.json``, read and checked field by field.

:class:`SoakReport` loads the report of one soak output folder (:mod:`sim2real.eval.report.build`) and
gives typed access to its fields; :func:`read_figures` extracts the figures that
:mod:`sim2real.eval.sim2sim.compare` judges, of one session or of the totals, as :class:`FigureValue`
(:data:`FIGURE_FIELDS` names the report.json field each is read from). :func:`report_info`
summarises a report (its path, declared engine, pass/fail and failed checks) and
:func:`option_warnings` lists what differs between the reports without preventing the
comparison (session options, engines declared twice or under another name).

Units of the figures: goals reached and tracking success in % (of goals, of RUNNING time),
guard interventions in % of ticks, peak winding temperature in degC, mean forward speed in m/s,
the rest counts (violations in ticks).

Errors: :class:`Sim2SimError` (a ``ValueError``) names the file, the field and the value expected:
a missing or unreadable report.json, another schema version, a field missing or of the wrong
type.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sim2real.eval.report.schema import SCHEMA_VERSION, ReportError

#: The report.json field of each figure: ``sessions[i].FIELD`` per session; the totals read
#: ``totals.FIELD`` where the report has one, else the sum over the sessions.
FIGURE_FIELDS = {
    "goals_reached": "goals.success_rate, goals.reached, goals.issued (arm)",
    "tracking_success": "locomotion.tracking_success (legged)",
    "falls": "locomotion.falls (legged)",
    "mean_speed": "locomotion.mean_forward_speed_m_s (legged)",
    "violations.<type>": "violations.total.<type> (hard_limit, soft_limit, velocity, effort, "
    "workspace, self_collision)",
    "interventions": "interventions.any.fraction",
    "peak_winding": "thermal.peak_c (max over the joints)",
    "safe_stops": "runtime.safe_stops, runtime.by_cause (totals: summed over the sessions)",
    "latched_faults": "runtime.latched_faults (totals: totals.latched_faults)",
    "diverged": "diverged (message or null; totals: totals.diverged, the ids)",
}

#: Labels of the violation types (sim2real.deploy.monitors.violations), in the order of the report.
VIOLATION_LABELS = {
    "hard_limit": "hard-limit violations",
    "soft_limit": "soft-limit violations",
    "velocity": "velocity violations",
    "effort": "effort (torque) violations",
    "workspace": "workspace violations",
    "self_collision": "self-collision violations",
}


class Sim2SimError(ReportError):
    """Reports that cannot be compared; the message names the file, the field and the value
    expected."""


# ---------------------------------------------------------------------- reading


def _dotted(keys: tuple) -> str:
    out = ""
    for k in keys:
        out += f"[{k}]" if isinstance(k, int) else (f".{k}" if out else str(k))
    return out


def is_number(v: Any) -> bool:
    """Whether ``v`` is a finite int or float (a bool is not a number here)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _is_count(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


class SoakReport:
    """One engine's report.json with typed field access (errors name the file and field).

    Attributes:
        engine: The engine name the report is compared under (a column label).
        folder: The soak output folder.
        path: ``folder / "report.json"``.
        doc: The parsed report (a dict whose ``schema_version`` is the current one).

    Raises:
        Sim2SimError: ``folder`` is a file; no report.json in it, or one that cannot be read, is
            not JSON, not a JSON object, or of another schema version.
    """

    def __init__(self, engine: str, folder: Path):
        self.engine = engine
        self.folder = folder
        self.path = folder / "report.json"
        if folder.exists() and not folder.is_dir():
            raise Sim2SimError(f"{folder}: expected a soak output folder (with report.json)")
        try:
            self.doc = json.loads(self.path.read_text())
        except FileNotFoundError:
            raise Sim2SimError(
                f"{self.path}: no report.json (expected the soak output of engine {engine!r}: "
                f"soak-test --engine {engine} --out {folder})"
            ) from None
        except OSError as exc:
            raise Sim2SimError(f"{self.path}: cannot read the report: {exc}") from None
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise Sim2SimError(f"{self.path}: not valid JSON: {exc}") from None
        if not isinstance(self.doc, dict):
            raise Sim2SimError(f"{self.path}: expected a JSON object (a soak report.json)")
        version = self.doc.get("schema_version")
        if version != SCHEMA_VERSION:
            raise Sim2SimError(
                f"{self.path}: field 'schema_version': expected {SCHEMA_VERSION}, got {version!r}"
            )

    def get(self, keys: tuple, expected: str, ok: Callable[[Any], bool]) -> Any:
        """The field at ``keys`` (object keys as str, list indices as int), checked by ``ok``.

        Raises:
            Sim2SimError: a container on the way is not an object (str key) or a list (int
                index), a key or index is missing, or ``ok`` rejects the value; the message
                names the field and says ``expected``.
        """
        node = self.doc
        for i, k in enumerate(keys):
            container_ok = isinstance(node, list) if isinstance(k, int) else isinstance(node, dict)
            if not container_ok:
                kind = "a list" if isinstance(k, int) else "an object"
                raise Sim2SimError(
                    f"{self.path}: field '{_dotted(keys[:i]) or '(top)'}': expected {kind}, "
                    f"got {node!r:.80}"
                )
            if (isinstance(k, int) and not 0 <= k < len(node)) or (
                not isinstance(k, int) and k not in node
            ):
                raise Sim2SimError(
                    f"{self.path}: field '{_dotted(keys[: i + 1])}' is missing (expected "
                    f"{expected if i == len(keys) - 1 else 'it in a soak report.json'})"
                )
            node = node[k]
        if not ok(node):
            raise Sim2SimError(
                f"{self.path}: field '{_dotted(keys)}': expected {expected}, got {node!r:.80}"
            )
        return node

    def number(
        self, keys: tuple, low: float | None = 0.0, high: float | None = None, null=False
    ) -> float | None:
        """A finite number in [low, high] (a bound None: none), or None when ``null``."""
        if low is not None and high is not None:
            span = f" in [{low:g}, {high:g}]"
        elif low is not None or high is not None:
            span = f" >= {low:g}" if low is not None else f" <= {high:g}"
        else:
            span = ""
        expected = f"a number{span}" + (" or null" if null else "")
        return self.get(
            keys,
            expected,
            lambda v: (
                (null and v is None)
                or (is_number(v) and (low is None or v >= low) and (high is None or v <= high))
            ),
        )

    def count(self, keys: tuple) -> int:
        """An integer >= 0 (a bool is refused)."""
        return self.get(keys, "an integer >= 0", _is_count)

    def counts(self, keys: tuple) -> dict[str, int]:
        """An object of name: integer >= 0 (may be empty)."""
        return self.get(
            keys,
            "an object of integers >= 0",
            lambda v: isinstance(v, dict) and all(_is_count(x) for x in v.values()),
        )

    def temperatures(self, keys: tuple) -> dict[str, float]:
        """An object of joint: temperature (degC, finite), one joint at least."""
        return self.get(
            keys,
            "an object of joint: degC (finite numbers), one joint at least",
            lambda v: isinstance(v, dict) and v and all(is_number(x) for x in v.values()),
        )


# ---------------------------------------------------------------------- figures


@dataclass(frozen=True)
class FigureValue:
    """One engine's value of a figure: the number (None: undefined), a note for the reader (e.g.
    ``"12/13"``), and counts by kind that the figure's rule judges too (safe stops by cause)."""

    value: float | None
    note: str | None = None
    breakdown: dict[str, int] | None = None


def read_figures(r: SoakReport, base: tuple, legged: bool, totals: bool) -> dict[str, FigureValue]:
    """The figures of one session (``base`` = ("sessions", i)) or of the totals (("totals",)).

    Args:
        r: The report.
        base: The keys of the session or of the totals in the report.
        legged: A legged robot's figures (tracking success, falls, mean forward speed) instead
            of an arm's (goals reached).
        totals: Read the totals: safe stops and their causes summed over the sessions, latched
            faults and diverged sessions from ``totals``.

    Returns:
        Figure name (as in :data:`FIGURE_FIELDS`, violations as ``violations.<type>`` for the
        types the report has, in :data:`VIOLATION_LABELS` order, then others sorted) -> value, in
        the units of the module docstring. Notes: goals ``"reached/issued"``, peak winding the
        hottest joint, safe stops the causes used; safe stops carry their counts by cause.

    Raises:
        Sim2SimError: a field missing or of the wrong type.
    """
    out: dict[str, FigureValue] = {}
    if legged:
        loco = base + ("locomotion",)
        ts = r.number(loco + ("tracking_success",), 0.0, 1.0, null=True)
        out["tracking_success"] = FigureValue(None if ts is None else 100.0 * ts)
        out["falls"] = FigureValue(r.count(loco + ("falls",)))
        speed = r.number(loco + ("mean_forward_speed_m_s",), None, null=True)
        out["mean_speed"] = FigureValue(speed)
    else:
        goals = base + ("goals",)
        rate = r.number(goals + ("success_rate",), 0.0, 1.0, null=True)
        reached, issued = r.count(goals + ("reached",)), r.count(goals + ("issued",))
        out["goals_reached"] = FigureValue(
            None if rate is None else 100.0 * rate, f"{reached}/{issued}"
        )
    violations = r.counts(base + ("violations", "total"))
    for kind in (*VIOLATION_LABELS, *sorted(set(violations) - set(VIOLATION_LABELS))):
        if kind in violations:
            out[f"violations.{kind}"] = FigureValue(violations[kind])
    fraction = r.number(base + ("interventions", "any", "fraction"), 0.0, 1.0)
    out["interventions"] = FigureValue(100.0 * fraction)
    peaks = r.temperatures(base + ("thermal", "peak_c"))
    joint = max(peaks, key=peaks.get)
    out["peak_winding"] = FigureValue(float(peaks[joint]), joint)
    if totals:
        n = len(r.get(("sessions",), "a list of sessions", lambda v: isinstance(v, list)))
        stops, causes = 0, {}
        for i in range(n):
            stops += r.count(("sessions", i, "runtime", "safe_stops"))
            for cause, k in r.counts(("sessions", i, "runtime", "by_cause")).items():
                causes[cause] = causes.get(cause, 0) + k
        latched = r.count(("totals", "latched_faults"))
        diverged = len(
            r.get(("totals", "diverged"), "a list of session ids", lambda v: isinstance(v, list))
        )
    else:
        stops = r.count(base + ("runtime", "safe_stops"))
        causes = r.counts(base + ("runtime", "by_cause"))
        latched = r.count(base + ("runtime", "latched_faults"))
        message = r.get(
            base + ("diverged",),
            "null or a message",
            lambda v: v is None or isinstance(v, str),
        )
        diverged = int(message is not None)
    used = {c: k for c, k in causes.items() if k}
    note = ", ".join(f"{c} {k}" for c, k in used.items()) or None
    out["safe_stops"] = FigureValue(stops, note, dict(causes))
    out["latched_faults"] = FigureValue(latched)
    out["diverged"] = FigureValue(diverged)
    return out


# ---------------------------------------------------------------------- about the reports


def declared_engine(doc: dict) -> str | None:
    """The engine a report says it ran on: its top-level ``engine``, else ``campaign.engine``
    (None: neither, a report written before ``soak-test --engine``)."""
    engine = doc.get("engine")
    if engine is None and isinstance(doc.get("campaign"), dict):
        engine = doc["campaign"].get("engine")
    return engine if isinstance(engine, str) else None


def report_info(r: SoakReport) -> dict:
    """What the comparison says of one report: ``{path (str), engine (declared, or None), passed
    and exit_code (as the report has them, or None), failed_checks [names, sorted]}``."""
    checks = r.doc.get("checks")
    failed = (
        sorted(k for k, c in checks.items() if isinstance(c, dict) and not c.get("passed", True))
        if isinstance(checks, dict)
        else []
    )
    return {
        "path": str(r.path),
        "engine": declared_engine(r.doc),
        "passed": r.doc.get("passed"),
        "exit_code": r.doc.get("exit_code"),
        "failed_checks": failed,
    }


def option_warnings(loaded: list[SoakReport]) -> list[str]:
    """What does not prevent the comparison but may explain a gap: options that differ between
    the campaigns (an engine option excepted), and reports that name the same engine.

    Args:
        loaded: The reports; the first is the one the others are compared with.

    Returns:
        One message per difference: each ``campaign.session_options`` key that differs from the
        first report's, each report whose declared engine is not its name, and each engine that
        several reports declare. Each report's ``campaign`` must be an object (as
        :func:`sim2real.eval.sim2sim.compare.compare` checks first); ``session_options`` may be missing.
    """
    out = []
    first = loaded[0]

    def options(r: SoakReport) -> dict:
        opts = (r.doc.get("campaign") or {}).get("session_options") or {}
        return (
            {k: v for k, v in opts.items() if "engine" not in k} if isinstance(opts, dict) else {}
        )

    base = options(first)
    for r in loaded[1:]:
        other = options(r)
        for key in sorted(set(base) | set(other)):
            if base.get(key) != other.get(key):
                out.append(
                    f"campaign.session_options.{key} differs: {first.engine} "
                    f"{base.get(key)!r:.60}, {r.engine} {other.get(key)!r:.60} (a gap may come "
                    "from the option, not the engine)"
                )
    declared: dict[str, list[str]] = {}
    for r in loaded:
        engine = declared_engine(r.doc)
        if engine is not None:
            declared.setdefault(engine, []).append(r.engine)
            if engine != r.engine:
                out.append(f"{r.path}: the report's engine is {engine!r}, compared as {r.engine!r}")
    for engine, names in declared.items():
        if len(names) > 1:
            out.append(
                f"the reports of {', '.join(names)} were all run on engine {engine!r}: their "
                "gaps are not an engine's"
            )
    return out
