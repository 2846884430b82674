"""The heat report of an exhibition soak: can a motion-tracking policy dance all day?

A tracking policy's soak session plays its clip, rests standing, plays it again
(:class:`~sim2real.deploy.tasks.motion.clock.MotionClock`'s ``exhibition``); each play is logged
with its hottest winding and the windings past their derating start (the plant's thermal model,
:mod:`sim2real.robots.thermal`; robot.toml's motors). :func:`heat_report` answers which windings
reach derating, after how many clips, and what the derated drive does to tracking (the joint
error of the clips played derated against those before).
"""

from __future__ import annotations

import numpy as np


def exhibition_task(task: dict, policy, robot, envs: int, config) -> None:
    """Make ``task`` (the soak's :func:`~sim2real.deploy.tasks.task.task_for` options) the
    ``tracking`` task of an exhibition when ``policy`` reads a clip: its contract's, or
    ``config.motion`` (a :class:`~sim2real.eval.soak.session.SessionConfig`), played, rested
    ``config.rest_s`` s standing at home, played again; unchanged for any other policy.

    Raises:
        sim2real.deploy.tasks.motion.clip.ClipError: a clip that does not fit (one line).
    """
    from sim2real.deploy.tasks.motion.source import motion_for

    motion = motion_for(policy, robot, envs, config.motion, "exhibition", rest_s=config.rest_s)
    if motion is not None:
        task.update(task="tracking", motion=motion)


def check_exhibition(policy, robot, config) -> None:
    """Read the clip :func:`exhibition_task` would play, on the driver before the campaign
    writes anything (a refusal leaves no ``sessions/`` folder and removes no earlier session).

    Raises:
        sim2real.deploy.tasks.motion.clip.ClipError: a clip that does not fit (one line).
    """
    exhibition_task({}, policy, robot, 1, config)


def clips_and_rests(plays: list[dict]) -> dict:
    """The clips of a session's ``plays`` apart from the rests between them (the tracking task's
    play log: each play's ``travel`` against its clip's root path,
    :meth:`~sim2real.deploy.tasks.motion.travel.ClipTravel.figures`, and its guard
    interventions): a rest is what follows a clip until the next starts (its transition to home
    and its standing), a hold judged as ``deploy-run`` judges one.

    Returns:
        ``clips``: ``travel_m`` (the base's over every clip, summed), ``worst_end_offset_m``
        (the farthest a clip ended from its root path's end), ``interventions``,
        ``hard_limit_ticks`` and ``violation_ticks`` (true state: ticks past a hard limit, ticks
        with any violation); ``rests``: ``count``, ``travel_m`` (summed: each rest's from where
        its clip ended), ``worst_travel_m`` (the farthest a rest went), ``interventions``,
        ``hard_limit_ticks``, ``violation_ticks`` (the rests' ticks; the transition counts with
        its clip); ``left_spot``: the 1-based plays
        whose base left its spot (:data:`~sim2real.deploy.tasks.motion.travel.OFF_PATH_M`).
    """
    travel = [(i, p["travel"]) for i, p in enumerate(plays, start=1) if p.get("travel")]
    rests = [(i, f) for i, f in travel if f["after_clip_s"] is not None]

    def total(rows, key):
        return float(sum(f[key] for _, f in rows if f[key] is not None))

    return {
        "clips": {
            "travel_m": total(travel, "base_travel_m"),
            "worst_end_offset_m": max(
                (f["clip_end_offset_m"] for _, f in travel if f["clip_end_offset_m"] is not None),
                default=None,
            ),
            "interventions": int(sum(p.get("interventions", 0) for p in plays)),
            "hard_limit_ticks": int(sum(p.get("hard_limit_ticks", 0) for p in plays)),
            "violation_ticks": int(sum(p.get("violation_ticks", 0) for p in plays)),
        },
        "rests": {
            "count": len(rests),
            "travel_m": total(rests, "after_clip_travel_m"),
            "worst_travel_m": max((f["after_clip_max_m"] for _, f in rests), default=None),
            "interventions": int(sum(p.get("rest_interventions", 0) for p in plays)),
            "hard_limit_ticks": int(sum(p.get("rest_hard_limit_ticks", 0) for p in plays)),
            "violation_ticks": int(sum(p.get("rest_violation_ticks", 0) for p in plays)),
        },
        "left_spot": [i for i, f in travel if f["off_path"]],
    }


def heat_report(plays: list[dict]) -> dict:
    """The heat report of one session's ``plays`` (the tracking task's play log, in order).

    Returns:
        ``clips`` (played), ``completed`` (its clip played to the end: not ended by a stop
        during the clip nor cut short), ``falls`` (plays a stop ended, the clip or its rest),
        ``rest_falls`` (of them, those whose stop came in the rest after the clip),
        ``unfinished`` (the play the session's end cut short: 0 or 1),
        ``derating`` {winding: the 1-based clip in which it first passed its derating start},
        ``first_derated_clip`` (or None), ``joint_rms_rad_before`` / ``joint_rms_rad_derated``
        (mean over the clips before the first derated one / from it on; None without such
        clips), ``hottest`` {winding: peak degC over the session}, at most the five hottest.
    """
    first: dict[str, int] = {}
    hottest: dict[str, float] = {}
    for i, p in enumerate(plays, start=1):
        for j in p.get("derating") or []:
            first.setdefault(j, i)
        if p.get("hottest") is not None:
            hottest[p["hottest"]] = max(hottest.get(p["hottest"], -np.inf), p["hottest_c"])
    start = min(first.values()) if first else None

    def mean_rms(rows: list[dict]) -> float | None:
        values = [p["joint_rms_rad"] for p in rows if p.get("joint_rms_rad") is not None]
        return float(np.mean(values)) if values else None

    cut = len(plays) if start is None else start - 1
    top = sorted(hottest.items(), key=lambda kv: -kv[1])[:5]
    return {
        "clips": len(plays),
        "completed": sum(
            1
            for p in plays
            if not p.get("unfinished") and (not p["stopped"] or p.get("stopped_in_rest"))
        ),
        "falls": sum(1 for p in plays if p["stopped"]),
        "rest_falls": sum(1 for p in plays if p.get("stopped_in_rest")),
        "unfinished": sum(1 for p in plays if p.get("unfinished")),
        "derating": dict(sorted(first.items(), key=lambda kv: kv[1])),
        "first_derated_clip": start,
        "joint_rms_rad_before": mean_rms(plays[:cut]),
        "joint_rms_rad_derated": mean_rms(plays[cut:]) if start is not None else None,
        "hottest": dict(top),
    }
