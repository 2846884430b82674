"""The report.html of a soak campaign, rendered from Jinja2 templates (``sim2real/eval/templates/``).

:func:`report_html` gathers what the page shows (the campaign, the checks, the baseline
comparison, per-session tables, the plots of :mod:`sim2real.eval.report.plots`, the film strip) and renders
``templates/report.html``; :func:`film_html` renders the film strip's section
(``templates/film.html``). The templates are autoescaped: every string from a report (robot and
policy names, session ids, messages, paths) is escaped.

The HTML is self-contained (plots are matplotlib PNGs embedded as base64; no scripts, no external
resources), and so is the film strip: each session's clips (H.264 MP4 in ``<video>``, the still at
the moment as its poster) embedded as base64 from ``film/<id>/`` beside the report (at most
``sim2real.eval.film.strip.MAX_CLIPS`` short clips per session).
"""

from __future__ import annotations

import base64
import functools
import os
from pathlib import Path

import jinja2

from sim2real.eval.report.camera_table import camera_table
from sim2real.eval.report.domain_account import domain_table
from sim2real.eval.report.plots import (
    plot_interventions,
    plot_robustness,
    plot_success,
    plot_temperatures,
    plot_tick_cost,
    plot_violations,
    plot_windows,
)
from sim2real.eval.report.schema import CHECKS
from sim2real.robots.files import atomic_write

#: The plots of report.html, in order: (title, function returning a base64 PNG).
PLOTS = (
    ("Winding temperature", plot_temperatures),
    ("Violations (true state) per hour", plot_violations),
    ("Interventions per hour", plot_interventions),
    ("Success over time", plot_success),
    ("Success per window", plot_windows),
    ("Tick cost", plot_tick_cost),
    ("Robustness sweep: success per level of each quantity", plot_robustness),
)


def _fmt(value) -> str:
    """A table cell's text: ``-`` for None, floats to 4 significant digits, lists joined."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(_fmt(v) for v in value)
    return str(value)


@functools.cache
def _environment() -> jinja2.Environment:
    """The templates' environment: the package's ``templates`` folder (found in an installed
    package too), autoescaped, undefined names an error."""
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("sim2real.eval", "templates"),
        autoescape=True,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )
    env.filters["fmt"] = _fmt
    return env


def _render(name: str, **context) -> str:
    return _environment().get_template(name).render(**context)


def _table(header: list[str], rows: list[list]) -> dict:
    """A table for the templates' ``table`` macro (cells are formatted by ``_fmt``)."""
    return {"header": header, "rows": rows}


def _data_uri(base: Path | None, rel: str, mime: str) -> str:
    """``data:`` URI of file ``base/rel``, or the relative path where it cannot be read."""
    if base is not None:
        try:
            data = (base / rel).read_bytes()
        except OSError:
            return rel
        return f"data:{mime};base64,{base64.b64encode(data).decode('ascii')}"
    return rel


def film_html(report: dict, base: Path | None = None) -> str:
    """The film strip section: per session, its clips as ``<video>`` elements (embedded from
    ``base``, the report's folder; relative links without it), each captioned with its moments,
    the replayed span and whether the replay matched the run bit for bit; ``""`` when no session
    has a film."""
    sessions = []
    for s in report["sessions"]:
        f = s.get("film")
        if f is None:
            continue
        clips = [
            {
                "kind": c["kind"],
                "label": c["label"],
                "start_s": c["start_s"],
                "end_s": c["end_s"],
                "exact": {True: "replay exact", False: "REPLAY DIFFERS from the run", None: ""}[
                    c.get("replay_exact")
                ],
                "video": _data_uri(base, c["video"], "video/mp4"),
                "poster": _data_uri(base, c["still"], "image/png"),
                "still": c["still"],
            }
            for c in ([] if f.get("error") else f["clips"])
        ]
        sessions.append(
            {
                "id": s["id"],
                "error": f.get("error"),
                "clips": clips,
                "width": f["size"][0] if clips else None,
                "height": f["size"][1] if clips else None,
                "not_filmed": f.get("not_filmed"),
                "max_clips": f.get("max_clips"),
            }
        )
    if not sessions:
        return ""
    return _render("film.html", sessions=sessions).removesuffix("\n")


def _velocity(loco: dict, key: str):
    """A legged session's velocity-tracking figure ``key``, or a word saying a motion clip
    commanded it (the figure then means nothing, :func:`sim2real.eval.soak.result.
    locomotion_result`'s ``commanded_by``)."""
    return "n/a (a clip)" if loco.get("commanded_by") == "clip" else loco[key]


