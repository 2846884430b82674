"""Command-line entry points: ``deploy-run`` and ``policy-export``.

``deploy-run``'s options are parsed by :mod:`deploy.cli.run_parser`; the summary it prints at the
end is :mod:`deploy.cli.run_summary`'s.

``deploy-run`` exit codes:

====  =====================================================================================
0     clean: no hard violation, no latched fault
1     a hard-limit violation: the true joint position (simulation) crossed a hard limit, or the
      guard found the estimate beyond one (a safe stop)
2     a latched fault: some env ended FAULTED (or in a safe stop) after a fault of the table
3     bad input: unreadable robot, policy or spec, mismatching contract, bad option; a servo bus
      that does not come up (port, missing servo, wrong model number, calibration); a Unitree
      robot that does not come up (no LowState, a high-level mode active, a ramp not followed)
4     the simulation diverged (MuJoCo reported a bad state)
====  =====================================================================================

Backends (``--backend``): ``sim`` (the MuJoCo plant, simulated or wall clock, many envs, fault
injection, true-state violation counting), ``feetech`` and ``dynamixel`` (a real servo bus through
the vendor's SDK, or the emulator's pty), ``unitree`` (a Unitree robot's low-level DDS interface,
or its emulator): one robot, wall clock only; goals and motion figures are judged on the
estimated state, as there is no ground truth. On hardware the run ends early once the fault is
latched (FAULTED); at the end a servo bus's torque goes off unless ``--hold-on-close``, a Unitree
robot is left damped.

Real time (``--wait``, ``--rt-priority``, ``--cpu``, ``--lock-memory``, ``--require-rt``):
:mod:`deploy.runtime.clock` and :mod:`deploy.runtime.realtime`, applied around the loop only.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from deploy.backends.registry import make_backend
from deploy.cli.policy_contract import check_drive_applied, contract_messages
from deploy.cli.run_parser import attach_vectors, build_parser
from deploy.cli.run_summary import print_summary
from deploy.core.backend import SimulatedPlant
from deploy.monitors.kernel import motion_statistics
from deploy.spec.drive import drive_robot
from deploy.tasks.task import task_for
from robots.files import atomic_write

EXIT_CLEAN, EXIT_HARD_VIOLATION, EXIT_FAULT, EXIT_BAD_INPUT, EXIT_DIVERGED = 0, 1, 2, 3, 4


def run(args) -> int:
    """``deploy-run`` with parsed ``args``: build and open the backend, run, report; the exit
    code (module docstring). The backend is closed (servo bus: torque off) however it ends."""
    from deploy.backends.sim.faults import Fault, FaultInjector
    from deploy.policy.onnx_policy import OnnxPolicy
    from deploy.runtime import SimClock, WallClock
    from deploy.spec.policy_spec import PolicySpec
    from robots import load_robot

    # hardware runs on the wall clock only; the real-time options are checked before loading
    wait, rt_request = realtime_options(args, bool(args.realtime) or args.backend != "sim")
    robot = load_robot(args.robot)
    spec = None
    if args.spec:
        spec = PolicySpec.from_json(Path(args.spec).read_text(), source=args.spec)
    policy = OnnxPolicy(args.policy, robot, spec=spec)
    for line in contract_messages(policy):
        print(line, file=sys.stderr)
    robot, drive = drive_robot(robot, policy.spec)  # the policy's PD gains and default pose
    faults = [Fault.parse(s) for s in args.inject]
    fixed = None
    if args.goal:
        try:
            fixed = np.array([float(x) for x in args.goal.split(",")])
            assert fixed.shape == (3,)
        except (ValueError, AssertionError):
            raise ValueError(f"--goal {args.goal!r}: expected X,Y,Z in metres") from None
    backend = make_backend(args, robot, policy.spec.action.mode)  # the registry's factory
    simulated = isinstance(backend, SimulatedPlant)
    check_drive_applied(drive, simulated, args.backend)
    for line in drive.values():
        print(
            f"deploy-run: warning: robot.toml differs from the policy's drive, which the "
            f"run uses: {line}",
            file=sys.stderr,
        )
    realtime = bool(args.realtime) or not simulated  # hardware: the wall clock only
    injector = FaultInjector(faults, backend) if faults else None
    if realtime:
        clock = WallClock(robot.control_period, wait=wait)
    else:
        clock = SimClock(robot.control_period)
    with backend:
        return _run_opened(
            args, robot, policy, backend, simulated, realtime, injector, clock, fixed, rt_request
        )


def realtime_options(args, realtime: bool):
    """The wall clock's wait mode and the :class:`~deploy.runtime.realtime.RealtimeRequest` of
    ``--wait``/``--spin``, ``--rt-priority``, ``--cpu``, ``--lock-memory`` and ``--require-rt``
    (validated against this machine: the CPUs exist for this process, the priority is in range).

    ``--lock-memory`` defaults to on with ``--rt-priority`` and off otherwise.

    Raises:
        ValueError: ``--spin`` with another ``--wait``; a wait mode or ``--rt-priority`` without
            the wall clock (a lockstep run never waits, and a lockstep run at real-time priority
            would take a core from everything else);
            :class:`~deploy.runtime.realtime.RealtimeError` for a bad ``--cpu`` or
            ``--rt-priority``.
    """
    from deploy.runtime.realtime import RealtimeRequest, parse_cpus

    if args.spin and args.wait not in (None, "spin"):
        raise ValueError(f"--spin and --wait {args.wait} disagree: give one of them")
    wait = "spin" if args.spin else (args.wait or "hybrid")
    if not realtime and (args.spin or args.wait or args.rt_priority is not None):
        given = "--spin" if args.spin else "--wait" if args.wait else "--rt-priority"
        raise ValueError(
            f"{given} needs the wall clock: add --realtime (a lockstep run never waits)"
        )
    lock = args.lock_memory if args.lock_memory is not None else args.rt_priority is not None
    request = RealtimeRequest(
        priority=args.rt_priority,
        cpus=parse_cpus(args.cpu) if args.cpu is not None else None,
        lock_memory=bool(lock),
        require=bool(args.require_rt),
        spin=wait == "spin",
    )
    request.validate()
    return wait, request


def _run_opened(
    args, robot, policy, backend, simulated, realtime, injector, clock, fixed, rt_request=None
) -> int:
    from deploy.backends.sim.plant import SimulationDivergedError
    from deploy.core.latency import LatencyHistogram
    from deploy.estimation.joints import reinit_warning
    from deploy.monitors.interventions import InterventionMonitor
    from deploy.monitors.violations import HARD_VIOLATION_TYPES, ViolationMonitor
    from deploy.observe.telemetry import Telemetry
    from deploy.runtime import FAULTED, RUNNING, STAGES, Runtime
    from deploy.runtime.realtime import RealtimeRequest, RealtimeSettings

    telemetry = None
    if args.telemetry:
        from deploy.observe import foxglove

        fox = {"robot": robot, "control_mode": policy.spec.action.mode}
        if not foxglove.available():
            fox = {}
            print(
                "deploy-run: note: foxglove-schemas-protobuf not installed (extra 'foxglove'): "
                "the telemetry has no Foxglove topics",
                file=sys.stderr,
            )
        telemetry = Telemetry(args.telemetry, args.envs, robot.n_joints, **fox)
    viewers = []  # called after every tick; they only read the runtime
    if args.print_joints is not None:
        from deploy.observe.joint_printer import JointPrinter

        viewers.append(JointPrinter(robot.joint_names, args.print_joints, policy.spec.action.mode))
    video = None
    if args.video is not None:
        from deploy.observe.video import open_video

        video = open_video(args, robot, backend)  # None (and a one-line error) without GL
        if video is not None:
            viewers.append(video)
    window = None
    if args.viewer:
        from deploy.observe.viewer import PassiveViewer

        window = PassiveViewer(robot, backend)  # synced after every tick; closing it ends the run
        viewers.append(window)
    limit = {} if args.overrun_limit is None else {"overrun_rate_limit": args.overrun_limit}
    rt = Runtime(
        robot, policy, backend, clock=clock, injector=injector, telemetry=telemetry, **limit
    )
    ticks = int(round(args.duration / robot.control_period))
    peak = np.full((args.envs, robot.n_joints), -np.inf)
    max_speed = np.zeros(robot.n_joints)
    # smoothness of the motion: jerk by second differences of the joint velocities at the
    # control rate (rad/s^3), summed while RUNNING; true velocities in simulation, else estimated
    dt = robot.control_period
    motion = {k: np.zeros((args.envs, robot.n_joints)) for k in ("dq", "acc", "jerk_sum")}
    motion_ticks = np.zeros(args.envs, dtype=np.int64)
    running = np.zeros(args.envs, dtype=bool)
    monitor_cost = LatencyHistogram()
    clock_ns = time.perf_counter_ns

    violations = ViolationMonitor(robot, args.envs) if simulated else None
    estimation = None  # the base estimate against the truth, and true falls (sim, legged)
    if simulated and robot.floating_base:
        from deploy.monitors.estimation import EstimationMonitor

        estimation = EstimationMonitor(robot, args.envs)
    interventions = InterventionMonitor(rt.guard, rt.smoother)
    task = task_for(
        robot,
        args.envs,
        backend,
        period=args.goal_period,
        rng=np.random.default_rng(args.seed + 1),
        success_time=args.success_time,
        fixed=fixed,
        command=args.command,
        interventions=interventions,
        schedule=False,
        heading_gain=args.heading_hold,
    )
    task.reset(rt, np.ones(args.envs, dtype=bool))
    node = None
    if args.ros2:
        from deploy.ros2.bridge import RuntimeNode

        node = RuntimeNode(
            rt, namespace=args.ros2_namespace, task=task, interventions=interventions
        )  # off the control thread; after_tick hands it each tick

    def on_tick(r):
        t0 = clock_ns()
        if violations is not None:
            # a legged robot lying damped after a stop: its ticks are counted apart
            violations.update(backend, down=r.damping if robot.floating_base else None)
        interventions.update()
        if estimation is not None:
            estimation.update(r, backend.true_base_state())
        monitor_cost.add(0, clock_ns() - t0)
        task(r)
        if node is not None:
            node.after_tick(r)
        temperature = (
            backend.thermal.winding_temperature if simulated else r.state.winding_temperature
        )
        np.fmax(peak, temperature, out=peak)
        dq = backend.true_velocity() if simulated else r.state.dq
        np.equal(r.mode, RUNNING, out=running)
        motion_statistics(
            dq, motion["dq"], motion["acc"], dt, running, r.ticks > 2, motion["jerk_sum"],
            motion_ticks, max_speed,
        )  # fmt: skip
        closed = False
        for viewer in viewers:
            closed |= bool(viewer(r))  # the viewer's window was closed: end the run
        return closed or (not simulated and bool((r.mode == FAULTED).all()))  # hardware: latched

    # priority, affinity and memory lock for the loop only (not the loading), restored after it
    settings = RealtimeSettings(rt_request or RealtimeRequest())
    with settings:  # RealtimeError (a ValueError: exit 3) if --require-rt and refused
        wall = time.perf_counter()
        diverged = None
        rt.start()
        interventions.resync()  # start zeroes the smoother's counters
        try:
            rt.run(ticks, on_tick=on_tick)
        except SimulationDivergedError as exc:
            diverged = str(exc)
        finally:
            if node is not None:
                node.close()
        wall = time.perf_counter() - wall
    if telemetry is not None:
        telemetry.close(rt.long_ticks.rows(rt.dt), rt.dt)
    if video is not None:
        video.close()
    if window is not None:
        window.close()

    hard_stops = int(rt.counters.faults["hard_limit"].sum())
    if violations is not None:
        true, down = violations.totals(), violations.totals(down=True)
        violation_report = {
            "source": "true state (simulation ground truth)",
            "ticks": violations.ticks * args.envs,
            "by_type": {k: v for k, v in true.items() if k != "any"},
            "any": true["any"],
            "while_down": down,  # lying damped after a stop: apart, and still a hard violation
        }
    else:
        true, down = {"hard_limit": 0}, {}
        violation_report = None  # no ground truth on hardware: the guard's counts stand in
    sections = task.report(rt)  # goals or locomotion, and the missed goals
    est_summary = estimation.summary() if estimation is not None else None
    true_falls = int(estimation.true_falls.sum()) if estimation is not None else 0
    loco = sections["locomotion"]
    if loco is not None and estimation is not None:
        # in simulation a fall is the truth's: one the runtime did not see counts too
        loco["runtime_falls"] = loco["falls"]
        loco["true_falls"] = true_falls
        loco["falls"] = max(loco["falls"], true_falls)
    report = {
        "robot": robot.name,
        "backend": args.backend,
        "policy": str(args.policy),
        "control_mode": policy.spec.action.mode,
        "control_rate_hz": 1.0 / robot.control_period,
        "duration_s": rt.time,
        "wall_s": wall,
        "realtime": realtime,
        "envs": args.envs,
        "seed": args.seed,
        "goals": sections["goals"],
        "locomotion": sections["locomotion"],
        "violations": violation_report,
        "estimation": est_summary,
        "interventions": interventions.summary(),
        "missed_goals": sections["missed_goals"],
        "faults": {
            "non_finite_actions": int(rt.counters.non_finite_actions.sum()),
            "safe_stops": int(rt.counters.safe_stops.sum()),
            "safe_stop_timeouts": int(rt.counters.safe_stop_timeouts.sum()),
            "by_cause": {k: int(v.sum()) for k, v in rt.counters.faults.items()},
            "estimator": {
                "stale_readings": int(rt.estimator.stale_readings.sum()),
                "missing_readings": int(rt.estimator.missing_readings.sum()),
                "reinitializations": int(rt.estimator.reinitializations.sum()),
                "warning": reinit_warning(
                    robot.joint_names, rt.estimator.reinitializations_per_joint, rt.time
                ),
            },
            "injected": injector.log if injector else [],
            "drive_errors": [
                backend.describe_drive_error(int(j), int(rt.drive_errors[e, j]))
                for e, j in np.argwhere(rt.drive_errors)
            ],
        },
        "final_state": rt.mode_names(),
        "final_cause": rt.cause_names(),
        "peak_winding_temperature_c": dict(
            zip(robot.joint_names, peak.max(axis=0).tolist(), strict=True)
        ),
        "max_joint_speed_rad_s": dict(zip(robot.joint_names, max_speed.tolist(), strict=True)),
        "mean_abs_jerk_rad_s3": dict(
            zip(
                robot.joint_names,
                (motion["jerk_sum"].sum(axis=0) / max(int(motion_ticks.sum()), 1)).tolist(),
                strict=True,
            )
        ),
        "tick_cost_us": rt.tick_cost.summary(),
        "monitor_cost_us": monitor_cost.summary(),
        "stage_cost_us": {s: rt.latency.summary(i) for i, s in enumerate(STAGES)},
        "deadline": {
            "overruns": clock.overruns,
            "missed_periods": clock.missed_periods,
            "jitter_us": clock.jitter.summary() if realtime else None,
            "wait": clock.wait_mode,
            "long_ticks": rt.long_ticks.rows(rt.dt),
        },
        "realtime_settings": settings.summary(),
        "bus": backend.bus_summary() if hasattr(backend, "bus_summary") else None,
        "ros2": node.summary() if node is not None else None,
        "diverged": diverged,
    }
    hard = {
        k: int(true[k]) + int(down.get(k, 0))
        for k in HARD_VIOLATION_TYPES
        if true.get(k, 0) + down.get(k, 0)
    }
    report["hard_violations"] = hard
    if hard or hard_stops > 0:
        code = EXIT_HARD_VIOLATION
    elif any(m in ("FAULTED", "SAFE_STOP") for m in report["final_state"]) or true_falls:
        code = EXIT_FAULT
    else:
        code = EXIT_CLEAN
    if diverged:
        code = EXIT_DIVERGED
    report["exit_code"] = code
    print_summary(report)
    if args.report:
        atomic_write(args.report, json.dumps(report, indent=2))
    return code


def deploy_run_main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    argv = attach_vectors(argv)
    args = build_parser(argv).parse_args(argv)
    if args.viewer:  # a window or nothing: refuse before the run starts
        from deploy.observe.viewer import NoDisplayError, check_display

        try:
            check_display()
        except NoDisplayError as exc:
            print(f"deploy-run: error: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
    if args.video is not None:
        from deploy.observe.video import headless_gl_default

        headless_gl_default()  # MUJOCO_GL=egl on a machine without a display, unless chosen
    if os.environ.get("MUJOCO_GL"):  # mujoco loads that GL backend when imported
        from deploy.observe.video import import_mujoco

        gl_error = import_mujoco()
        if gl_error is not None:
            print(f"deploy-run: error: {gl_error}", file=sys.stderr)
            args.video = None  # the run goes on without video
    try:
        code = run(args)
    except (
        ValueError,
        OSError,
    ) as exc:  # RobotSpecError, SpecError, PolicyLoadError are ValueErrors
        print(f"deploy-run: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.viewer:  # the run is reported: leave before MuJoCo's viewer tears down its GL
        from deploy.observe.viewer import exit_now

        exit_now(code)
    return code


if __name__ == "__main__":
    raise SystemExit(deploy_run_main())
