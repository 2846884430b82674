"""``deploy-run``'s hard-limit and self-collision ticks of a tracking run (a clip, or a
phase-clocked dance) judged against the policy's own loop before the run is failed for them: the
soak's rule and reference (:mod:`sim2real.eval.soak.own_loop_limits`: the own loop of the stack
whose ``tracking_loop`` face finds the policy's folder, played on the run's robot, each kind's
ticks per second of motion, ``1.1 x expected + 3 sqrt(expected)`` allowed).

The own loop plays only when the run has such ticks to judge, on the simulated backend (the true
state), with ``--own-loop-plays`` > 0 (default 1: ``deploy-run`` has no pushes, so the own loop
is deterministic and one play from rest says all; a run that played its clip again,
``--motion-playback loop``, gets as many plays back to back, each from where the last left the
robot, as its envs played on average), one policy (a hand-over's second policy is no part of
the own loop's motion) and the policy's own clip (not ``--motion``). Ticks lying down after a
stop, hard-limit safe stops and the other hard kinds (velocity, effort, workspace) are judged as
before.
"""

from __future__ import annotations

import time


def clip_seconds(report: dict, period: float) -> float | None:
    """s of motion the run played (the clip's judged ticks, or a phase-clocked dance's, every env,
    times the control ``period``); None for a run no motion commands."""
    for key in ("tracking", "motion_phase"):
        part = report.get(key)
        if part is not None:
            return int(part.get("ticks") or 0) * period
    return None


def own_loop_verdict(args, rig, report: dict) -> dict | None:
    """The run's judged kinds against its own loop (module docstring), or None where nothing is
    to be judged (no tick of a judged kind, no motion, not simulated, ``--own-loop-plays 0``).

    Returns:
        ``{"compared": False, "why"}`` (the run is judged as before), or ``compared`` True,
        ``own`` (:func:`~sim2real.eval.soak.own_loop_limits.play_reference`), ``clip_s``,
        ``verdict`` (:func:`~sim2real.eval.soak.own_loop_limits.judge_run`), ``wall_s``.
    """
    from sim2real.eval.soak.own_loop_limits import JUDGED_KINDS, judge_run, play_reference

    v = report.get("violations")
    plays = getattr(args, "own_loop_plays", 1)
    if plays < 1 or v is None or not any(v["by_type"].get(k, 0) for k in JUDGED_KINDS):
        return None
    clip_s = clip_seconds(report, rig.robot.control_period)
    if clip_s is None:
        return None
    if args.motion is not None:
        return {"compared": False, "why": "--motion plays another clip than the own loop's"}
    if len(args.policies) > 1:
        return {"compared": False, "why": "a second policy plays in the run"}
    # a clip played again (--motion-playback loop): as many plays back to back in the own loop
    played = (report.get("tracking") or report.get("motion_phase") or {}).get("plays") or 1
    plays = max(plays, -(-int(played) // max(1, int(report.get("envs") or 1))))
    wall = time.perf_counter()
    own = play_reference(rig.robot, report["policy"], plays)
    if not own["compared"]:
        return own
    return {
        "compared": True,
        "own": own,
        "clip_s": clip_s,
        "verdict": judge_run(v, own, clip_s),
        "wall_s": time.perf_counter() - wall,
    }


def own_loop_lines(judged: dict | None) -> list[str]:
    """The summary's lines of :func:`own_loop_verdict`'s result (none for None)."""
    if judged is None:
        return []
    if not judged["compared"]:
        return [f"  own loop          not compared: {judged['why']}"]
    own = judged["own"]
    lines = [
        f"  own loop          {own['stack']}: {own['loop']}; {own['plays']} play(s), "
        f"{own['clip_s']:.1f} s of motion, {own['falls']} falls ({judged['wall_s']:.0f} s wall)"
    ]
    for kind, k in judged["verdict"].items():
        names = ", ".join(
            f"{n} {f['ours']}/{f['own']} (allowed {f['allowed']:g})"
            for n, f in k["names"].items()
            if n != kind
        )
        verdict = "within the own loop's" if k["passed"] else f"{k['stack']} the stack's"
        lines.append(
            f"  own loop {kind:<15} ticks ours {k['ours']} over {judged['clip_s']:.1f} s of "
            f"motion, own loop's {k['own']} over {own['clip_s']:.1f} s; allowed "
            f"{k['allowed']:g}" + (f" ({names})" if names else "") + f": {verdict}"
        )
    return lines
