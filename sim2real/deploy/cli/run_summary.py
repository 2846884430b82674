"""The summary ``deploy-run`` prints at the end of a run (:func:`print_summary`).

It reads the report :func:`sim2real.deploy.cli.deploy_run.run` builds (the JSON of ``--report``): goals or
the walk, violations (true state in simulation) and interventions, faults, the servo bus, peak
winding temperatures, motion, the costs of the tick, the monitors and the stages, deadlines and the
real-time settings, the final state and the exit code. It only prints; the exit code is decided
before.
"""

from __future__ import annotations

import math

from sim2real.deploy.cli.clip_summary import print_tracking
from sim2real.deploy.cli.own_loop_check import own_loop_lines

#: deg of heading change the commands did not ask for past which the summary flags a drift (our
#: choice: a straight 20 s walk that turns 30 deg ends 5 m off a 10 m line).
HEADING_DRIFT_DEG = 30.0
#: Stale-sensor stops the summary prints a line for (the report has them all).
STALE_LINES = 3


def print_summary(r: dict) -> None:
    """Print the human-readable summary of a ``deploy-run`` report (the dict ``--report`` writes
    as JSON), one line per topic."""
    print(
        f"deploy-run: {r['robot']}, {r['control_mode']} control at {r['control_rate_hz']:.0f} Hz, "
        f"{r['duration_s']:.1f} s {'wall-clock' if r['realtime'] else 'simulated'} "
        f"in {r['wall_s']:.2f} s"
    )
    _print_task(r)
    _print_estimation(r)
    _print_violations(r)
    _print_interventions(r)
    _print_chunks(r.get("chunks"))
    _print_faults(r)
    _print_bus(r)
    _print_ros2(r)
    _print_operator(r)
    _print_temperatures_and_motion(r)
    _print_costs_and_deadlines(r)
    _print_final_state(r)


def _print_chunks(c: dict | None) -> None:
    """A chunked policy's lines: its cadence and the peak joint jerk after a chunk boundary
    against after a policy tick inside a chunk (medians of the peaks, rad/s^3), of the joints,
    the guard's target (no smoother) and the smoothed command
    (:class:`sim2real.deploy.rig.chunk_hook.ChunkHook`)."""
    if not c:
        return
    scheme = (
        f"temporal ensembling (coeff {c['temporal_ensemble_coeff']:g})"
        if c["temporal_ensemble_coeff"] is not None
        else f"{c['n_action_steps']} of {c['chunk_size']} actions per chunk"
    )
    print(
        f"  chunks: policy at {c['policy_rate_hz']:g} Hz beside the {c['servo_rate_hz']:g} Hz "
        f"servo loop, {scheme}; {c['policy_ticks']} policy ticks, {c['network_calls']} network "
        f"calls; RUNNING: policy ticks per chunk {c['policy_ticks_per_chunk']}, servo ticks per "
        f"policy tick {c['servo_ticks_per_policy_tick']}"
    )
    if "inference" in c:
        print(
            f"  chunks: {c['inference']} inference; network calls on the servo thread "
            f"{c['network_calls_on_servo_thread']}; chunks not done when taken "
            f"{c['chunk_waits']} (longest wait {c['chunk_wait_max_ms']:.1f} ms), late "
            f"{c['late_chunks']}"
        )
    names = {
        "position": f"joints ({c['joints']})",
        "target": "target, no smoother",
        "command": "command, smoothed",
    }
    for what, label in names.items():
        f = c[what]
        inside = (
            "no policy tick inside a chunk"
            if f["inside"] == 0
            else f"inside a chunk {f['inside_median']:.3g} (max {f['inside_max']:.3g})"
        )
        print(
            f"  chunk jerk, {label}: after a boundary {f['boundary_median']:.3g} (max "
            f"{f['boundary_max']:.3g}) rad/s^3 over {f['boundaries']} boundaries; {inside}"
        )


