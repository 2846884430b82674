"""Benchmarks (`make bench`): speed is measured here, never by timed unit tests.

``python -m bench`` (``make bench``, under 10 minutes on the 2-core development machine) measures
the runtime against a bare sim2sim loop on the same robot and policy in the same run, writes
``bench/results.json`` atomically and prints a plain-text table ending with the targets of issue 7
(PASS/FAIL). Options: ``--quick`` (a few seconds per item: a smoke test, rough percentiles),
``--only ITEM[,ITEM]``, ``--robots``, ``--campaign-envs``, ``--workers``, ``--out``.

The policy of every item but ``inference``: a deterministic
:class:`deploy.policy.mlp_checkpoint.MLPActor`
(hidden 64, 64, ELU, weights from ``torch.manual_seed(0)``) over the robot's default
:class:`~deploy.spec.policy_spec.PolicySpec` (default observation blocks and control mode: arm3
velocity at 200 Hz, arm6 position at 500 Hz), its weights tamed so that it holds the arm near home
and moves it a little with every goal (:func:`bench.common.tame_actor`; a purely random MLP parks
the arm against a limit or overheats it, a regime a trained policy never runs in), saved with
``save_checkpoint`` and exported with ``deploy.export.run_export`` (parity gate included) to a
temporary folder (:mod:`bench.common`). The runtime stays RUNNING with no guard event for the
whole run; the tick section reports the ticks spent outside RUNNING.
Goals come from :class:`deploy.tasks.goals.GoalScheduler` (a new one every 4 s) as in
``deploy-run``.
All latencies go through :class:`deploy.observe.telemetry.LatencyHistogram` (1 us bins, bin
centres).

Items (module: what):

``plant`` (:mod:`bench.plant`)
    MuJoCo alone per control tick, every robot and control mode: ``mj_step(nstep=decimation)``,
    and ``SimBackend`` read + write + advance (physics, thermal and sensor models).
``inference`` (:mod:`bench.policy_inference`, also runnable alone)
    Export time and batch-1 inference: OnnxPolicy, ``session.run``, torch eager.
``tick`` (:mod:`bench.tick`)
    Per-stage cost of the full runtime over the whole loop (the Runtime's own stamps,
    ``rt.latency`` and ``rt.tick_cost``) and of the bare loop (unitree_rl_gym's
    ``deploy_mujoco.py``: torch eager, PD torques at the physics rate, ``mj_step``), in alternating
    rounds; ratios full / bare of the tick with physics and of the overhead without physics.
``session`` (:mod:`bench.session`)
    ``deploy-run`` for a short simulated run, extrapolated linearly to 8 hours:
    ``setup_s + wall_s * 28800 / simulated_s``.
``campaign`` (:mod:`bench.campaign`)
    One process per core, each a batched Runtime over ``SimBackend(envs=k)``; simulated
    seconds of all sessions per wall second, for several k; the best k is reported; then the
    same models stepped by MuJoCo alone (physics-only throughput, and the fraction kept).
``wallclock`` (:mod:`bench.session`)
    ``deploy-run --realtime`` on arm6 (``WallClock``, period 1/500 s) for 60 s
    (``--wallclock-seconds``) per configuration: each wait mode (sleep, hybrid, spin), hybrid
    and spin at SCHED_FIFO priority 50 with the memory locked where permitted, and hybrid at that
    priority pinned to the last CPU (``--wallclock-modes``; also ``spin+fifo+cpu``): deadline
    overruns, missed periods, wake-up jitter percentiles, tick cost, and the scheduler settings
    read back.
``bus`` (:mod:`bench.bus`)
    One SYNC READ + one SYNC WRITE per tick through the vendor SDK (so101: 6 Feetech servos;
    arm3_xm430: 3 Dynamixel servos; 1 Mbaud) against the wire-protocol emulator in its own
    process, back to back: per-tick cost, the tick rate the bus sustains, and the emulator's
    timing model of the same exchange (bytes on the wire). Skipped without the servo extra.
``profile`` (:mod:`bench.profiling`, only with ``--only profile``)
    cProfile of the full runtime: functions ranked by own time per tick.

results.json (schema ``sim2real-deploy/bench/1``; times in us unless the key says ``_s``;
a percentile summary is ``{"p50_us", "p99_us", "p99.9_us", "max_us", "mean_us", "samples"}``;
NaN is written as null)::

    schema, generated (UTC ISO time), quick, argv, items, settings, wall_s
    machine     {platform, processor, python, cpu_count, load_average_at_start, versions}
    policies    {<robot>: {kind, hidden, activation, seed, obs_dim, act_dim, observation_blocks,
                           control_mode, control_rate_hz, export_s}}
    sections    every section also has measured_at, quick, section_wall_s
      plant     {ticks, rows: [{robot, mode, what ("mj_step" | "plant"), decimation, <summary>}]}
      inference {policy, exports: [{name, seconds, parity}], max_abs_error, calls,
                 rows: [{name, median_us, p99_us}]}
      tick      {robots: {<robot>: {ticks, rounds, warmup_ticks, control_rate_hz, decimation,
                   full: {stages: {read, estimate, observe, infer, guard, smooth, write,
                                   physics: <summary>},
                          overhead: <summary> (rt.tick_cost: the tick without physics),
                          tick: <summary> (the tick as the loop sees it, physics included),
                          ticks_not_running, final_state, safe_stops, goals_issued},
                   bare: {stages: {read, observe, infer, target, pd, physics: <summary>},
                          overhead: <summary> (tick minus mj_step), tick: <summary>},
                   ratio: {tick_p50, tick_mean, overhead_p50, overhead_mean} (full / bare)}}}
      session   {robots: {<robot>: {simulated_s, wall_s, setup_s, real_time_factor,
                   wall_per_simulated_s, estimate_8h_s, extrapolation, control_rate_hz,
                   physics_rate_hz, tick_cost_us, stage_p50_us, final_state, goals, exit_code}}}
      campaign  {robot, workers, method, section_wall_s,
                 configs: [{envs_per_worker, workers, sessions, simulated_s_per_session, wall_s,
                            throughput_x, physics_only_x, physics_fraction,
                            per_worker_loop_s, setup_s, tick_cost_p50_us,
                            physics_p50_us, safe_stops, sessions_running_at_end}],
                 best: {envs_per_worker, workers, throughput_x, physics_only_x,
                        physics_fraction}}
      wallclock {robot, period_s, duration_s, target: {overrun_rate, duration_s},
                 rows: [{mode, options, wait, scheduler, priority, cpus, memory_locked, notes,
                         duration_s, wall_s, ticks, overruns, missed_periods, overrun_rate,
                         jitter_us: <summary>, tick_cost_us, final_state, final_cause,
                         exit_code}]}
      bus       {ticks, rows: [{robot, protocol, servos, baudrate, <summary> (read + write),
                 sustained_hz, wire_model_us, read_block_bytes, goal_bytes, dropouts}]}
                (or {skipped: reason, rows: []})
      profile   {robots: {<robot>: {ticks, rows: [{function, calls_per_tick, own_us_per_tick,
                                                   cumulative_us_per_tick}]}}}
    targets     [{key, label, robot, value, limit, comparison ("<=" | ">="), unit, pass}]
                (pass is null when the figure was not measured)

Targets (issues 7 and 18): full tick / bare loop p50 <= 1.0 on arm6; runtime overhead without
physics <= 50 us p50 and <= 150 us p99.9 on arm6; one 8-hour-equivalent arm3 session in <= 8
minutes (issue 18 measures it with ``make soak``; here ``deploy-run`` extrapolated); campaign
throughput >= 500x real time for arm3 on the whole machine, and >= 0.6 of physics-only stepping
in the same run (machine-independent).
"""
