"""Soak reports: report.json built from the sessions' results, its checks, and the files written.

:func:`build_report` makes the report.json document (its layout is in its docstring; a
**violation** is the robot's true state past a limit, an **intervention** a command the guard or
the smoother changed: they are reported apart); :func:`write_reports` writes report.json,
report.html (:mod:`sim2real.eval.report.html`) and junit.xml (:mod:`sim2real.eval.report.junit`), each
atomically. The campaign totals are :mod:`sim2real.eval.report.totals`, the console lines
:mod:`sim2real.eval.report.summary`, the comparison with a baseline :mod:`sim2real.eval.report.baseline`, and
the report's vocabulary (``SCHEMA_VERSION``, ``CHECKS``, ``Thresholds``, ``ReportError``, ``load_report``)
:mod:`sim2real.eval.report.schema`.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path

from sim2real.eval.report.baseline import compare_with_baseline
from sim2real.eval.report.html import write_html
from sim2real.eval.report.junit import write_junit
from sim2real.eval.report.schema import CHECKS, SCHEMA_VERSION, ReportError, Thresholds
from sim2real.eval.report.totals import totals
from sim2real.robots.files import atomic_write

#: The success checks' message for a session a motion clip commands: its velocity tracking
#: means nothing (its tracking: the result's ``exhibition`` section).
CLIP_NOT_JUDGED = (
    "not judged: a motion clip commands the policy, not a velocity (its tracking: the "
    "exhibition section)"
)


def session_checks(result: dict, thresholds: Thresholds) -> dict[str, dict]:
    """The checks of one session result: ``{name: {"passed": bool, "message": str}}``.

    ``no_hard_violation`` (no true-state hard-limit violation, standing or lying down after a
    stop, and no hard-limit safe stop of the runtime), ``no_latched_fault`` (a latch whose
    ``injected`` names the injected fault that stopped the robot, a camera's
    (:mod:`sim2real.eval.soak.camera_verdict`), is counted in the message, not failed),
    ``no_over_temperature`` (a winding above its maximum, or an over-temperature safe stop),
    ``success_rate`` (at least ``min_success_rate`` over the session), ``window_success`` (at
    least ``min_window_success_rate`` in every window of ``window_minutes`` with a goal),
    ``interventions`` (ticks with an intervention at most ``max_intervention_rate`` of the
    ticks; a legged robot's position targets clamped into its soft limits are its policy's style:
    reported in the message, not judged), ``no_divergence``, ``falls`` (a legged session: at
    most ``max_falls_per_hour`` and no ``false_fall_stops``; an arm passes). For a legged
    session the success checks are its tracking success (``locomotion``), judged only with
    ``thresholds.judge_tracking`` (else they pass and say "not judged"); a session a motion clip
    commands has no velocity tracking: they pass, not judged (:data:`CLIP_NOT_JUDGED`).
    """
    latches = result["runtime"]["latches"]
    safely = [x for x in latches if x.get("injected")]  # a stop an injected fault was to cause
    latched = len(latches) - len(safely)
    th = result["thermal"]
    hot = [j for j in th["joints"] if th["peak_c"][j] > th["max_winding_c"][j]]
    thermal_stops = result["runtime"]["by_cause"].get("over_temperature", 0)
    causes = sorted({x["cause"] for x in latches if x.get("cause") and not x.get("injected")})
    loco = result.get("locomotion")
    if loco is not None:  # a legged session: its success is the tracking success
        success, window, falls = _tracking_checks(loco, thresholds)
    else:
        success, window = _goal_checks(result["goals"], thresholds)
        falls = (True, "fixed base: no falls")
    checks = {
        "no_hard_violation": _hard_limit_check(result),
        "no_latched_fault": (
            latched == 0,
            (f"{latched} latched faults ({', '.join(causes)})" if latched else "no latched fault")
            + (
                f"; {len(safely)} more after an injected camera fault stopped it safely "
                "(not failed)"
                if safely
                else ""
            ),
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
        "success_rate": success,
        "window_success": window,
        "falls": falls,
        "interventions": _interventions_check(result["interventions"], thresholds),
        "no_divergence": (
            not result["diverged"],
            f"simulation diverged: {result['diverged']}" if result["diverged"] else "no divergence",
        ),
        "on_spot": on_spot_check(result),
    }
    return {k: {"passed": bool(p), "message": m} for k, (p, m) in checks.items()}


def own_loop_checks(result: dict, own: dict, thresholds: Thresholds) -> dict:
    """Judge ``result``'s ``no_hard_violation`` and ``interventions`` (its ``checks``, replaced
    in place) against the own loop ``own`` by :mod:`sim2real.eval.soak.own_loop_limits`'s rule;
    returns the figures of both."""
    from sim2real.eval.soak.own_loop_limits import judge_hard_limits, judge_interventions

    hard = judge_hard_limits(result, own)
    iv = judge_interventions(result, own, thresholds.max_intervention_rate)
    for name, (passed, message, _) in (("no_hard_violation", hard), ("interventions", iv)):
        result["checks"][name] = {"passed": bool(passed), "message": message}
    return {"hard_limits": hard[2], "interventions": iv[2]}


def on_spot_check(result: dict) -> tuple[bool, str]:
    """``on_spot``: an exhibition's base stays where its clips take it: no clip ends, and no
    rest goes, past the bounds of :mod:`sim2real.deploy.tasks.motion.travel` (0.5 m); a session
    no clip commands passes."""
    x = (result.get("exhibition") or {}).get("clips_and_rests")
    if x is None:
        return True, "no motion clip: not judged"
    clips, rests, off = x["clips"], x["rests"], x["left_spot"]
    worst = clips["worst_end_offset_m"]
    text = (
        f"clips: travel {clips['travel_m']:.2f} m, the worst ended "
        + (f"{worst:.2f} m" if worst is not None else "n/a")
        + f" from its root path's end; rests: {rests['count']}, travel {rests['travel_m']:.2f} m"
        + (f" (the worst {rests['worst_travel_m']:.2f} m)" if rests["count"] else "")
    )
    if off:
        return False, f"left its spot in plays {off[:10]}: {text}"
    return True, text


def _hard_limit_check(result: dict) -> tuple[bool, str]:
    """``no_hard_violation``: no tick past a hard limit (true state), standing or lying down,
    and no hard-limit safe stop."""
    hard = result["violations"]["total"].get("hard_limit", 0)
    hard_down = result["violations"].get("while_down", {}).get("hard_limit", 0)
    hard_stops = result["runtime"]["by_cause"].get("hard_limit", 0)
    hard_joints = result["violations"].get("hard_limit_joints") or {}
    joints = ", ".join(f"{j} {t}" for j, t in hard_joints.items())
    return (
        hard == 0 and hard_down == 0 and hard_stops == 0,
        f"{hard} ticks with a joint beyond a hard limit (true state)"
        + (f" (ticks per joint: {joints})" if joints else "")
        + (f" and {hard_down} more lying down after a stop" if hard_down else "")
        + f", {hard_stops} hard-limit safe stops"
        if hard or hard_down or hard_stops
        else "no hard-limit violation (true state), no hard-limit safe stop",
    )


def _tracking_checks(loco: dict, thresholds: Thresholds) -> tuple[tuple, tuple, tuple]:
    """A legged session's ``success_rate``, ``window_success`` and ``falls`` checks, each
    ``(passed, message)``: its tracking success, judged only with ``thresholds.judge_tracking``
    and never for a session a motion clip commands."""
    rate, window = loco["tracking_success"], loco["min_window_success_rate"]
    yaw = loco.get("yaw_tracking_success")  # None: never RUNNING, or a result before it
    # a motion clip commands it: no velocity tracking to judge or report
    clip = loco.get("commanded_by") == "clip"
    judged = thresholds.judge_tracking and not clip
    threshold = f"threshold {thresholds.min_success_rate:.3f}" if judged else "not judged"
    success_message = (CLIP_NOT_JUDGED if clip else None) or (
        f"tracking success {rate:.3f} ({threshold}, "
        f"{loco['tracked_s']:.0f}/{loco['running_s']:.0f} s RUNNING within "
        f"{loco['tracking_tolerance_m_s']:g} m/s of the command"
        + (
            f", {loco['settle_s']:g} s after each change allowed to settle)"
            if loco.get("settle_s")
            else ")"
        )
        + (
            f"; yaw-rate tracking success {yaw:.3f} (within "
            f"{loco['yaw_tracking_tolerance_rad_s']:g} rad/s; judged by the same threshold)"
            if yaw is not None
            else ""
        )
        if rate is not None
        else "never RUNNING"
    )
    least = rate if yaw is None or rate is None else min(rate, yaw)
    window_message = (CLIP_NOT_JUDGED if clip else None) or (
        f"lowest tracking success in a {loco['window_s'] / 60:g}-minute window {window:.3f} "
        + (f"(threshold {thresholds.min_window_success_rate:.3f}, " if judged else "(not judged, ")
        + f"{len(loco['windows'])} windows)"
        if window is not None
        else "never RUNNING"
    )
    false_stops = loco.get("false_fall_stops", 0)
    falls_ok = loco["falls_per_hour"] <= thresholds.max_falls_per_hour and not false_stops
    falls_message = (
        f"{loco['falls']} falls, {loco['falls_per_hour']:.2f} per hour (threshold "
        f"{thresholds.max_falls_per_hour:g}); {false_stops} false fall stops (an upright "
        "robot stopped by the fall check; must be 0)"
    )
    return (
        (
            not judged or (least is not None and least >= thresholds.min_success_rate),
            success_message,
        ),
        (
            not judged or (window is not None and window >= thresholds.min_window_success_rate),
            window_message,
        ),
        (falls_ok, falls_message),
    )


def _goal_checks(goals: dict, thresholds: Thresholds) -> tuple[tuple, tuple]:
    """An arm session's ``success_rate`` and ``window_success`` checks, ``(passed, message)``."""
    rate, window = goals["success_rate"], goals["min_window_success_rate"]
    return (
        (
            rate is not None and rate >= thresholds.min_success_rate,
            f"success rate {rate:.3f} (threshold {thresholds.min_success_rate:.3f}, "
            f"{goals['reached']}/{goals['issued']} goals)"
            if rate is not None
            else "no goal was issued",
        ),
        (
            window is not None and window >= thresholds.min_window_success_rate,
            f"lowest success rate in a {goals['window_s'] / 60:g}-minute window {window:.3f} "
            f"(threshold {thresholds.min_window_success_rate:.3f}, "
            f"{len(goals['windows'])} windows)"
            if window is not None
            else "no goal was issued",
        ),
    )


