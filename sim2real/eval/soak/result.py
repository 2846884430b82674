"""The result of one soak session: the document built from its book-keeping, and its
``result.json``.

A finished session writes ``result.json`` in its folder (``OUT/sessions/<id>/``,
:func:`sim2real.eval.soak.session.session_dir`); a resumed campaign reads it back (:func:`read_result`)
instead of running the session again, after checking that it was run with the same options
(:func:`check_result`). The document's schema is in :mod:`sim2real.eval.report.build`; everything in it but
``wall`` (wall-clock time, tick cost) follows from the session's seed and options.

A legged session (its task a :class:`sim2real.deploy.tasks.velocity.VelocityTask`) has ``goals`` None and
a ``locomotion`` section instead (:func:`locomotion_result`): falls, falls per hour, tracking
success (its success rate), distance, forward speed, per window too; its curves have commands,
falls, distance and tracking instead of goals. An arm's result has ``locomotion`` None.
"""

from __future__ import annotations

import json
import os

import numpy as np

from sim2real.deploy.monitors.interventions import INTERVENTION_CHECKS
from sim2real.deploy.monitors.violations import VIOLATION_TYPES
from sim2real.deploy.runtime import FAULT_CAUSES, STAGES, Mode
from sim2real.eval.soak import checkpoint as ckpt
from sim2real.eval.soak.camera import camera_result
from sim2real.eval.soak.falls import (
    attribute_falls,
    fall_replays,
    falls_by_origin,
    false_fall_stops,
    stops_while_falling,
)
from sim2real.eval.soak.session import (
    RESPONSES,
    Session,
    SessionConfig,
    option_difference,
    session_dir,
)
from sim2real.robots.files import sha256_file

VIOLATION_SOURCE = "true state (simulation ground truth)"
#: A legged session's task curves (cumulative; ``curves`` of its result).
LEGGED_CURVES = ("commands", "falls", "distance_m", "running_s", "tracked_s")
#: Joint kinds of a quadruped whose peak winding temperature a legged result lists (by name).
LEG_JOINTS = ("hip", "thigh", "calf")


def locomotion_result(session: Session) -> dict:
    """The ``locomotion`` section of a legged session's result (see :mod:`sim2real.eval.report.build`)."""
    from dataclasses import asdict

    from sim2real.deploy.tasks.locomotion import (
        SETTLE_TIME,
        TRACKING_TOLERANCE,
        TRACKING_WINDOW,
        YAW_TRACKING_TOLERANCE,
    )

    b, e, rt = session.batch, session.e, session.batch.rt
    tr, cmd = session.task.tracker, session.task.schedule
    t_end = rt.time
    sim_h = t_end / 3600.0
    falls = int(tr.falls[e])
    running = float(tr.running_time[e])
    windows = tr.windows(e, t_end)
    names = list(b.robot.joint_names)
    peaks = {}
    for kind in LEG_JOINTS:
        hits = [i for i, j in enumerate(names) if f"_{kind}" in j]
        if hits:
            peaks[kind] = float(b.peak[e, hits].max())
    schedule = [
        {"kind": f.kind, "start_s": f.start, "duration_s": f.duration} for f in session.schedule
    ]
    pushes = b.pushes.times[e] if b.pushes is not None else []
    fall_records = attribute_falls(tr.fall_log[e], schedule, pushes)
    figures = b.terrain_figures.summary(e) if b.terrain_figures is not None else None
    if figures is not None and b.curriculum is not None:  # sim2real.eval.soak.curriculum_walk
        figures["curriculum"] = b.curriculum.summary(e)
    if figures is not None:  # each fall's tile and part, counted at the same stop
        for record, place in zip(fall_records, figures["fall_places"], strict=True):
            record["where"] = {"tile": place["tile"], "part": place["part"]}
    return {
        # what commands the policy: a velocity (the tracking figures below mean something) or a
        # motion clip (they do not: its tracking is the exhibition section's)
        "commanded_by": "clip" if session.task.name == "tracking" else "velocity",
        "commands_issued": int(cmd.issued[e]) if cmd is not None else 0,
        "command_period_s": period_value(session.config.command_period),
        "command_ranges": asdict(cmd.ranges) if cmd is not None else None,
        "final_command": [float(x) for x in rt.velocity_command[e]],
        "falls": falls,
        "falls_per_hour": falls / sim_h if sim_h > 0 else 0.0,
        "falls_by_cause": tr.causes(e),
        "falls_by_origin": falls_by_origin(fall_records),
        "stops_while_falling": stops_while_falling(fall_records),
        "fall_replays": fall_replays(fall_records),
        "fall_records": fall_records,
        "domain_pushes": len(pushes),
        "fall_stops": int(rt.counters.faults["fall"][e]),
        "false_fall_stops": false_fall_stops(
            fall_records, float(b.robot.config.base.standing_height), _tilt_limit(b.robot)
        ),
        "stood_up": session.stood_up,
        "tracking_success": float(tr.tracked_time[e]) / running if running else None,
        "tracking_tolerance_m_s": TRACKING_TOLERANCE,
        "tracking_window_s": TRACKING_WINDOW,
        "yaw_tracking_success": float(tr.yaw_tracked_time[e]) / running if running else None,
        "yaw_tracked_s": float(tr.yaw_tracked_time[e]),
        "yaw_tracking_tolerance_rad_s": YAW_TRACKING_TOLERANCE,
        # heading commands (legged_gym's heading_command): how near each came; None without
        "heading": cmd.heading_figures(e) if cmd is not None else None,
        "settle_s": SETTLE_TIME,
        "judged_on": tr.judged_on,
        "running_s": running,
        "standing_fraction": running / t_end if t_end > 0 else None,
        "tracked_s": float(tr.tracked_time[e]),
        "distance_m": float(tr.distance[e]),
        "forward_m": float(tr.forward[e]),
        "mean_forward_speed_m_s": float(tr.forward[e]) / running if running else None,
        "window_s": tr.success_window,
        "windows": windows,
        "min_window_success_rate": (min(w["success_rate"] for w in windows) if windows else None),
        "peak_winding_c": peaks,
        # what the robot did on its terrain tiles (None on the plane): sim2real.eval.soak.terrain_figures
        "on_terrain": figures,
    }