def _success_cells(s: dict) -> list:
    """A session's success rate, lowest window success and missed goals; a legged session's
    tracking success, lowest window tracking success and falls."""
    loco = s.get("locomotion")
    if loco is not None:
        return [
            _velocity(loco, "tracking_success"),
            _velocity(loco, "min_window_success_rate"),
            loco["falls"],
        ]
    g = s["goals"]
    return [g["success_rate"], g["min_window_success_rate"], len(g["missed"]) + g["missed_dropped"]]


def _tables(report: dict) -> dict[str, dict]:
    """The tables of report.html (campaign, checks, baseline, sessions, interventions, faults,
    locomotion, wheels, robustness, randomization, camera verdict) as ``{"header", "rows"}``; a
    table whose content the report lacks (no baseline, no wheels, no sweep, no camera) is left
    out."""
    built = {name: make(report) for name, make in _TABLES.items()}
    return {name: table for name, table in built.items() if table is not None}


def _campaign_table(report: dict) -> dict:
    from sim2real.eval.world.command_schedule import schedule_text

    c, t = report["campaign"], report["totals"]
    schedule = c.get("commands")  # a legged robot's command schedule and its sources
    return _table(
        ["robot", "policy", "sessions", "hours each", "seed", "simulated h", "created"]
        + (["velocity commands"] if schedule else []),
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
            + ([schedule_text(schedule)] if schedule else [])
        ],
    )


def _checks_table(report: dict) -> dict:
    return _table(
        ["session", *CHECKS],
        [
            [s["id"]]
            + [
                ("pass: " if s["checks"][n]["passed"] else "FAIL: ") + s["checks"][n]["message"]
                for n in CHECKS
            ]
            for s in report["sessions"]
        ],
    )


def _baseline_table(report: dict) -> dict | None:
    b = report.get("baseline")
    if b is None:
        return None
    return _table(
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


def _sessions_table(report: dict) -> dict:
    return _table(
        [
            "session",
            "status",
            "simulated h",
            "hard-limit violations (true, ticks)",
            "violations/h (true, all types)",
            "interventions (% of ticks)",
            "success rate (legged: tracking)",
            "lowest window success",
            "missed goals (legged: falls)",
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
                *_success_cells(s),
                s["faults"]["injected"],
                s["faults"]["survived"],
                s["runtime"]["latched_faults"],
                max(s["thermal"]["peak_c"].values()),
                s["wall"]["speed"],
            ]
            for s in report["sessions"]
        ],
    )


