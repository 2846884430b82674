"""The soak's console summary of a report: a few lines, what passed and what failed."""

from __future__ import annotations

import numpy as np

from sim2real.eval.report.domain_account import domain_summary

#: What the replays showed for a fall with no push, fault or stop before it, by its origin
#: (:func:`sim2real.eval.soak.falls.replay_origin`).
REPLAY_MEANING = {
    "policy": "the policy's own loop fell there in most of its replays",
    "runtime": "the policy's own loop stood in most, the runtime with other sensor noise fell",
    "rare_draw": "both stood in most of their replays (the session's draw of the noise)",
    "undecided": "not replayed, or only in the own loop, which stood: the soak cannot tell",
}


def replay_lines(origins: dict[str, int]) -> list[str]:
    """The summary's line on the falls with no push, fault or stop before them: what their
    replays showed (:data:`REPLAY_MEANING`) by ``origins`` (``falls_by_origin``); none when
    there were none."""
    shown = [(o, n) for o, n in origins.items() if n and o in REPLAY_MEANING]
    if not shown:
        return []
    said = "; ".join(f"{o.replace('_', ' ')} {n}: {REPLAY_MEANING[o]}" for o, n in shown)
    return [f"  no push, fault or stop before: the replays say {said}"]


def locomotion_line(loco: dict) -> str:
    """The legged sessions' line: falls, and the velocity tracking of the sessions a velocity
    commands; a clip's sessions (``clip_sessions``) have none (their tracking: the exhibition
    lines), and no velocity figure is printed for them."""
    head = f"  locomotion   falls {loco['falls']} ({loco['falls_per_hour']:.2f} per hour)"
    clips = loco.get("clip_sessions", 0)
    if clips and clips == loco["sessions"]:
        return (
            f"{head}; a motion clip commands the policy, not a velocity: no velocity tracking "
            "(its tracking: the exhibition lines)"
        )
    ts, speed = loco["tracking_success"], loco["mean_forward_speed_m_s"]
    yaw = loco.get("yaw_tracking_success")
    over = f" (the {loco['sessions'] - clips} velocity-commanded sessions)" if clips else ""
    heading = loco.get("heading")
    ended = (heading or {}).get("heading_commands_ended", 0)
    return (
        f"{head}; tracking success {'n/a' if ts is None else f'{100 * ts:.1f} %'} (within 0.2 "
        f"m/s), yaw rate {'n/a' if yaw is None else f'{100 * yaw:.1f} %'} (within 0.2 rad/s)"
        + (
            f"; heading commands {ended}, {heading['mean_heading_error_deg']:.0f} deg from "
            "their heading at their end on average"
            if ended
            else ""
        )
        + f"{over}; distance {loco['distance_m']:.0f} m; mean forward speed "
        f"{'n/a' if speed is None else f'{speed:.3f} m/s'}; commands issued "
        f"{loco.get('commands_issued', 'n/a')}"
    )


def summary_text(report: dict) -> str:
    """A few lines for the console."""
    t = report["totals"]
    lines = [
        f"soak-test: {report['campaign'].get('robot')}, {t['sessions']} sessions, "
        f"{t['simulated_hours']:.3f} simulated h: {'PASSED' if report['passed'] else 'FAILED'}"
    ]
    rate = t["goals"]["success_rate"]
    loco = t.get("locomotion")
    if loco is None or t["goals"]["issued"]:
        lines.append(
            f"  goals        {t['goals']['reached']}/{t['goals']['issued']} reached"
            + (f" ({100 * rate:.1f} %)" if rate is not None else "")
        )
    w = t["goals"]["min_window_success_rate"]
    if w is not None:
        lines.append(f"  windows      lowest success rate in a window {100 * w:.1f} %")
    if loco is not None:
        lines += _locomotion_lines(loco, report["campaign"].get("commands"), t.get("by_terrain"))
    lines += domain_summary(report["campaign"].get("training_domain"))
    lines += _estimate_lines(t.get("base_estimate"))
    lines += _violation_lines(t)
    lines += _intervention_lines(t["interventions"])
    lines.append(_faults_line(t))
    for s in report.get("sessions", []):
        lines += camera_lines(s)
        lines += exhibition_lines(s)
    peaks = ", ".join(f"{j} {p:.1f}" for j, p in t["thermal"]["peak_c"].items())
    lines.append(f"  peak winding degC {peaks}")
    tc = t["tick_cost_us"]
    if tc["samples"]:
        lines.append(f"  tick cost us p50 {tc['p50_us']:.0f}, p99 {tc['p99_us']:.0f}")
    return "\n".join(lines + _check_lines(report))