def exhibition_result(session: Session) -> dict:
    """The ``exhibition`` section of a motion-tracking session: its clips
    (:attr:`sim2real.deploy.tasks.motion.tracking.TrackingTask.play_log`) and the heat report
    (:func:`sim2real.eval.soak.exhibition.heat_report`)."""
    from sim2real.eval.soak.exhibition import clips_and_rests, heat_report

    task, e = session.task, session.e
    plays = task.plays(e)  # with the clip the session's end cut short (unfinished)
    return {
        "clip": str(task.motion.clip.source),
        "clip_s": task.motion.length,
        "stand_s": task.motion.stand_s,
        "rest_s": task.motion.rest_s,
        "clips": plays,
        "reference_contacts": task.contacts.summary(),
        "reference_contact_ticks": int(session.batch.violations.reference_ticks[e]),
        "heat": heat_report(plays),
        "clips_and_rests": clips_and_rests(plays),
    }


def period_value(period: tuple[float, float]) -> float | list[float]:
    """A command period ``(low, high)`` as the report writes it: s, or ``[low, high]`` s when
    each command's length is drawn."""
    low, high = period
    return float(low) if low == high else [float(low), float(high)]


def wheel_speeds(b, e: int) -> dict:
    """The continuous joints' (a wheel-legged robot's wheels': no position limit, checked on
    speed and torque) largest true speed in env ``e`` of batch ``b`` against their limits:
    ``joints``, then ``peak_speed_rad_s``, ``velocity_limit_rad_s`` (the hard limit) and
    ``soft_velocity_limit_rad_s`` by joint; empty without continuous joints."""
    robot = b.robot
    wheels = np.flatnonzero(np.isinf(robot.position_lower) | np.isinf(robot.position_upper))
    names = [robot.joint_names[i] for i in wheels]
    if not names:
        return {"joints": []}
    return {
        "joints": names,
        "peak_speed_rad_s": dict(zip(names, b.speed_peak[e, wheels].tolist(), strict=True)),
        "velocity_limit_rad_s": dict(
            zip(names, robot.velocity_limit[wheels].tolist(), strict=True)
        ),
        "soft_velocity_limit_rad_s": dict(
            zip(names, robot.soft_velocity_limit[wheels].tolist(), strict=True)
        ),
    }


def _tilt_limit(robot) -> float:
    """rad, the fall check's tilt limit of ``robot`` (``safety.fall_tilt`` or its default)."""
    from sim2real.deploy.estimation.fall import FALL_TILT

    tilt = robot.config.safety.fall_tilt
    return float(FALL_TILT if tilt is None else tilt)


def goals_result(session: Session) -> dict:
    """The ``goals`` section of an arm's session result (see :mod:`sim2real.eval.report.build`)."""
    g, e, t_end = session.task.scheduler, session.e, session.batch.rt.time
    times = g.hit_times[e]
    windows = g.windows(e, t_end)
    return {
        "issued": int(g.issued[e]),
        "reached": int(g.hit_count[e]),
        "success_rate": int(g.hit_count[e]) / int(g.issued[e]) if g.issued[e] else None,
        "median_time_to_reach_s": float(np.median(times)) if times else None,
        "within_s": session.config.success_time,
        "period_s": session.config.goal_period,
        "window_s": g.window,
        "windows": windows,
        "min_window_success_rate": (min(w["success_rate"] for w in windows) if windows else None),
        "missed": list(g.missed[e]),
        "missed_dropped": int(g.missed_dropped[e]),
    }