def _interventions_check(iv: dict, thresholds: Thresholds) -> tuple[bool, str]:
    """``interventions``: the judged share of ticks with an intervention at most
    ``max_intervention_rate``; the policy's style (``by_design``) reported, not judged
    (:mod:`sim2real.deploy.monitors.interventions`)."""
    by_design = iv.get("by_design", [])
    share = iv.get("safety", iv["any"])["fraction"]
    worst = sorted(
        ((c["fraction"], k) for k, c in iv["checks"].items() if c["count"] and k not in by_design),
        reverse=True,
    )[:3]
    style = ", ".join(
        f"{k} {100 * iv['checks'][k]['fraction']:.3f} %" for k in by_design if k in iv["checks"]
    )
    return (
        share <= thresholds.max_intervention_rate,
        f"{100 * share:.3f} % of ticks with an intervention (threshold "
        f"{100 * thresholds.max_intervention_rate:.3f} %"
        + ("; " + ", ".join(f"{k} {100 * f:.3f} %" for f, k in worst) + ")" if worst else ")")
        + (
            f"; not judged, the policy's PD targets past its joints' ranges: {style}"
            if style
            else ""
        ),
    )


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
        if s.get("locomotion") is not None:
            continue  # a legged session: no goals
        missed = (s.get("goals") or {}).get("missed")
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
    own_loop: dict | None = None,
) -> dict:
    """The report.json document (``schema_version`` ``SCHEMA_VERSION`` = 2)::

        schema_version, tool, created (UTC, ISO 8601)
        campaign        robot, policy, policy_sha256, hours, sessions, seed, options of the
                        sessions, ranges_file (soak-test --ranges, or null), commands (a
                        legged robot's schedule, else null: period_s, zero_fraction, ranges and
                        where each came from), executor, sessions_per_process, wall_s
        thresholds      the pass/fail thresholds and baseline tolerances
                        (:class:`~sim2real.eval.report.schema.Thresholds`)
        sessions[]      one per session (sim2real.eval.soak's result):
            id, seed, status ('complete' | 'diverged'), simulated_s, simulated_hours, ticks,
            control_mode, options (the session's, ranges {dynamics, sensors, drift, faults, imu,
            floor_friction} among them), randomization {dynamics, sensors, drift, faults[]},
            violations {source, total {type: ticks}, any, per_hour [{hour, start_s, end_s,
                        counts {type: ticks}, any}], rate_per_hour {type: ticks per hour},
                        self_collision_pairs {"geom_a|geom_b": ticks}, most first,
                        hard_limit_joints {joint: ticks beyond its hard limit}, most first,
                        while_down {type: ticks, any}: a legged robot's ticks lying damped after
                        a stop, counted apart from the others}
                        (types: hard_limit, soft_limit, velocity, effort, workspace, self_collision;
                        a tick counts once per type)
            interventions {ticks, checks {check: {count, fraction}}, any {count, fraction},
                        warnings {soft_band_estimate: {count, fraction}}, per_hour [{hour, start_s,
                        end_s, ticks, counts {check: ticks}, any, warnings}], while_down {ticks,
                        checks, any, safety}: a legged robot's ticks lying damped after a stop,
                        apart; ticks, counts and fractions above are of the ticks up}
                        (checks: hard_limit, soft_limit, velocity, workspace, self_collision,
                        effort, stopping_distance, target_clamp; count = ticks on which the check
                        changed a command, fraction = count / ticks)
            goals (null for a legged robot) {issued, reached, success_rate,
                   median_time_to_reach_s, within_s, period_s,
                   window_s, windows [{start_s, end_s, issued, reached, success_rate}],
                   min_window_success_rate, missed [{t_s, issued_s, goal, q, dq, q_estimate,
                   distance_m, best_distance_m, interventions {check: ticks, any}}],
                   missed_dropped}
            locomotion (null for an arm) {commanded_by ("velocity", or "clip": a motion-tracking
                   session, whose velocity-tracking figures mean nothing and are neither
                   printed nor judged), commands_issued, command_period_s (s, or [low, high]
                   when each command's length is drawn), command_ranges,
                   final_command, falls, falls_per_hour, fall_stops, fall_replays {falls,
                   own_loop, own_loop_fell, redraw, redraw_fell} (the falls replayed,
                   :func:`sim2real.eval.soak.falls.fall_replays`), false_fall_stops (fall-check
                   stops of a robot the truth had upright, :func:`sim2real.eval.soak.falls.
                   false_fall_stops`; must be 0), tracking_success (the session's success
                   rate: share of RUNNING time within tracking_tolerance_m_s of the command, the
                   velocity and the command both averaged over tracking_window_s),
                   tracking_tolerance_m_s, tracking_window_s, yaw_tracking_success (the
                   same of the yaw rate against the yaw-rate command the policy was given,
                   within yaw_tracking_tolerance_rad_s; with --min-success the lower of the two
                   is judged), yaw_tracked_s, yaw_tracking_tolerance_rad_s, heading (null
                   without heading commands: {heading_commands_ended, mean_heading_error_deg},
                   the estimate's heading against each heading command at its end), judged_on,
                   running_s,
                   standing_fraction (RUNNING s / session s), tracked_s, distance_m, forward_m,
                   mean_forward_speed_m_s, window_s, windows [{start_s, end_s, running_s,
                   tracked_s, success_rate}], min_window_success_rate, peak_winding_c {hip, thigh,
                   calf}}
            faults {scheduled, injected, survived, responses {held, safe_stop, resumed, latched,
                    not_running}, events [{kind, start_s, duration_s, magnitude, response, survived,
                    causes, ...}], skipped_pushes [{start_s, magnitude, mode, reason}]},
            runtime {safe_stops, by_cause, non_finite_actions, resyncs, anchors, latched_faults,
                     latches[], operator_resets, final_mode, final_cause},
            estimator {missing_readings, stale_readings, reinitializations},
            wheels {joints (the continuous ones; empty without), peak_speed_rad_s (true),
                    velocity_limit_rad_s, soft_velocity_limit_rad_s},
            thermal {joints, derating_start_c, max_winding_c, peak_c, derating_band_s,
                     over_temperature_s, curve {t_s, winding_c {joint: [...]}}},
            curves {t_s, goals_issued, goals_reached (legged: commands, falls, distance_m,
                    running_s, tracked_s), violations {type | any: [...]},
                    interventions {check | any: [...]}, mode}   (cumulative counts)
            drift {friction_final_nm}, diverged (message or null),
            checks {name: {passed, message}},
            wall {wall_s, speed, batch, tick_cost_us, tick_cost_histogram, stage_cost_us},
            film (only with the film strip, :mod:`sim2real.eval.film.strip`) {clips [{kind, kinds, label,
                  moments, t_s, start_s, end_s, video, still (paths relative to the report's
                  folder), frames, bytes, replay_exact, checked, from_tick}], moments {kind:
                  found}, not_filmed, fps, size, frames_per_s, error (why there is no film, or
                  null)}
        totals          over every session: simulated_hours, ticks, violations {total, any,
                        rate_per_hour, per_hour [{hour, counts, any}], self_collision_pairs,
                        hard_limit_joints, while_down},
                        interventions {ticks,
                        checks {check: {count, fraction}}, any {count, fraction}, warnings,
                        per_hour [{hour, ticks, counts, any, fraction}], while_down}, goals
                        {issued, reached,
                        success_rate, min_window_success_rate, missed, missed_dropped} (arm
                        sessions), locomotion (legged sessions, else null) {sessions, falls,
                        falls_per_hour, clip_sessions (a motion clip commands them: not in the
                        velocity figures), tracking_success, min_window_success_rate, distance_m,
                        mean_forward_speed_m_s, running_s, peak_winding_c}, faults {injected,
                        survived, responses, by_kind}, latched_faults, operator_resets, wheels
                        (null without) {joints, peak_speed_rad_s, velocity_limit_rad_s,
                        soft_velocity_limit_rad_s}, thermal {peak_c, derating_band_s,
                        over_temperature_s}, diverged [ids], tick_cost_us
        checks          {name: {passed, failed_sessions}}
        baseline        null, or {path, passed, regressions [{metric, baseline, current, allowed,
                        message}], compared {metric: {baseline, current, allowed}}, violation_basis,
                        known_failures [{check, sessions, message}]: checks failed in the same
                        sessions of the baseline too (:func:`sim2real.eval.report.baseline.known_failures`)}
        passed          every check and the baseline comparison passed

    Everything in a session except ``wall`` (wall-clock time, tick cost) follows from the
    session's seed and options: a repeated or resumed session reproduces it exactly.

    Args:
        campaign: Campaign description (robot, policy, options; see the schema).
        results: Session results from :func:`sim2real.eval.soak.campaign.run_campaign`.
        thresholds: Pass/fail thresholds (default :class:`Thresholds`).
        baseline: An earlier report (:func:`load_report`) to compare with, or None.
        baseline_path: Where the baseline came from (recorded in the report).
        own_loop: An exhibition's own-loop reference
            (:func:`sim2real.eval.soak.own_loop_limits.own_loop_reference`), recorded as the
            report's ``own_loop``; where compared, each clip session's ``no_hard_violation`` and
            ``interventions`` are judged against it and the session gets ``own_loop_verdict``
            {hard_limits, interventions} (the figures of
            :func:`~sim2real.eval.soak.own_loop_limits.judge_hard_limits` and
            :func:`~sim2real.eval.soak.own_loop_limits.judge_interventions`).

    Raises:
        ReportError: the baseline is not of this schema, misses a field, or is of another robot.
    """
    thresholds = Thresholds() if thresholds is None else thresholds
    sessions = []
    for r in results:
        r = dict(r)
        r["checks"] = session_checks(r, thresholds)
        if own_loop and own_loop.get("compared") and r.get("exhibition"):
            r["own_loop_verdict"] = own_loop_checks(r, own_loop, thresholds)
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
        "own_loop": own_loop,
    }
    if baseline is not None:
        report["baseline"] = compare_with_baseline(report, baseline, thresholds, baseline_path)
    report["passed"] = all(c["passed"] for c in checks.values()) and (
        report["baseline"] is None or report["baseline"]["passed"]
    )
    return report


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


def write_reports(out: str | os.PathLike, report: dict) -> dict[str, Path]:
    """Write report.json, report.html and junit.xml into ``out``; returns their paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return {
        "json": write_json(out / "report.json", report),
        "html": write_html(out / "report.html", report),
        "junit": write_junit(out / "junit.xml", report),
    }