def _locomotion_lines(loco: dict, schedule, by_terrain) -> list[str]:
    """The walking block: commands, tracking, falls by origin and their replays, the fall
    check, standing time, windows and the per-terrain rows."""
    lines = []
    clips_only = loco.get("clip_sessions", 0) == loco["sessions"]
    if schedule and not clips_only:  # a clip's sessions draw no command
        from sim2real.eval.world.command_schedule import schedule_text

        lines.append(f"  commands     {schedule_text(schedule)}")
    lines.append(locomotion_line(loco))
    origins = loco.get("falls_by_origin")
    if loco["falls"] and origins:
        by = ", ".join(f"{o.replace('_', ' ')} {n}" for o, n in origins.items() if n)
        causes = ", ".join(f"{c} {n}" for c, n in loco.get("falls_by_cause", {}).items())
        lines.append(f"  falls began  {by} (stops by cause: {causes or 'none'})")
        lines += replay_lines(origins)
        falling = loco.get("stops_while_falling", 0)
        if falling:
            lines.append(
                f"  stops        {falling} runtime stop(s) on a robot already falling (its "
                "replay without the stop fell too; counted above by what began the fall)"
            )
    fr = loco.get("fall_replays") or {}
    if fr.get("falls"):
        from sim2real.eval.soak.fall_replay import LEAD, REDRAW_LEAD

        lines.append(
            f"  replays      {fr['falls']} fall(s) replayed (not judged): the policy's own loop "
            f"(true state, no guard or smoother) from {min(LEAD):g}-{max(LEAD):g} s before "
            f"fell in {fr['own_loop_fell']} of {fr['own_loop']}; the runtime from "
            f"{REDRAW_LEAD:g} s before with other sensor-noise draws fell in "
            f"{fr['redraw_fell']} of {fr['redraw']}"
        )
    if loco.get("false_fall_stops") is not None:
        lines.append(
            f"  fall check   false_fall_stops {loco['false_fall_stops']} (stops for a fall of "
            "a robot the truth had upright; must be 0)"
        )
    up = loco.get("standing_fraction")
    if up is not None:
        lines.append(f"  standing     {100 * up:.2f} % of the session RUNNING (on its feet)")
    lw = loco["min_window_success_rate"]
    if lw is not None:
        lines.append(f"  windows      lowest tracking success in a window {100 * lw:.1f} %")
    from sim2real.eval.report.by_terrain import terrain_lines

    return lines + terrain_lines(by_terrain)


def _estimate_lines(est) -> list[str]:
    """The base estimate against the truth (nothing for a fixed-base robot)."""
    if est is None:
        return []
    att, vz = est["attitude_error_deg"], est["vertical_velocity_m_s"]
    lines = [
        f"  base estimate vs truth  attitude error mean {att['mean']:.2f} deg (worst session "
        f"p95 {att['worst_session_p95']:.2f}); planar RMS {est['velocity_rms_m_s']:.3f} m/s; "
        f"vertical bias {vz['bias']:+.3f} m/s, RMS {vz['rms']:.3f}"
    ]
    after = est.get("after_push")
    if after is not None:
        lines.append(
            f"  after pushes planar velocity error in the {after['window_s']:g} s after "
            f"{after['pushes']} pushes: mean {after['mean_m_s']:.3f} m/s, RMS "
            f"{after['rms_m_s']:.3f}, worst tick {after['worst_m_s']:.3f}, worst push's mean "
            f"{after['worst_push_mean_m_s']:.3f} (steady: the planar RMS above)"
        )
    return lines