def session_result(session: Session) -> dict:
    """The result of a session as it stands (see :mod:`sim2real.eval.report.build` for the schema).

    Args:
        session: The session's book-keeping in its batch (:class:`sim2real.eval.soak.session.Session`).
    """
    b, e, rt = session.batch, session.e, session.batch.rt
    t_end = rt.time
    hours = list(session.hours)
    last_end = hours[-1]["end_s"] if hours else 0.0
    if t_end > last_end + 1e-9:
        hours.append(session.hour_row(last_end, t_end))
    name = session.task.name  # the task's section: goals or locomotion
    est = rt.estimator
    return {
        "id": session.config.id,
        "seed": session.config.seed,
        "status": "diverged" if session.diverged else "complete",
        "simulated_s": t_end,
        "simulated_hours": t_end / 3600.0,
        "ticks": rt.ticks,
        "control_mode": b.mode,
        "options": session.config.batch_key(),
        "policy_sha256": b.policy_sha256,
        "randomization": session.draw.to_dict(),
        "violations": _violations(session, hours, t_end / 3600.0),
        "interventions": {
            **b.interventions.summary(e),
            "per_hour": [
                {
                    "hour": h["hour"],
                    "start_s": h["start_s"],
                    "end_s": h["end_s"],
                    "ticks": h["ticks"],
                    "counts": {k: h["interventions"][k] for k in INTERVENTION_CHECKS},
                    "any": h["interventions"]["any"],
                    "warnings": h["warnings"],
                }
                for h in hours
            ],
        },
        "goals": goals_result(session) if name == "goals" else None,
        "locomotion": locomotion_result(session) if name in ("locomotion", "tracking") else None,
        "exhibition": exhibition_result(session) if name == "tracking" else None,
        "faults": _faults(session),
        "runtime": _runtime(session),
        "base_estimate": base_estimate(b, e),
        "estimator": {
            "missing_readings": int(est.missing_per_joint[e].sum()),
            "stale_readings": int(est.stale_per_joint[e].sum()),
            "reinitializations": int(est.reinitializations_per_joint[e].sum()),
        },
        "wheels": wheel_speeds(b, e),
        "camera": camera_result(b, e),
        "thermal": _thermal(session),
        "curves": _curves(session, legged=name in ("locomotion", "tracking")),
        "drift": {
            "friction_final_nm": dict(zip(b.robot.joint_names, session.friction, strict=True))
        },
        "diverged": session.diverged,
        "wall": _wall(session, t_end),
    }


def _violations(session: Session, hours: list, sim_h: float) -> dict:
    """The ``violations`` section: the true state's counts in total, per hour and per hour's
    rate, the self-collision pairs, the joints past their hard limits and those while down."""
    b, e = session.batch, session.e
    true = session.counters()["violations"]
    return {
        "source": VIOLATION_SOURCE,
        "total": {k: true[k] for k in VIOLATION_TYPES},
        "any": true["any"],
        "per_hour": [
            {
                "hour": h["hour"],
                "start_s": h["start_s"],
                "end_s": h["end_s"],
                "counts": {k: h["violations"][k] for k in VIOLATION_TYPES},
                "any": h["violations"]["any"],
            }
            for h in hours
        ],
        "rate_per_hour": {k: (true[k] / sim_h if sim_h > 0 else 0.0) for k in VIOLATION_TYPES},
        "self_collision_pairs": b.violations.pair_counts(e),
        "hard_limit_joints": b.violations.hard_limit_joints(e),
        "while_down": b.violations.env_counts(e, down=True),
    }


def _faults(session: Session) -> dict:
    """The ``faults`` section: scheduled, injected and survived faults and their responses."""
    responses = {r: 0 for r in RESPONSES}
    for ev in session.fault_events:
        responses[ev["response"]] += 1
    return {
        "scheduled": len(session.schedule),
        "injected": len(session.fault_events),
        "survived": sum(1 for ev in session.fault_events if ev["survived"]),
        "responses": responses,
        "events": session.fault_events,
        "skipped_pushes": session.skipped_pushes,
    }


def _runtime(session: Session) -> dict:
    """The ``runtime`` section: the runtime's counters of env ``session.e``, its latches,
    resets and final mode and cause."""
    rt, e = session.batch.rt, session.e
    return {
        "safe_stops": int(rt.counters.safe_stops[e]),
        "by_cause": {c: int(v[e]) for c, v in rt.counters.faults.items()},
        "non_finite_actions": int(rt.counters.non_finite_actions[e]),
        "resyncs": int(rt.counters.resyncs[e]),
        "anchors": int(rt.counters.anchors[e]),
        "latched_faults": len(session.latches),
        "latches": session.latches,
        "operator_resets": session.operator_resets,
        "final_mode": Mode(int(rt.mode[e])).name,
        "final_cause": FAULT_CAUSES[rt.cause[e]] if rt.cause[e] >= 0 else None,
    }