def _interventions_table(report: dict) -> dict:
    t = report["totals"]
    checks = list(t["interventions"]["checks"])
    return _table(
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


def _faults_table(report: dict) -> dict:
    return _table(
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


def _locomotion_table(report: dict) -> dict:
    legged = [s for s in report["sessions"] if s.get("locomotion") is not None]
    return _table(
        [
            "session",
            "falls",
            "falls/h",
            "falls began (runtime stop, push, fault; replays: policy, runtime, rare draw, "
            "undecided)",
            "tracking success (within 0.2 m/s)",
            "yaw-rate tracking (within 0.2 rad/s)",
            "lowest window tracking",
            "distance (m)",
            "mean forward speed (m/s)",
            "RUNNING (s)",
            "commands",
            "floor friction",
            "peak winding degC (hip, thigh, calf)",
        ],
        [
            [
                s["id"],
                s["locomotion"]["falls"],
                s["locomotion"]["falls_per_hour"],
                list(s["locomotion"].get("falls_by_origin", {}).values()),
                _velocity(s["locomotion"], "tracking_success"),
                (
                    _velocity(s["locomotion"], "yaw_tracking_success")
                    if "yaw_tracking_success" in s["locomotion"]
                    else None
                ),
                _velocity(s["locomotion"], "min_window_success_rate"),
                s["locomotion"]["distance_m"],
                _velocity(s["locomotion"], "mean_forward_speed_m_s"),
                s["locomotion"]["running_s"],
                s["locomotion"]["commands_issued"],
                s["randomization"].get("floor_friction"),
                list(s["locomotion"]["peak_winding_c"].values()),
            ]
            for s in legged
        ],
    )


def _wheels_table(report: dict) -> dict | None:
    wheeled = [s for s in report["sessions"] if (s.get("wheels") or {}).get("joints")]
    if not wheeled:
        return None
    joints = wheeled[0]["wheels"]["joints"]
    return _table(
        ["session", *(f"{j} peak / limit (rad/s)" for j in joints)],
        [
            [s["id"]]
            + [f"{w['peak_speed_rad_s'][j]:.1f} / {w['velocity_limit_rad_s'][j]:g}" for j in joints]
            for s in wheeled
            for w in [s["wheels"]]
        ],
    )


def _robustness_table(report: dict) -> dict | None:
    sweep = report.get("robustness")
    if sweep is None:
        return None
    from sim2real.eval.soak.sweep import margin_text

    return _table(
        ["quantity", "margin", "first level that failed", "levels (success, falls)"],
        [
            [
                row["label"],
                margin_text(row),
                row["failed_at"],
                "; ".join(
                    f"{lv['level']:g}: {_fmt(lv['success'])}, {lv['falls']}" for lv in row["levels"]
                ),
            ]
            for row in sweep["quantities"]
        ],
    )


#: report.html's tables in page order, each built from the report by its function.
_TABLES = {
    "campaign": _campaign_table,
    "training domain": lambda report: domain_table(report, _table),
    "checks": _checks_table,
    "baseline": _baseline_table,
    "sessions": _sessions_table,
    "interventions": _interventions_table,
    "faults": _faults_table,
    "locomotion": _locomotion_table,
    "wheels": _wheels_table,
    "robustness": _robustness_table,
    "randomization": lambda report: randomization_table(report["sessions"]),
    "camera": lambda report: camera_table(report, _table),
}


def randomization_table(sessions: list[dict]) -> dict:
    """The sessions' drawn randomization as a table: dynamics factors, encoder settings, friction
    rise, and a training domain's draws (added base mass, largest encoder bias, centre-of-mass
    offset) as columns only where a session drew them."""
    # a training domain's draws, as columns only where a session drew them
    extra = [
        (header, key, cell)
        for header, key, cell in (
            ("added base mass (kg)", "added_base_mass", lambda v: v),
            ("encoder bias, largest |b| (rad)", "encoder_bias", lambda v: max(map(abs, v))),
            (
                "centre of mass offset (m)",
                "com_offset",
                lambda v: f"{v['body']}: {_fmt(v['offset_m'])}",
            ),
        )
        if any(s["randomization"].get(key) is not None for s in sessions)
    ]

    def drawn(s: dict) -> list:
        r = s["randomization"]
        return [None if r.get(key) is None else cell(r[key]) for _, key, cell in extra]

    return _table(
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
            *[header for header, _, _ in extra],
        ],
        [
            [
                s["id"],
                s["randomization"]["dynamics"]["link_length"],
                s["randomization"]["dynamics"]["mass"],
                s["randomization"]["dynamics"]["friction"],
                s["randomization"]["dynamics"]["damping"],
                s["randomization"]["dynamics"]["actuator_strength"],
                s["randomization"]["sensors"]["noise_sigma"],
                s["randomization"]["sensors"]["latency_ticks"],
                s["randomization"]["sensors"]["dropout_probability"],
                s["randomization"]["drift"]["friction_rate"],
                *drawn(s),
            ]
            for s in sessions
        ],
    )


def report_html(report: dict, base: str | os.PathLike | None = None) -> str:
    """The self-contained report.html text; ``base``: the report's folder, from which the film
    strip's clips are embedded (module docstring)."""
    b = report.get("baseline")
    return _render(
        "report.html",
        robot=str(report["campaign"].get("robot")),
        verdict="PASSED" if report["passed"] else "FAILED",
        passed=report["passed"],
        failed_checks=[
            f"{name} ({', '.join(c['failed_sessions'])})"
            for name, c in report["checks"].items()
            if not c["passed"]
        ],
        tables=_tables(report),
        film=film_html(report, Path(base) if base is not None else None),
        baseline=None
        if b is None
        else {
            "passed": b["passed"],
            "path": str(b["path"]),
            "known_failures": [k["message"] for k in b.get("known_failures", [])],
        },
        plots=[(title, img) for title, plot in PLOTS if (img := plot(report))],
    )


def write_html(path: str | os.PathLike, report: dict) -> Path:
    """Write report.html atomically (the film strip embedded from the report's folder)."""
    return atomic_write(path, report_html(report, Path(path).parent))