def _violation_lines(t: dict) -> list[str]:
    """Violations of the true state, while down, wheel speeds, hard limits, collision pairs."""
    v = ", ".join(f"{k} {n}" for k, n in t["violations"]["total"].items())
    lines = [f"  violations   (true state, ticks) {v}"]
    down = t["violations"].get("while_down", {})
    if down.get("any"):
        d = ", ".join(f"{k} {n}" for k, n in down.items() if k != "any" and n)
        lines.append(f"  while down   (lying damped after a stop, ticks; not counted above) {d}")
    wheels = t.get("wheels")
    if wheels:
        peak, limit = wheels["peak_speed_rad_s"], wheels["velocity_limit_rad_s"]
        each = ", ".join(f"{j} {peak[j]:.1f} of {limit[j]:g}" for j in wheels["joints"])
        lines.append(
            f"  wheel speeds (true peak of the velocity limit, rad/s; no position limit) {each}"
        )
    hard = ", ".join(f"{j} {n}" for j, n in t["violations"].get("hard_limit_joints", {}).items())
    if hard:
        lines.append(f"  hard limits  (joints beyond theirs, ticks) {hard}")
    pairs = list(t["violations"].get("self_collision_pairs", {}).items())
    if pairs:
        top = ", ".join(f"{p} {n}" for p, n in pairs[:3])
        more = f" (+{len(pairs) - 3} more pairs)" if len(pairs) > 3 else ""
        lines.append(f"  self-collision pairs (ticks) {top}{more}")
    return lines


def _intervention_lines(iv: dict) -> list[str]:
    """The guard's interventions, up and while down."""
    used = ", ".join(
        f"{k} {100 * c['fraction']:.3f}" for k, c in iv["checks"].items() if c["count"]
    )
    by_design = [k for k in iv.get("by_design", []) if iv["checks"].get(k, {}).get("count")]
    down = iv.get("while_down") or {}
    lines = [
        f"  interventions {100 * iv['any']['fraction']:.3f} % of ticks"
        + (" up" if down.get("ticks") else "")
        + (f" ({used})" if used else "")
        + (
            f"; judged {100 * iv['safety']['fraction']:.3f} % (not {', '.join(by_design)}: "
            "the policy's PD targets past its joints' ranges, by design)"
            if by_design
            else ""
        )
    ]
    if down.get("ticks"):
        lying = ", ".join(
            f"{k} {100 * c['fraction']:.3f}" for k, c in down["checks"].items() if c["count"]
        )
        lines.append(
            f"  while down   (lying damped after a stop, not counted above) interventions "
            f"{100 * down['any']['fraction']:.3f} % of {down['ticks']} ticks"
            + (f" ({lying})" if lying else "")
        )
    return lines


def _faults_line(t: dict) -> str:
    """Injected faults, survived, responses, latched faults and resets."""
    f = t["faults"]
    resp = ", ".join(f"{k} {n}" for k, n in f["responses"].items() if n)
    return (
        f"  faults       {f['injected']} injected, {f['survived']} survived ({resp or 'none'}); "
        f"latched {t['latched_faults']}"
        + (
            f" ({t['latched_injected']} after an injected camera fault: stopped safely)"
            if t.get("latched_injected")
            else ""
        )
        + f", operator resets {t['operator_resets']}"
        + (
            f"; {f['skipped_pushes']} scheduled pushes not applied (robot not running, or "
            "within the warmup after a reset)"
            if f.get("skipped_pushes")
            else ""
        )
    )


def camera_lines(s: dict) -> list[str]:
    """A camera policy's session: the camera faults it met (drawn for the session, and the
    frames they hit), the verdict (those it survived, those that stopped it safely and whether
    it ran again, the camera faults each kind of failure followed) and the first three
    stale-camera stops with the runtime's verdict; none without a camera
    (:func:`sim2real.eval.soak.camera_faults.camera_result`)."""
    c = s.get("camera")
    if not c:
        return []
    stops = c.get("stale_stops", [])
    v = c.get("verdict")
    count = v["stops"]["count"] if v else len(stops)
    lines = [camera_line(s["id"], cam, count) for cam in (c.get("cameras") or {0: c}).values()]
    if v:
        lines += verdict_lines(v)
    for stop in stops[:3]:
        lines.append(f"  camera stop  at {stop['t_s']:.1f} s: {stop.get('verdict')}")
    return lines


