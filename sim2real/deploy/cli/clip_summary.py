"""The motion-tracking lines of ``deploy-run``'s summary (:mod:`sim2real.deploy.cli.run_summary`):
the clip, its errors, its own self-contacts, what followed it (a hand-over or a judged hold) and
the base's travel against the clip's root path, with the finding of a base that left its spot
(exit 5: :mod:`sim2real.deploy.tasks.motion.travel`).
"""

from __future__ import annotations


def print_tracking(t: dict, loco: dict | None, excused: dict | None = None) -> None:
    """Print the motion tracking: the clip, its share completed, joint and anchor errors, falls."""
    print(
        f"  motion clip       {t['clip']}: {t['frames']} frames at {t['fps']:g} Hz "
        f"({t['length_s']:.2f} s, {t['playback']}), played {t['plays']}x, "
        f"{100 * t['completed']:.1f} % completed"
    )
    if t["ticks"]:
        groups = ", ".join(f"{g} {v:.3f}" for g, v in t["joint_rms_rad"].items())
        print(
            f"  joint error       {t['joint_rms_rad_all']:.3f} rad RMS ({groups}) over "
            f"{t['ticks']} ticks ({t['judged_on']})"
        )
        print(
            f"  anchor error      {t['anchor_error_deg_mean']:.2f} deg mean, "
            f"{t['anchor_error_deg_max']:.2f} deg max (torso orientation); MPJPE "
            f"{t['mpjpe_mm']:.1f} mm ({t['bodies']} bodies, root-relative)"
        )
    if t.get("stand_s") is not None and t.get("end_from_home_rad_rms") is not None:
        print(
            f"  stand             after the clip, to home over {t['stand_s']:g} s; ends "
            f"{t['end_from_home_rad_rms']['all']:.3f} rad RMS from home ("
            + ", ".join(f"{g} {v:.3f}" for g, v in t["end_from_home_rad_rms"].items() if g != "all")
            + ")"
        )
    plays = t.get("plays_logged") or []
    if plays:
        per = ", ".join(f"{p['interventions']} ({p['safety_interventions']})" for p in plays[:8])
        more = f", ... ({len(plays)} plays)" if len(plays) > 8 else ""
        print(f"  guard per play    intervention ticks (of them safety): {per}{more}")
    _print_reference_contacts(t.get("reference_contacts"), excused)
    if loco is not None:
        print(f"  falls             {loco['falls']}")
    _print_after_clip(t)


#: What each way of ending a clip is, as its stack does it (the summary's words).
FOLLOWS = {
    "handover": "handed over to '{policy}' at the clip's end{at}{blend} (rl_sar's fsm hands "
    "its dance to its locomotion policy)",
    "stand": "a hold judged: to home over {stand_s:g} s, then home (holosoma's default pose "
    "append)",
    "once": "a hold judged: its last frame (BeyondMimic's controller holds it)",
    "hold": "a hold judged: its last frame (BeyondMimic's controller holds it)",
    "default_pose": "the policy off at the clip's end{at}, the PD loop holding home, ramped to "
    "over {ramp_s:g} s from its last target (unitree_rl_gym's move_to_default_pos, "
    "default_pos_state); judged",
    "loop": "the clip again (a loop)",
    "exhibition": "to home, a rest at home, the clip again (an exhibition)",
}


def after_clip_text(t: dict) -> str:
    """What followed the clip, in the summary's words (:data:`FOLLOWS`)."""
    after = t.get("after_clip") or {"follows": t["playback"]}
    blend = after.get("blend_s") or 0.0
    return FOLLOWS.get(after["follows"], after["follows"]).format(
        policy=after.get("policy"),
        blend=f", blended over {blend:g} s" if blend else ", at once",
        at=f" ({after['at_s']:.2f} s)" if after.get("at_s") is not None else " (not reached)",
        stand_s=t.get("stand_s") or 0.0,
        ramp_s=blend,
    )


def _print_after_clip(t: dict) -> None:
    """Print what followed the clip, the base's travel against the clip's root path (the
    env farthest from it) and the finding of a base that left its spot."""
    travel = t.get("travel")
    figures = [f for f in (travel or {}).get("envs", []) if f is not None]
    print(f"  after the clip    {after_clip_text(t)}")
    if not figures:
        return
    e, f = max(enumerate(figures), key=lambda ef: ef[1]["end_offset_m"])
    env = f" (env {e}, the farthest)" if len(figures) > 1 else ""
    print(
        f"  base travel       during the clip {f['base_travel_m']:.2f} m, turned "
        f"{f['base_turn_deg']:+.1f} deg (the clip's root path: {f['clip_root_travel_m']:.2f} m, "
        f"{f['clip_turn_deg']:+.1f} deg)"
        + (
            f"; at its end {f['clip_end_offset_m']:.2f} m from the path's end"
            if f["clip_end_offset_m"] is not None
            else f"; {f['clip_s']:.1f} s of it reached"
        )
        + f"{env} ({travel['judged_on']})"
    )
    if f["after_clip_s"] is not None:
        print(
            f"  after it          {f['after_clip_travel_m']:.2f} m in {f['after_clip_s']:.1f} s "
            f"(farthest {f['after_clip_max_m']:.2f} m), turned {f['after_clip_turn_deg']:+.1f} deg; "
            f"guard interventions {travel.get('after_clip_interventions', 0)} ticks, hard limit "
            f"{travel.get('after_clip_hard_limit_ticks', 0)}, any violation "
            f"{travel.get('after_clip_violation_ticks', 0)} (true state, every env)"
        )
    print(
        f"  base ends         {f['end_offset_m']:.2f} m from where the clip's root path "
        + ("ends" if f["after_clip_s"] is not None else "is at the time reached")
    )
    off = travel.get("off_path") or []
    if off:
        why = []
        if f["end_offset_m"] > travel["off_path_m"]:
            why.append(f"ends {f['end_offset_m']:.2f} m from the clip's end (bound "
                       f"{travel['off_path_m']:g} m)")  # fmt: skip
        if (f["after_clip_max_m"] or 0.0) > travel["after_clip_m"]:
            why.append(f"went {f['after_clip_max_m']:.2f} m after the clip (bound "
                       f"{travel['after_clip_m']:g} m)")  # fmt: skip
        print(
            f"  LEFT ITS SPOT     {len(off)} of {len(travel['envs'])} envs; the farthest "
            f"{'; '.join(why)}: the run fails (exit code 5)"
        )


def _print_reference_contacts(c: dict | None, excused: dict | None) -> None:
    """Print the clip's own self-contacts (the reference posed in the robot's collision model)
    and the self-collision ticks counted apart as its contacts."""
    if not c or not c["frames_touching"]:
        return
    pairs = ", ".join(f"{k} {n}" for k, n in list(c["pairs"].items())[:4])
    print(
        f"  clip self-contact {c['frames_touching']} of {c['frames']} reference frames (the clip, "
        f"then its transition to home) touch in "
        f"the robot's collision model (worst {1000 * c['worst_depth_m']:.0f} mm deep; {pairs}): "
        "the description's collision geometry (a convex hull of a concave mesh, say) under "
        "the clip, not the policy's doing"
    )
    if excused:
        print(
            f"  reference contact {excused['ticks']} self-collision ticks on pairs the clip "
            f"itself touches then (+-{c['window_s']:g} s): counted apart, not violations"
        )