def _print_task(r: dict) -> None:
    """Print the task lines: goals reached, or the walk, its heading and its true falls."""
    g, loco = r["goals"], r.get("locomotion")
    if g is not None:
        rate = f"{100 * g['success_rate']:.1f} %" if g["success_rate"] is not None else "n/a"
        print(
            f"  goals reached     {g['reached']}/{g['issued']} within {g['within_s']:.1f} s "
            f"({rate})"
        )
    # a clip (or a phase-clocked dance's motion) commands the policy: no velocity lines
    clip = r.get("tracking") is not None or r.get("motion_phase") is not None
    if loco is not None and not clip:
        _print_walk(loco)
    if loco is not None and not clip and loco.get("heading_change_deg") is not None:
        _print_heading(loco)
    if r.get("tracking") is not None:
        v = r.get("violations") or {}
        excused = {"ticks": v.get("reference_contact_ticks", 0)}
        print_tracking(r["tracking"], loco, excused)
    if r.get("motion_phase") is not None:
        _print_motion_phase(r["motion_phase"], loco)
    if loco is not None and loco.get("true_falls", 0) > loco.get("runtime_falls", 0):
        print(
            f"  TRUE FALLS        {loco['true_falls']} of the true base (sim), of which the "
            f"runtime detected {loco['runtime_falls']}: the run fails (exit code 2)"
        )


def _print_motion_phase(p: dict, loco: dict | None) -> None:
    """Print a phase-clocked policy's motion line (:mod:`sim2real.deploy.rig.motion_phase_hook`)."""
    rms = "n/a" if p["joint_rms_rad"] is None else f"{p['joint_rms_rad']:.4f} rad RMS"
    falls = "n/a" if loco is None else loco["falls"]
    print(
        f"  motion phase      t / T over T = {p['length_s']:g} s: played {p['plays']}x, "
        f"{100 * p['completed']:.1f} % completed, {p['stopped']} cut short by a stop; joint "
        f"error against the policy's targets {rms} over {p['ticks']} ticks; falls in the run {falls}"
    )


def _print_walk(loco: dict) -> None:
    """Print the walk line: distance, mean forward speed, tracking and falls."""
    speed, track = loco["mean_forward_speed_m_s"], loco["tracking_success"]
    yaw = loco.get("yaw_tracking_success")
    print(
        f"  walked            {loco['distance_m']:.2f} m, mean forward speed "
        + (f"{speed:.3f} m/s" if speed is not None else "n/a")
        + f" (command {', '.join(f'{c:g}' for c in loco['command'][0])}); tracking "
        + (f"{100 * track:.1f} %" if track is not None else "n/a")
        + f" of RUNNING time within {loco['tracking_tolerance_m_s']} m/s; yaw rate "
        + (f"{100 * yaw:.1f} %" if yaw is not None else "n/a")
        + f" within {loco.get('yaw_tracking_tolerance_rad_s', 0.2)} rad/s; falls {loco['falls']}"
        + (f" ({_causes(loco['falls_by_cause'])})" if loco.get("falls_by_cause") else "")
        + (f"; operator stops {loco['operator_stops']}" if loco.get("operator_stops") else "")
    )


def _print_heading(loco: dict) -> None:
    """Print the heading line: the turn against the commanded one, displacement, base height."""
    turn, asked = loco["heading_change_deg"], loco["commanded_turn_deg"]
    height = loco.get("base_height_m")
    flag = abs(turn - asked) > HEADING_DRIFT_DEG
    hold = loco.get("heading_hold_gain")
    moved = loco.get("displacement_m")
    print(
        f"  heading           turned {turn:+.1f} deg (the commands asked {asked:+.1f})"
        + (" - A TURN THE COMMAND DID NOT ASK FOR" if flag else "")
        + (f", held at gain {hold:g}/s" if hold else "")
        + (
            f"; displaced {moved[0]:+.2f} m along its first heading, {moved[1]:+.2f} across"
            if moved is not None
            else ""
        )
        + (
            f"; base height {height:.3f} m by its kinematics "
            f"(standing {loco['standing_height_m']:.3f})"
            if height is not None and loco.get("standing_height_m")
            else ""
        )
    )


def _print_estimation(r: dict) -> None:
    """Print the base estimate against the true base (simulation only)."""
    est = r.get("estimation")
    if est is not None:
        att, bias = est["attitude_error_deg"], est["velocity_bias_fraction"]
        print(
            f"  base estimate vs truth (sim)  attitude error mean {att['mean']:.2f} deg, "
            f"p95 {att['p95']:.2f}; forward speed {est['forward_speed_m_s']['estimated']:.3f} "
            f"against {est['forward_speed_m_s']['true']:.3f} m/s ("
            + (f"bias {100 * bias:+.1f} %" if bias is not None else "bias n/a")
            + f"), planar RMS {est['velocity_rms_m_s']:.3f} m/s; vertical bias "
            f"{est['vertical_velocity_m_s']['bias']:+.3f} m/s, RMS "
            f"{est['vertical_velocity_m_s']['rms']:.3f}"
        )