def camera_line(session: str, c: dict, count: int) -> str:
    """One camera of a session (its ``camera`` section, or one camera's of several): the
    faults it met, the oldest frame used, the session's stale-camera stops ``count``."""
    f = c["faults"]
    knocked = np.degrees(np.abs(f["extrinsic"])).max()
    met = [
        f"{c['dropped']} frames dropped",
        f"{c['spiked']} late by {1000 * f['spike_latency']:.0f} ms",
        f"{c['frozen']} frozen ({c['frames_repeated']} repeated seen)",
        f"lens {100 * f['occlusion']:.1f} % covered",
        f"mount knocked {knocked:.2f} deg",
    ]
    if c.get("kind") == "rgb" and f.get("lighting", 1.0) != 1.0:
        met.append(f"light x{f['lighting']:.2f}")
    return (
        f"  camera       {session}: '{c['camera']}' {c['rate_hz']:g} Hz, {c['frames']} frames; "
        f"met {', '.join(met)}; oldest frame used {1000 * c['oldest_s']:.0f} ms; safe stops "
        f"for a stale camera {count}"
    )


def verdict_lines(v: dict) -> list[str]:
    """A camera session's verdict (the ``camera`` section's ``verdict``,
    :meth:`sim2real.eval.soak.camera_verdict.CameraVerdict.section`) in three lines."""
    fr = v["frames"]
    names = {"frozen": "frozen frames", "dropped": "dropped frames", "late": "late frames"}
    after = v["latched_after_camera"]
    stopped = ", ".join(
        f"{names[k]} {n} time{'s' if n != 1 else ''}" for k, n in v["stopped_safely"].items()
    )
    labels = ", ".join(f"{k} {n}" for k, n in sorted(v["stops"]["by_fault"].items()))
    failures = []
    for name, counts in v["failures"]["counts"].items():
        total = sum(counts.values())
        if total:
            by = ", ".join(f"{k} {n}" for k, n in sorted(counts.items()))
            failures.append(f"{name.replace('_', ' ')} {total} ({by})")
    kept = len(v["stops"]["sample"])
    return [
        "  camera verdict survived (no stop): "
        + (", ".join(names.get(k, k) for k in v["survived"]) or "none"),
        "  camera verdict stopped it safely: "
        + (
            f"{stopped} (stale-camera stops {v['stops']['count']}: {labels}; "
            f"{fr['frozen_spells']} frozen spells met); latched {after['count']}, each reset by "
            f"the operator after {after['operator_reset_s']:g} s, running again after "
            f"{after['ran_again']} of them (stops kept: the first {kept}, all counted)"
            + (
                f"; {v['own_faults_judged_with_a_camera_stop']} of the soak's own faults were "
                "judged with a camera stop in their window"
                if v.get("own_faults_judged_with_a_camera_stop")
                else ""
            )
            if stopped
            else "none"
        ),
        "  camera verdict failures by the camera fault before them (1 s; a missed goal: its "
        "period): " + ("; ".join(failures) or "none"),
    ]


def _check_lines(report: dict) -> list[str]:
    """The failed checks (known ones marked) and the baseline's comparison."""
    lines = []
    b = report.get("baseline")
    known = {k["check"] for k in (b or {}).get("known_failures", [])}
    for name, c in report["checks"].items():
        if not c["passed"]:
            tag = "FAILED (known: in the baseline too)" if name in known else "FAILED"
            lines.append(f"  {tag} {name}: {', '.join(c['failed_sessions'])}")
    if b is not None:
        if b["passed"]:
            lines.append(f"  baseline     no regression against {b['path']}")
        if b.get("violation_basis"):
            lines.append(f"  baseline     violation rates compared with {b['violation_basis']}")
        for r in b["regressions"]:
            lines.append(f"  REGRESSION   {r['message']}")
    return lines