def _thermal(session: Session) -> dict:
    """The ``thermal`` section: each joint's motor limits (degC), peak winding temperature,
    time in the derating band and over temperature (s), and the winding curve."""
    b, e = session.batch, session.e
    names, motors, dt = list(b.robot.joint_names), b.robot.motors, b.dt
    return {
        "joints": names,
        "derating_start_c": {
            j: m.derating_start_temperature for j, m in zip(names, motors, strict=True)
        },
        "max_winding_c": {j: m.max_winding_temperature for j, m in zip(names, motors, strict=True)},
        "peak_c": dict(zip(names, b.peak[e].tolist(), strict=True)),
        "derating_band_s": dict(
            zip(names, ((b.band_ticks[e] - b.over_ticks[e]) * dt).tolist(), strict=True)
        ),
        "over_temperature_s": dict(zip(names, (b.over_ticks[e] * dt).tolist(), strict=True)),
        "curve": {
            "t_s": session.curve["t_s"],
            "winding_c": {
                j: [row[i] for row in session.curve["winding_c"]] for i, j in enumerate(names)
            },
        },
    }


def _curves(session: Session, legged: bool) -> dict:
    """The ``curves`` section: the walking curves (``legged``) or the goals', then violations,
    interventions and mode over time."""
    c = session.curve
    return {
        "t_s": c["t_s"],
        **(
            {k: c[k] for k in LEGGED_CURVES}
            if legged
            else {"goals_issued": c["issued"], "goals_reached": c["reached"]}
        ),
        "violations": {k: [row[k] for row in c["violations"]] for k in (*VIOLATION_TYPES, "any")},
        "interventions": {
            k: [row[k] for row in c["interventions"]] for k in (*INTERVENTION_CHECKS, "any")
        },
        "mode": [Mode(m).name for m in c["mode"]],
    }


def _wall(session: Session, t_end: float) -> dict:
    """The ``wall`` section: wall time and speed, the batch's seeds, the tick's and stages' cost."""
    b, rt = session.batch, session.batch.rt
    wall = session.wall_s + b.wall_elapsed()
    tick_cost = rt.tick_cost
    nz = np.flatnonzero(tick_cost.counts[0])
    return {
        "wall_s": wall,
        "speed": t_end / wall if wall > 0 else None,
        "batch": [s.config.seed for s in b.sessions],
        "tick_cost_us": tick_cost.summary(),
        "tick_cost_histogram": {"bin_us": nz.tolist(), "count": tick_cost.counts[0][nz].tolist()},
        "stage_cost_us": {s: rt.latency.summary(i) for i, s in enumerate(STAGES)},
    }


def base_estimate(batch, e: int) -> dict | None:
    """The ``base_estimate`` section of env ``e``'s result: the estimate against the truth
    (:meth:`sim2real.deploy.monitors.estimation.EstimationMonitor.summary`) with ``after_push``,
    its planar velocity error in the second after each push
    (:meth:`sim2real.eval.soak.push_response.PushResponse.summary`; None without pushes); None
    for an arm or before any RUNNING tick."""
    if batch.estimation is None:
        return None
    out = batch.estimation.summary(e)
    if out is not None:
        response = batch.push_response
        out["after_push"] = response.summary(e) if response is not None else None
    return out


def read_result(out: str | os.PathLike, seed: int) -> dict | None:
    """The finished result of session ``seed`` in campaign folder ``out``, or None."""
    path = session_dir(out, seed) / "result.json"
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ckpt.CheckpointError(
            f"{path}: not a readable session result ({exc}); delete it to run the session again"
        ) from None


def check_result(result: dict, config: SessionConfig, out) -> None:
    """A finished session may only stand for ``config`` if it was run with the same options.

    Raises:
        sim2real.eval.soak.checkpoint.CheckpointError: ``result`` was run with other options (but the policy
            path and checkpoint interval) or another policy file (named).
    """
    path = session_dir(out, config.seed) / "result.json"
    differs = option_difference(result.get("options", {}), config.batch_key())
    if differs is not None:
        key, old, new = differs
        raise ckpt.CheckpointError(
            f"{path}: the session was run with {key} = {old!r}, this run has {new!r}; resume "
            f"with the options of that campaign or use another --out"
        )
    if result.get("policy_sha256") != sha256_file(config.policy):
        raise ckpt.CheckpointError(
            f"{path}: the session was run with another policy file than {config.policy}"
        )