def _print_violations(r: dict) -> None:
    """Print the violation lines (true state), or the guard's hard-limit stops on hardware."""
    v = r["violations"]
    if v is not None:
        text = ", ".join(f"{k} {n}" for k, n in v["by_type"].items())
        print(f"  violations (true state, sim)  ticks: {text}")
        down = v.get("while_down") or {}
        if down.get("any"):
            text = ", ".join(f"{k} {n}" for k, n in down.items() if k != "any" and n)
            print(f"  violations lying down after a stop (true state, sim)  ticks: {text}")
        for line in own_loop_lines(r.get("own_loop")):
            print(line)
        within = r.get("within_own_loop")
        if within:
            kinds = ", ".join(f"{k} {n}" for k, n in within.items())
            print(f"  within own loop   {kinds} ticks: within what the policy's own loop has")
        hard = r.get("hard_violations")
        if hard:
            kinds = ", ".join(f"{k} {n}" for k, n in hard.items())
            print(f"  HARD VIOLATIONS   {kinds} ticks (true state): the run fails (exit code 1)")
            for line in hard_violation_lines(v):
                print(f"    {line}")
    else:
        print(
            "  violations        n/a (no ground truth on hardware; the guard's hard-limit "
            f"stops: {r['faults']['by_cause']['hard_limit']})"
        )


def hard_violation_lines(v: dict) -> list[str]:
    """What a run's hard violations were, one line each (``deploy-run``'s summary under HARD
    VIOLATIONS): every joint past its hard limit with its ticks and how far past it was at most
    (rad and degrees; up, then lying down after a stop), every joint above its velocity or
    effort limit with its ticks and how far above (rad/s, N m), and every self-collision pair
    that touched with its ticks; from the report's ``violations`` (:meth:`Rig.violation_report
    <sim2real.deploy.rig.rig.Rig.violation_report>`). Empty where the report holds none of them
    (one written before they were kept)."""
    lines = []
    for key, where in (("hard_limit_joints", ""), ("hard_limit_joints_while_down", " lying down")):
        for joint, j in (v.get(key) or {}).items():
            depth = j["depth_rad"]
            lines.append(
                f"hard_limit{where}: {joint} past its hard limit on {j['ticks']} ticks, at most "
                f"{depth:.4f} rad ({math.degrees(depth):.2f} deg) past it"
            )
    for kind, unit in (("velocity", "rad/s"), ("effort", "N m")):
        for joint, j in (v.get(f"{kind}_joints") or {}).items():
            lines.append(
                f"{kind}: {joint} above its {kind} limit on {j['ticks']} ticks, at most "
                f"{j['excess']:.3g} {unit} above it"
            )
    for pair, ticks in (v.get("self_collision_pairs") or {}).items():
        lines.append(f"self_collision: {pair.replace('|', ' and ')} in contact on {ticks} ticks")
    return lines


def _print_interventions(r: dict) -> None:
    """Print the interventions line: % of ticks per check and the soft-band warning."""
    iv = r["interventions"]
    text = ", ".join(
        f"{k} {100 * c['fraction']:.2f}" for k, c in iv["checks"].items() if c["count"]
    )
    warn = iv["warnings"]["soft_band_estimate"]
    print(
        f"  interventions (% of ticks)    any {100 * iv['any']['fraction']:.2f}"
        + (f" ({text})" if text else "")
        + f"; warning: estimate in soft band {100 * warn['fraction']:.2f}"
    )


def _print_faults(r: dict) -> None:
    """Print the faults line, the estimator's warning and the servo errors."""
    f = r["faults"]
    causes = ", ".join(f"{k} {n}" for k, n in f["by_cause"].items() if n) or "none"
    print(
        f"  faults            non-finite actions {f['non_finite_actions']}, safe stops "
        f"{f['safe_stops']} ({causes}"
        + (
            f"; not at rest, timed out {f['safe_stop_timeouts']}"
            if f.get("safe_stop_timeouts")
            else ""
        )
        + f"); estimator: stale {f['estimator']['stale_readings']}, "
        f"missing {f['estimator']['missing_readings']}, re-inits "
        f"{f['estimator']['reinitializations']}"
    )
    if f["estimator"].get("warning"):
        print(f"  WARNING           {f['estimator']['warning']}")
    _print_stale_stops(f)
    for text in f.get("drive_errors", []):
        print(f"  servo error       {text}")
    for text in f.get("smoothing_errors", []):
        print(f"  smoother          {text[:300]}")