def exhibition_lines(s: dict) -> list[str]:
    """A motion-tracking session's exhibition: its clips (completed, falls, joint error,
    interventions) and the heat report (:func:`sim2real.eval.soak.exhibition.heat_report`)."""
    x = s.get("exhibition")
    if not x:
        return []
    h, clips = x["heat"], x["clips"]

    def spread(key: str, form: str, unit: str) -> str:
        v = [c[key] for c in clips if c.get(key) is not None]
        return f"{min(v):{form}}-{max(v):{form}} {unit}" if v else "n/a"

    iv = [c["interventions"] for c in clips]
    cut = ", the last cut short by the session's end" if h.get("unfinished") else ""
    lines = [
        f"  exhibition   {s['id']}: {h['clips']} clips of {x['clip_s']:.1f} s (then "
        f"{x['stand_s']:g} s to home, {x['rest_s']:g} s standing); completed {h['completed']}, "
        f"falls {h['falls']}"
        + (f" ({h['rest_falls']} in the rests after their clips)" if h.get("rest_falls") else "")
        + f"{cut}; per clip: joint error {spread('joint_rms_rad', '.3f', 'rad RMS')}, "
        f"anchor error {spread('anchor_error_deg_mean', '.1f', 'deg mean')}, MPJPE "
        f"{spread('mpjpe_mm', '.1f', 'mm')}, guard interventions "
        f"{min(iv, default=0)}-{max(iv, default=0)} ticks"
    ]
    if h["derating"]:
        which = ", ".join(f"{j} (clip {n})" for j, n in h["derating"].items())
        before, after = h["joint_rms_rad_before"], h["joint_rms_rad_derated"]
        effect = (
            f"joint error {before:.3f} rad RMS before, {after:.3f} derated"
            if before is not None and after is not None
            else "no clip before it to compare"
        )
        lines.append(f"  heat         windings reaching derating: {which}; {effect}")
    else:
        hot = ", ".join(f"{j} {c:.1f}" for j, c in h["hottest"].items())
        lines.append(
            f"  heat         no winding reached derating in {h['clips']} clips (hottest degC: "
            f"{hot or 'n/a'})"
        )
    cr = x.get("clips_and_rests")
    if cr:
        clips, rests = cr["clips"], cr["rests"]
        worst = clips["worst_end_offset_m"]
        lines.append(
            f"  clips/rests  clips: base travel {clips['travel_m']:.2f} m, the worst ended "
            + (f"{worst:.2f} m" if worst is not None else "n/a")
            + f" from its root path's end, guard interventions {clips['interventions']} ticks, "
            f"hard limit {clips.get('hard_limit_ticks', 0)}; "
            f"rests ({rests['count']}): travel {rests['travel_m']:.2f} m"
            + (f" (worst {rests['worst_travel_m']:.2f} m)" if rests["count"] else "")
            + f", guard interventions {rests['interventions']} ticks, hard limit "
            f"{rests.get('hard_limit_ticks', 0)}"
            + (f"; LEFT ITS SPOT in plays {cr['left_spot'][:10]}" if cr["left_spot"] else "")
        )
    v = s.get("own_loop_verdict")
    if v:
        hard, iv = v["hard_limits"], v["interventions"]
        joints = ", ".join(
            f"{j} {f['ours']}/{f['own']}" + (f" ({f['stack']} the stack's)" if f["stack"] else "")
            for j, f in hard["joints"].items()
        )
        lines.append(
            f"  own loop     hard-limit ticks ours/own loop's per joint over {hard['clip_s']:.0f} / "
            f"{hard['own_clip_s']:.0f} s of clip: {joints or 'none'}; the stack's "
            f"{hard['stack_ticks']}; interventions {100 * iv['ours']:.3f} % of ticks, the guard "
            f"replayed on the own loop {100 * iv['own']:.3f} %"
        )
    c = x["reference_contacts"]
    if c["frames_touching"]:
        lines.append(
            f"  clip contact {c['frames_touching']} of {c['frames']} reference frames touch in the "
            f"robot's collision model (worst {1000 * c['worst_depth_m']:.0f} mm): "
            f"{x['reference_contact_ticks']} self-collision ticks counted apart, not violations"
        )
    return lines
