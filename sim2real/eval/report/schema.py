"""The vocabulary of a soak report.json: its schema version, its checks, its thresholds, its
error, and reading one back.

The layout of report.json is described in :mod:`sim2real.eval.report.build`, which builds it. A report is
read back (:func:`load_report`, e.g. as a baseline) only if it is of schema ``SCHEMA_VERSION`` and
has every field the baseline comparison reads (:func:`check_schema`; :mod:`sim2real.eval.report.baseline`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

from sim2real.robots.errors import Sim2RealError

SCHEMA_VERSION = 2
CHECKS = (
    "no_hard_violation",
    "no_latched_fault",
    "no_over_temperature",
    "success_rate",
    "window_success",
    "interventions",
    "no_divergence",
    "falls",
    "on_spot",
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
        max_falls_per_hour: Most falls per simulated hour of a legged session that pass (0:
            every fall fails, our choice: a fall on hardware is damage). The success thresholds
            apply to a legged session's tracking success (share of RUNNING time within 0.2 m/s
            of the velocity command) only with ``judge_tracking``.
        judge_tracking: Judge a legged session's tracking success against the success
            thresholds (``soak-test --min-success`` or ``--min-window-success`` given). False
            (the default): the tracking is reported, not judged: how closely a walking policy
            follows every command of its training ranges is the policy's quality, which its
            training measured, not a property of the deployment (a published G1 policy stands
            still at one lateral command in a bare MuJoCo loop too); a baseline still judges a
            drop of it as a regression.

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
    max_falls_per_hour: float = 0.0
    judge_tracking: bool = False

    def __post_init__(self):
        for name, value in asdict(self).items():
            if name == "judge_tracking":
                continue
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ReportError(f"thresholds: {name}: expected a number >= 0, got {value!r}")
        for name in ("min_success_rate", "min_window_success_rate", "max_intervention_rate"):
            if getattr(self, name) > 1:
                raise ReportError(
                    f"thresholds: {name}: expected a value in [0, 1], got {getattr(self, name)}"
                )


#: Fields of report.json the baseline comparison reads.
BASELINE_FIELDS = (
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


def check_schema(doc: dict, where: str) -> None:
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
    for field_path in BASELINE_FIELDS:
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
    check_schema(doc, str(path))
    return doc
