"""A camera policy's soak verdict in report.html: the ``camera verdict`` table
(:func:`camera_table`), one row per session with a camera, from report.json's
``sessions[].camera.verdict`` (:meth:`sim2real.eval.soak.camera_verdict.CameraVerdict.section`):
its cameras (several: each one, the verdict being the session's), the frames the per-frame
faults hit, the camera faults it survived (met, no stop), those after which it stopped safely
(its stale-camera stops by fault), its latches after a camera fault and how many ran again
after the operator's reset, and its failures by the camera fault before them. The console's
lines say the same (:func:`sim2real.eval.report.summary.verdict_lines`)."""

from __future__ import annotations

from collections.abc import Callable

#: The verdict's per-frame fault keys in words (``CameraVerdict.section``'s ``frames``).
NAMES = {"frozen": "frozen frames", "dropped": "dropped frames", "late": "late frames"}
#: The table's columns.
HEADER = [
    "session",
    "camera",
    "frames hit (frozen / dropped / late; frozen spells)",
    "survived (no stop)",
    "stopped safely after (stale-camera stops)",
    "stale-camera stops by fault",
    "latched after a camera fault: count, running again (operator reset s)",
    "failures by the camera fault before them",
]


def _counts(counts: dict) -> str:
    """``{label: n}`` as ``label n, ...`` (sorted), ``none`` when empty."""
    return ", ".join(f"{k} {n}" for k, n in sorted(counts.items()) if n) or "none"


def _row(s: dict) -> list:
    c, v = s["camera"], s["camera"]["verdict"]
    fr, latched = v["frames"], v["latched_after_camera"]
    failures = [
        f"{name.replace('_', ' ')} {sum(counts.values())} ({_counts(counts)})"
        for name, counts in v["failures"]["counts"].items()
        if sum(counts.values())
    ]
    return [
        s["id"],
        "; ".join(  # several cameras: each one's section under ``cameras``
            f"{cam['camera']} ({cam.get('kind', 'depth')}) {cam['rate_hz']:g} Hz"
            for cam in (c.get("cameras") or {None: c}).values()
        ),
        f"{fr['frozen']} / {fr['dropped']} / {fr['late']}; {fr['frozen_spells']}",
        ", ".join(NAMES.get(k, k) for k in v["survived"]) or "none",
        ", ".join(f"{NAMES[k]} {n}" for k, n in v["stopped_safely"].items()) or "none",
        f"{v['stops']['count']}: {_counts(v['stops']['by_fault'])}",
        f"{latched['count']}, {latched['ran_again']} ({latched['operator_reset_s']:g} s)",
        "; ".join(failures) or "none",
    ]


def camera_table(report: dict, table: Callable[[list[str], list[list]], dict]) -> dict | None:
    """The camera verdict as a table (``table(header, rows)``: report.html's), a row per session
    whose result has a camera verdict; None when no session has one (no camera policy)."""
    rows = [_row(s) for s in report["sessions"] if (s.get("camera") or {}).get("verdict")]
    return table(HEADER, rows) if rows else None
