"""The junit.xml of a soak report: one testcase per session and check, one for the baseline
comparison.

A failed check names the still frame of the session's first film clip showing why it failed
(``still frame: film/<id>/NN-<kind>.png``, also as a ``[[ATTACHMENT|...]]`` line in the
testcase's system-out; :mod:`sim2real.eval.film.strip`).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

from sim2real.eval.report.schema import CHECKS
from sim2real.robots.files import atomic_write


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


#: The film's moments that show why a check failed (sim2real.eval.film.strip.KINDS).
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