def _print_stale_stops(f: dict) -> None:
    """One line per ``stale_sensor`` stop (the first ``STALE_LINES``): when, the verdict (what
    went stale, the other side, our side) and the stale joints (and the IMU)."""
    stops = f.get("stale_stops") or []
    for s in stops[:STALE_LINES]:
        joints = list(s["joints"])
        shown = ", ".join(joints[:4]) + (f" (+{len(joints) - 4} more)" if len(joints) > 4 else "")
        stale = ([f"joints {shown}"] if joints else []) + (
            ["the IMU"] if s.get("imu_s") is not None else []
        )
        print(
            f"  stale sensor      t {s['t_s']:.2f} s"
            + (f" env {s['env']}" if s["env"] else "")
            + f": {s['verdict']}; {'; '.join(stale)}"
        )
    more = len(stops) - STALE_LINES + f.get("stale_stops_dropped", 0)
    if more > 0:
        print(f"  stale sensor      {more} more (report.json faults.stale_stops)")


def _print_bus(r: dict) -> None:
    """Print the bus line: DDS, ros2_control or a servo bus, if the backend has one."""
    b = r.get("bus")
    if b and b.get("transport") == "dds":
        _print_dds(b)
    elif b and b.get("transport") == "ros2":
        rd, wr, age = b["read_us"], b["write_us"], b["state_age_us"]
        print(
            f"  ros2_control      joint_states {b['joint_states_received']} at "
            f"{b['joint_states_rate_hz']:.0f} Hz, stale reads {b['stale_reads']}, missing "
            f"joint readings {b['missing_joint_readings']}; {b['commands_sent']} commands on "
            f"{b['command_topic']}; read p50 {rd['p50_us']:.0f} p99 {rd['p99_us']:.0f} us, "
            f"write p50 {wr['p50_us']:.0f} p99 {wr['p99_us']:.0f} us, state age p50 "
            f"{age['p50_us']:.0f} us"
        )
    elif b:
        rd, wr = b["read_us"], b["write_us"]
        drops = ", ".join(f"{k} {n}" for k, n in b["dropouts"].items())
        print(
            f"  bus               {b['protocol']} {b['port']} at {b['baudrate']} bit/s: "
            f"{b['sync_reads']} sync reads, dropouts {drops} "
            f"({100 * b['dropout_fraction']:.2f} % of replies); read p50 {rd['p50_us']:.0f} "
            f"p99 {rd['p99_us']:.0f} us, write p50 {wr['p50_us']:.0f} us"
        )


def _print_ros2(r: dict) -> None:
    """Print the ROS 2 node line (--ros2): topics published and received, skips, time-outs."""
    n = r.get("ros2")
    if n:
        pub = ", ".join(f"{k} {v}" for k, v in n["published"].items() if v)
        got = ", ".join(f"{k} {v}" for k, v in n["received"].items() if v) or "nothing"
        print(
            f"  ros2 node         {n['node']}: published {pub}; received {got}; ticks skipped "
            f"{n['ticks_skipped']}, cmd_vel time-outs {n['cmd_vel_timeouts']}"
        )


def _print_operator(r: dict) -> None:
    """Print the operator's line (--operator): its transitions, refusals and policy switches,
    and the hand-overs' largest steps against the policies' own."""
    o = r.get("operator")
    if o:
        print(
            f"  operator          {o['mapping']} from {', '.join(o['sources'])}: "
            f"{len(o['transitions'])} transitions, {len(o['refused'])} refused, "
            f"{o['switches']} policy switches, dead-man {o['deadman_events']}; now "
            f"{o['final_state']} ({o['policy']})"
        )
        print(
            f"  hand-overs        largest target step {o['handover_max_target_step']:.3f}, "
            f"command step {o['handover_max_command_step']:.3f} "
            f"({o['handover_max_command_step_share_of_limit']:.2f} of the smoother's limit a "
            f"period); the policies' own: {o['steady_max_target_step']:.3f}, "
            f"{o['steady_max_command_step']:.3f} ({o['units']})"
        )


def _print_temperatures_and_motion(r: dict) -> None:
    """Print the peak winding temperatures, the max joint speed and the mean |jerk|."""
    temps = ", ".join(f"{k} {t:.1f}" for k, t in r["peak_winding_temperature_c"].items())
    print(f"  peak winding degC {temps}")
    speed = max(r["max_joint_speed_rad_s"].values())
    jerk = ", ".join(f"{k} {v:.0f}" for k, v in r["mean_abs_jerk_rad_s3"].items())
    source = "true" if r["violations"] is not None else "estimated"
    print(f"  max joint speed   {speed:.2f} rad/s; mean |jerk| rad/s^3 ({source}, RUNNING) {jerk}")


