"""The table ``python -m bench`` prints: every measured section, the targets (PASS / FAIL) and
each target against the last full run."""

from __future__ import annotations

import math

from bench.targets import compare_history
from bench.tick import FLOORS_OF_STAGE


def _f(x, spec: str = ".1f") -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:{spec}}"


def _pct(s: dict) -> str:
    return f"{_f(s['p50_us']):>8} {_f(s['p99_us']):>8} {_f(s['p99.9_us']):>9} {_f(s['mean_us']):>8}"


def _ran(sections: dict, name: str, add) -> bool:
    """Whether item ``name`` has figures to render: False when it is not in ``sections``, or
    when it was skipped (its section then one line, ``== name: skipped: why``); a section that
    is there starts with a blank line."""
    if name not in sections:
        return False
    add("")
    why = sections[name].get("skipped")
    if why:
        add(f"== {name}: skipped: {why}")
    return not why


def render(results: dict) -> str:
    """The results as a plain-text report (what ``python -m bench`` prints)."""
    lines: list[str] = []
    add = lines.append
    m = results["machine"]
    add(
        f"bench: {m['platform']}, python {m['python']}, {m['cpu_count']} CPUs, load average at "
        f"start {m['load_average_at_start']}{' [QUICK: rough figures]' if results['quick'] else ''}"
    )
    sec = results["sections"]
    pct_head = f"{'p50 us':>8} {'p99 us':>8} {'p99.9 us':>9} {'mean us':>8}"

    if _ran(sec, "plant", add):
        add(f"== plant: MuJoCo alone, per control tick ({sec['plant']['ticks']} ticks)")
        add(f"{'robot':6} {'mode':9} {'what':8} {'dec':>3} {pct_head}")
        for r in sec["plant"]["rows"]:
            add(f"{r['robot']:6} {r['mode']:9} {r['what']:8} {r['decimation']:>3} {_pct(r)}")

    if _ran(sec, "inference", add):
        r = sec["inference"]
        add(f"== inference: batch-1 policy calls ({r['policy']}; {r['calls']} calls)")
        for e in r["exports"]:
            add(f"   export ({e['name']}) {e['seconds']:.2f} s")
        add(f"   {'':36} {'median us':>10} {'p99 us':>8}")
        for row in r["rows"]:
            add(f"   {row['name']:36} {row['median_us']:10.1f} {row['p99_us']:8.1f}")

    for robot, t in sec.get("tick", {}).get("robots", {}).items():
        add("")
        add(
            f"== tick: {robot}, {t['control_rate_hz']:.0f} Hz, decimation {t['decimation']}, "
            f"{t['ticks']} ticks of each loop in {t['rounds']} alternating rounds"
        )
        full, bare = t["full"], t["bare"]
        add(f"   full runtime (rt.latency)        {pct_head}")
        for s, v in full["stages"].items():
            add(f"     {s:30} {_pct(v)}")
        add(f"     {'= overhead (rt.tick_cost)':30} {_pct(full['overhead'])}")
        add(f"     {'= tick incl. physics':30} {_pct(full['tick'])}")
        if bare["tick"]["samples"]:
            add(f"   bare loop (torch eager, PD)      {pct_head}")
            for s, v in bare["stages"].items():
                add(f"     {s:30} {_pct(v)}")
            add(f"     {'= overhead (tick - mj_step)':30} {_pct(bare['overhead'])}")
            add(f"     {'= tick incl. physics':30} {_pct(bare['tick'])}")
        else:
            add("   bare loop: none (a shipped legged policy; the bare loop has no base state)")
        fl = t.get("floors")
        if fl is not None:
            add(f"   floors: the library calls alone  {pct_head}   stage p50 - floor p50")
            last = {fs[-1]: s for s, fs in FLOORS_OF_STAGE.items()}  # glue on a stage's last
            for s, v in fl["stages"].items():
                stage = last.get(s)
                glue = f"   {stage} {fl['glue_p50_us'][stage]:+.1f} us" if stage else ""
                add(f"     {s:30} {_pct(v)}{glue}")
            add(f"     {'= overhead floor (no mj_step)':30} {_pct(fl['overhead'])}")
        r = t["ratio"]
        add(
            f"   full / bare: tick p50 {_f(r['tick_p50'], '.2f')}x, mean "
            f"{_f(r['tick_mean'], '.2f')}x; overhead p50 {_f(r['overhead_p50'], '.2f')}x, "
            f"mean {_f(r['overhead_mean'], '.2f')}x   (runtime final state "
            f"{','.join(full['final_state'])}, {full['ticks_not_running']} ticks not RUNNING)"
        )

    for robot, s in sec.get("session", {}).get("robots", {}).items():
        add("")
        add(
            f"== session: {robot} deploy-run, {s['control_rate_hz']:.0f} Hz control, "
            f"{s['physics_rate_hz']:.0f} Hz physics: {s['simulated_s']:.0f} s simulated in "
            f"{s.get('loop_s', s['wall_s']):.2f} s ({s['real_time_factor']:.0f}x real time), set-up "
            f"{s['setup_s']:.2f} s"
        )
        add(
            f"   8-hour equivalent: {s['estimate_8h_s']:.0f} s = {s['estimate_8h_s'] / 60:.1f} min "
            f"(extrapolated: {s['extrapolation']})"
        )

    if _ran(sec, "campaign", add):
        c = sec["campaign"]
        add(
            f"== campaign: {c['robot']}, {c['workers']} worker processes x k envs "
            f"(batched Runtime); {c['method']}"
        )
        add(
            f"   {'k':>3} {'sessions':>8} {'sim s/session':>13} {'wall s':>7} "
            f"{'throughput':>10} {'tick p50 us':>11} {'physics only':>12} {'fraction':>8} "
            f"{'floor only':>10} {'fraction':>8}"
        )
        for row in c["configs"]:
            add(
                f"   {row['envs_per_worker']:>3} {row['sessions']:>8} "
                f"{row['simulated_s_per_session']:>13.1f} {row['wall_s']:>7.2f} "
                f"{row['throughput_x']:>9.0f}x {row['tick_cost_p50_us']:>11.1f} "
                f"{row.get('physics_only_x', float('nan')):>11.0f}x "
                f"{row.get('physics_fraction', float('nan')):>8.2f} "
                f"{row.get('floor_only_x', float('nan')):>9.0f}x "
                f"{row.get('floor_fraction', float('nan')):>8.2f}"
            )
        b = c["best"]
        add(
            f"   best: k = {b['envs_per_worker']}, {b['throughput_x']:.0f}x real time, "
            f"{b.get('physics_fraction', float('nan')):.2f} of physics-only stepping, "
            f"{b.get('floor_fraction', float('nan')):.2f} of physics + library calls alone"
        )

    if _ran(sec, "wallclock", add):
        w = sec["wallclock"]
        target = w.get("target", {})
        add(
            f"== wallclock: {w['robot']}, WallClock period {1e3 * w['period_s']:.1f} ms, "
            f"{w['duration_s']:.0f} s per configuration (target: overruns < "
            f"{100 * target.get('overrun_rate', float('nan')):g} % over "
            f"{target.get('duration_s', float('nan')):.0f} s)"
        )
        add(
            f"   {'mode':16} {'scheduler':14} {'cpus':>5} {'mlock':>5} {'ticks':>7} "
            f"{'overruns':>8} {'rate %':>7} {'missed':>6}  {'jitter p50/p99/p99.9/max us':>29}  "
            f"{'tick p50/p99 us':>15}  final"
        )
        for r in w.get("rows", [w]):  # a results file from before the wait modes has no rows
            j = r["jitter_us"] or {}
            sched = r.get("scheduler") or "?"
            if sched == "SCHED_FIFO":
                sched += f" {r['priority']}"
            jit = "/".join(_f(j.get(k), ".0f") for k in ("p50_us", "p99_us", "p99.9_us", "max_us"))
            tc = r["tick_cost_us"]
            add(
                f"   {r.get('mode', 'hybrid'):16} {sched:14} "
                f"{','.join(map(str, r.get('cpus', []))):>5} "
                f"{'yes' if r.get('memory_locked') else 'no':>5} {r['ticks']:>7} "
                f"{r['overruns']:>8} {100 * r['overrun_rate']:>7.3f} {r['missed_periods']:>6}  "
                f"{jit:>29}  {_f(tc['p50_us'], '.0f') + '/' + _f(tc['p99_us'], '.0f'):>15}  "
                f"{','.join(r['final_state'])}"
            )
            for note in r.get("notes", []):
                add(f"     {note}")

    if _ran(sec, "busy", add):
        b = sec["busy"]
        add(
            f"== busy: deploy-run --realtime beside {b['burners']} CPU-bound processes, "
            f"{b['duration_s']:.0f} s each, loop at {b.get('loop_priority', 'normal priority')}"
        )
        for r in b["rows"]:
            falls = "" if r["falls"] is None else f", falls {r['falls']}"
            causes = ", ".join(f"{c} {n}" for c, n in r["overrun_causes"].items()) or "none"
            longest = ", ".join(f"{t['period_us'] / 1e3:.1f} ms" for t in r["longest"])
            add(
                f"   {r['robot']:9} ticks {r['ticks']}, overruns {r['overruns']} "
                f"({100 * r['overrun_rate']:.3f} %), missed {r['missed_periods']}; final "
                f"{','.join(r['final_state'])}{falls}; longest {longest}; overruns by cause: "
                f"{causes}"
            )

    if _ran(sec, "ros2", add):
        r2 = sec["ros2"]
        add(
            f"== ros2: deploy-run --realtime on {r2['robot']}, {r2['duration_s']:.0f} s per "
            "row; us p50/p99 (tick without physics, wake-up jitter, the node's after_tick)"
        )
        for r in r2["rows"]:
            tc, jit, at = r["tick_cost_us"], r["jitter_us"], r["after_tick_us"] or {}
            sent = sum((r["published"] or {}).values())
            add(
                f"   {r['config']:8} tick {_f(tc['p50_us'], '.0f')}/{_f(tc['p99_us'], '.0f')}"
                f"  jitter {_f(jit['p50_us'], '.0f')}/{_f(jit['p99_us'], '.0f')}"
                f"  after_tick {_f(at.get('p50_us'), '.0f')}/{_f(at.get('p99_us'), '.0f')}"
                f"  overruns {r['overruns']}  published {sent}"
                f"  skipped {r['ticks_skipped'] if r['ticks_skipped'] is not None else '-'}"
                f"  final {','.join(r['final_state'])}"
            )

    if _ran(sec, "bus", add):
        b = sec["bus"]
        add(
            f"== bus: one SYNC READ + one SYNC WRITE per tick, vendor SDK against the emulator "
            f"(own process), {b['ticks']} ticks back to back"
        )
        add(f"{'robot':10} {'protocol':9} {'servos':>6} {pct_head} {'Hz':>7} {'wire us':>8}")
        for r in b["rows"]:
            add(
                f"{r['robot']:10} {r['protocol']:9} {r['servos']:>6} {_pct(r)} "
                f"{r['sustained_hz']:>7.0f} {r['wire_model_us']:>8.0f}"
            )

    if _ran(sec, "camera", add):
        from bench.camera_cost import render_lines

        render_lines(sec["camera"], add)

    for robot, pr in sec.get("profile", {}).get("robots", {}).items():
        add("")
        add(f"== profile: {robot}, cProfile over {pr['ticks']} ticks, most own time first")
        add(f"   {'own us/tick':>11} {'cum us/tick':>11} {'calls/tick':>10}  function")
        for r in pr["rows"]:
            add(
                f"   {r['own_us_per_tick']:>11.1f} {r['cumulative_us_per_tick']:>11.1f} "
                f"{r['calls_per_tick']:>10.1f}  {r['function']}"
            )

    add("")
    add("== targets (ratios of figures measured in this run)")
    add(f"   {'target':50} {'robot':6} {'measured':>10} {'goal':>10}  result")
    for t in results["targets"]:
        verdict = {True: "PASS", False: "FAIL", None: "n/a"}[t["pass"]]
        if t["limit"] is None:
            verdict = "stated"
        v = _f(t["value"], {"x": ".2f", "": ".2f", "%": ".3f"}.get(t["unit"], ".1f"))
        lim = "" if t["limit"] is None else f"{t['comparison']} {t['limit']:g}"
        add(
            f"   {t['label']:50} {t['robot']:6} {v:>7} {t['unit']:<2} {lim:>7} {t['unit']:<2} "
            f"{verdict}"
        )
    trend = compare_history(results)
    if trend:
        add("")
        add("== against the last full run (bench/results.json history)")
        for c in trend:
            change = "n/a" if c["change"] is None else f"{100 * c['change']:+.1f} %"
            flag = "  REGRESSION" if c["regression"] else ""
            add(
                f"   {c['key'] + '/' + c['robot']:28} {_f(c['value'], '.2f'):>10} was "
                f"{_f(c['previous'], '.2f'):>10} at {str(c['commit'])[:12]:12} {change}{flag}"
            )
    return "\n".join(lines)


# ---------------------------------------------------------------------- main