def _print_costs_and_deadlines(r: dict) -> None:
    """Print the tick, monitor and stage costs, the deadlines and the real-time settings."""
    t = r["tick_cost_us"]
    print(
        f"  tick cost (us)    p50 {t['p50_us']:.1f}  p99 {t['p99_us']:.1f}  "
        f"p99.9 {t['p99.9_us']:.1f}  (runtime, without physics)"
    )
    m = r["monitor_cost_us"]
    print(
        f"  monitors (us)     p50 {m['p50_us']:.1f}  p99 {m['p99_us']:.1f}  (violations + "
        "interventions, per tick, outside the runtime)"
    )
    stages = "  ".join(f"{k} {s['p50_us']:.0f}" for k, s in r["stage_cost_us"].items())
    print(f"  stages p50 (us)   {stages}")
    d = r["deadline"]
    line = f"  deadlines         overruns {d['overruns']}, missed periods {d['missed_periods']}"
    if d["jitter_us"]:
        j = d["jitter_us"]
        line += f", jitter p50 {j['p50_us']:.1f} p99 {j['p99_us']:.1f} p99.9 {j['p99.9_us']:.1f} us"
    print(line)
    long = [t for t in d.get("long_ticks", []) if t["overran"]][:3]
    if long:
        print(
            "  longest overruns  "
            + "; ".join(f"{t['period_us'] / 1e3:.1f} ms {t['cause']}" for t in long)
            + " (report.json deadline.long_ticks)"
        )
    _print_realtime_settings(r)


def _print_realtime_settings(r: dict) -> None:
    """Print the real-time line: wait mode, scheduler, CPUs, memory lock (when asked for)."""
    rts, d = r.get("realtime_settings"), r["deadline"]
    if rts and (r["realtime"] or rts["requested"]["cpus"] is not None):
        sched = rts["scheduler"] or "scheduler unknown"
        if rts["scheduler"] == "SCHED_FIFO":
            sched += f" {rts['priority']}"
        print(
            f"  real time         wait {d.get('wait') or 'none (lockstep)'}, {sched}, CPUs "
            f"{','.join(map(str, rts['cpus']))}, memory "
            f"{'locked' if rts['memory_locked'] else 'not locked'}"
        )


def _print_final_state(r: dict) -> None:
    """Print the final state and its causes, a divergence and the exit code."""
    print(
        f"  final state       {', '.join(r['final_state'])}"
        + (f" ({', '.join(c for c in r['final_cause'] if c)})" if any(r["final_cause"]) else "")
    )
    if r["diverged"]:
        print(f"  SIMULATION DIVERGED: {r['diverged']}")
    print(f"  exit code         {r['exit_code']}")


def _causes(counts: dict[str, int]) -> str:
    """``hard_limit 1, fall 2`` from ``{cause: count}``."""
    return ", ".join(f"{cause} {n}" for cause, n in counts.items())


def _print_dds(b: dict) -> None:
    """The DDS line of a Unitree robot's run (:meth:`sim2real.deploy.backends.unitree.backend.
    UnitreeBackend.bus_summary`)."""
    rd, wr, age = b["read_us"], b["write_us"], b["state_age_us"]
    drops = ", ".join(f"{k} {n}" for k, n in b["dropouts"].items())
    where = f"{b['interface'] or 'default interface'}, domain {b['domain_id']}"
    print(
        f"  bus               DDS {b['family']} on {where}: LowState {b['lowstate_received']} "
        f"at {b['lowstate_rate_hz']:.0f} Hz, dropouts {drops} "
        f"({100 * b['dropout_fraction']:.2f} %); LowCmd {b['lowcmd_sent']}; read p50 "
        f"{rd['p50_us']:.0f} p99 {rd['p99_us']:.0f} us, write p50 {wr['p50_us']:.0f} p99 "
        f"{wr['p99_us']:.0f} us; state age p50 {age['p50_us']:.0f} p99 {age['p99_us']:.0f} us"
    )
    if b.get("mode_machine") is not None:
        print(f"  mode_machine      {b['mode_machine']}")
    if b.get("held_at_home_s") is not None:
        print(
            f"  bring-up          {b['bringup_s']:.2f} s, then held at home "
            f"{b['held_at_home_s']:.2f} s before the policy's first command"
        )
    if b["motor_lost"]:
        lost = ", ".join(f"motor {k} {n}" for k, n in b["motor_lost"].items())
        print(f"  motor lost        {lost} packets")
