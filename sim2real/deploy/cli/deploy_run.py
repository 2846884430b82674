"""Command-line entry points: ``deploy-run`` and ``policy-export``.

``deploy-run``'s options are parsed by :mod:`sim2real.deploy.cli.run_parser`; the summary it prints at the
end is :mod:`sim2real.deploy.cli.run_summary`'s.

``deploy-run`` exit codes:

====  =====================================================================================
0     clean: no hard violation, no latched fault
1     a hard-limit violation: the true joint position (simulation) crossed a hard limit, or the
      guard found the estimate beyond one (a safe stop); a tracking run's hard-limit and
      self-collision ticks only past what its own loop allows
      (:mod:`sim2real.deploy.cli.own_loop_check`)
2     a latched fault: some env ended FAULTED (or in a safe stop) after a fault of the table
3     bad input: unreadable robot, policy or spec, mismatching contract, bad option; a servo bus
      that does not come up (port, missing servo, wrong model number, calibration); a Unitree
      robot that does not come up (no LowState, a high-level mode active, a ramp not followed)
4     the simulation diverged (MuJoCo reported a bad state)
5     a clip run whose base left its spot: it ends more than 0.5 m from where the clip's root
      path ends, or went more than 0.5 m after the clip
      (:mod:`sim2real.deploy.tasks.motion.travel`)
====  =====================================================================================

Backends (``--backend``): ``sim`` (the MuJoCo plant, simulated or wall clock, many envs, fault
injection, true-state violation counting), ``feetech`` and ``dynamixel`` (a real servo bus through
the vendor's SDK, or the emulator's pty), ``unitree`` (a Unitree robot's low-level DDS interface,
or its emulator): one robot, wall clock only; goals and motion figures are judged on the
estimated state, as there is no ground truth. On hardware the run ends early once the fault is
latched (FAULTED); at the end a servo bus's torque goes off unless ``--hold-on-close``, a Unitree
robot is left damped. Real time: :func:`realtime_options`.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from sim2real.deploy.backends.registry import make_backend
from sim2real.deploy.cli.exteroception import (
    attach_camera,
    attach_height_map,
    camera_report,
    close_camera,
    show_goal,
)
from sim2real.deploy.cli.own_loop_check import own_loop_verdict
from sim2real.deploy.cli.policy_contract import check_drive_applied, contract_messages
from sim2real.deploy.cli.run_checks import check_options, check_outputs, discard
from sim2real.deploy.cli.run_operator import (
    after_clip_policy,
    load_policies,
    open_operator_source,
    operator_hook,
    operator_mapping,
    parse_policies,
)
from sim2real.deploy.cli.run_parser import (
    attach_vectors,
    build_parser,
    parse_camera_source_option,
    parse_terrain_option,
)
from sim2real.deploy.cli.run_summary import print_summary
from sim2real.deploy.cli.run_verdict import (  # noqa: F401 (deploy-run's exit codes, public here)
    EXIT_BAD_INPUT,
    EXIT_CLEAN,
    EXIT_DIVERGED,
    EXIT_FAULT,
    EXIT_HARD_VIOLATION,
    exit_code,
)
from sim2real.deploy.core.backend import SimulatedPlant
from sim2real.deploy.spec.drive import drive_robot
from sim2real.robots.files import atomic_write


def run(args) -> int:
    """``deploy-run`` with parsed ``args``: build and open the backend, run, report; the exit
    code (module docstring). The backend is closed (servo bus: torque off) however it ends.
    Every input is read and checked before any output opens (telemetry, video, recorded
    commands, report); a run refused or ended by an error leaves none of them behind
    (:mod:`sim2real.deploy.cli.run_checks`).

    Raises:
        ValueError: bad input (exit 3): a robot, spec or policy that does not load or fit, a
            bad option, mapping or operator source, an output in no folder.
        OSError: a file, device or network interface that cannot be opened (exit 3).
    """
    from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
    from sim2real.deploy.runtime import SimClock, WallClock
    from sim2real.deploy.tasks.motion.source import motion_for
    from sim2real.robots import load_robot

    # hardware runs on the wall clock only; the real-time options are checked before loading
    wait, rt_request = realtime_options(args, bool(args.realtime) or args.backend != "sim")
    check_outputs(args)
    robot = load_robot(args.robot)
    policies = run_policies(args, robot)
    policy = next(iter(policies.values()))
    for line in contract_messages(policy):
        print(line, file=sys.stderr)
    robot, drive = drive_robot(robot, policy.spec)  # the policy's PD gains and default pose
    faults = [Fault.parse(s) for s in args.inject]
    fixed = _fixed_goal(args.goal)
    check_options(args, robot)  # --command, --size, --fps: read once the rig is built
    after = after_clip_policy(args, policies, policy)  # (name, policy) or None
    playback = args.motion_playback or ("once" if after else "stand")
    motion = motion_for(
        policy, robot, args.envs, args.motion, playback, args.motion_fps, args.motion_stand_s,
    )  # fmt: skip  # a tracking policy's clip (ClipError: a ValueError, exit 3)
    if after is not None and motion is None:
        raise ValueError(
            f"--after-clip {after[0]}: the first --policy plays no clip (a motion-tracking "
            "policy's observation reads one)"
        )
    mapping = operator_mapping(args)  # the mapping and its source's file, not its device
    backend = make_backend(args, robot, policy.spec.action.mode)  # the registry's factory
    simulated = isinstance(backend, SimulatedPlant)
    attach_height_map(args, backend, policy.spec)  # a height_scan block: the plant's ray casts
    # an image input: the plant's MJCF camera, for the first policy that reads one (the camera
    # goes with a switch of policy: Runtime.switch_policy)
    seeing = [p.spec for p in policies.values() if getattr(p.spec, "images", ())]
    attach_camera(args, backend, seeing[0] if seeing else policy.spec)
    check_drive_applied(drive, simulated or getattr(backend, "commands_gains", False), args.backend)
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
    # the rig (its compiled stages, warmed) before the bring-up (in _run_rig): a robot brought
    # up holds at home, and what plays on its clock (a scripted remote) waits on no compile
    rig = build_rig(args, robot, policies, backend, injector, clock, fixed, mapping, motion, after)
    show_goal(backend, rig.runtime.goal)  # a task scene's marker at the runtime's goals
    try:
        return _run_rig(args, rig, realtime, injector, clock, rt_request)
    finally:
        backend.close()  # servo bus: torque off; Unitree: damped
        close_camera(backend)  # a hardware camera's grab thread and device


def run_policies(args, robot) -> dict:
    """{name: policy} of ``--policy`` (with ``--spec``), or ``--excitation``'s scripted
    trajectory in the policy's place.

    Raises:
        ValueError: a spec, policy or excitation that does not load or fit the robot.
    """
    from sim2real.deploy.spec.policy_spec import PolicySpec

    spec = None
    if args.spec:
        spec = PolicySpec.from_json(Path(args.spec).read_text(), source=args.spec)
    if args.excitation is None:
        # --policy [NAME=]FILE, repeated; --inference for a LeRobot export's chunks
        return load_policies(args.policies, robot, spec, inference=args.inference, seed=args.seed)
    from sim2real.deploy.policy.excitation import Excitation, ExcitationPolicy

    excitation = ExcitationPolicy(robot, Excitation.load(args.excitation))
    print(
        f"deploy-run: excitation {args.excitation}: {excitation.duration:.1f} s "
        f"(--duration {args.duration:g} s)",
        file=sys.stderr,
    )
    return {"excitation": excitation}


def _fixed_goal(text: str | None) -> np.ndarray | None:
    """``--goal X,Y,Z`` (m, base frame) as a (3,) array, or None.

    Raises:
        ValueError: not three numbers.
    """
    if not text:
        return None
    try:
        fixed = np.array([float(x) for x in text.split(",")])
    except ValueError:
        fixed = None
    if fixed is None or fixed.shape != (3,):
        raise ValueError(f"--goal {text!r}: expected X,Y,Z in metres")
    return fixed


def realtime_options(args, realtime: bool):
    """The wall clock's wait mode and the :class:`~sim2real.deploy.runtime.realtime.RealtimeRequest` of
    ``--wait``/``--spin``, ``--rt-priority``, ``--cpu``, ``--lock-memory`` and ``--require-rt``
    (validated against this machine: the CPUs exist for this process, the priority is in range):
    :mod:`sim2real.deploy.runtime.clock` and :mod:`sim2real.deploy.runtime.realtime`, applied
    around the control loop only.

    ``--lock-memory`` defaults to on with ``--rt-priority`` and off otherwise.

    Raises:
        ValueError: ``--spin`` with another ``--wait``; a wait mode or ``--rt-priority`` without
            the wall clock (a lockstep run never waits, and a lockstep run at real-time priority
            would take a core from everything else);
            :class:`~sim2real.deploy.runtime.realtime.RealtimeError` for a bad ``--cpu`` or
            ``--rt-priority``.
    """
    from sim2real.deploy.runtime.realtime import RealtimeRequest, parse_cpus

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


def build_rig(
    args, robot, policies, backend, injector, clock, fixed, mapping, motion=None, after=None
):
    """The run's :class:`~sim2real.deploy.rig.rig.Rig` on the first of ``policies``: the runtime
    (telemetry, overrun limit), the task of the options, the motion figures, the hooks the
    options switch on, the operator (``--operator``'s ``mapping``, after them) and, on hardware
    without an operator, the end of the run once every env is latched. The operator's source
    opens first, before any output; an error discards what was opened
    (:func:`~sim2real.deploy.cli.run_checks.discard`).

    Raises:
        ValueError, OSError: the operator's source does not open, an output does not open, a
            hook refuses its options.
    """
    from sim2real.deploy.rig.chunk_hook import chunk_hook
    from sim2real.deploy.rig.hooks import registered_hooks
    from sim2real.deploy.rig.motion_phase_hook import motion_phase_hook
    from sim2real.deploy.rig.rig import LatchedStopHook, MotionHook, Rig

    policy = next(iter(policies.values()))
    source = open_operator_source(args, mapping, robot)  # an input: before any output
    telemetry = rig = None
    try:
        telemetry = _telemetry(args, robot, policy)
        runtime = {"clock": clock, "injector": injector, "telemetry": telemetry}
        if args.overrun_limit is not None:
            runtime["overrun_rate_limit"] = args.overrun_limit
        task = {
            "period": args.goal_period,
            "rng": np.random.default_rng(args.seed + 1),
            "success_time": args.success_time,
            "fixed": fixed,
            "command": args.command,
            "schedule": False,
            "heading_gain": args.heading_hold,
        }
        if motion is not None:  # the tracking task plays the clip (motion_for)
            task.update(task="tracking", motion=motion, motion_start_after=args.motion_start_after)
        rig = Rig(robot, policy, backend, envs=args.envs, task=task, runtime=runtime)
        rig.add(MotionHook(rig))
        # a chunked policy (LeRobot's): its cadence and jerk; a phase-clocked one: its motion's
        for hook in (chunk_hook(rig), motion_phase_hook(rig)):
            if hook is not None:
                rig.add(hook)
        if after is not None:  # the hand-over at the clip's end
            from sim2real.deploy.rig.after_clip import AfterClipHook

            rig.add(AfterClipHook(rig, after[1], after[0], args.after_clip_blend))
        for entry in registered_hooks().values():  # --ros2, --print-joints, --video, ...
            hook = entry.build(args, rig)
            if hook is not None:
                rig.add(hook)  # added at once: discarded with the rig on an error
        # after --ros2: its command is the last word
        operator = operator_hook(args, rig, policies, mapping, source)
        if operator is not None:
            rig.add(operator)
        elif not rig.simulated:  # an operator stands a latched robot up again
            rig.add(LatchedStopHook())
    except BaseException:
        discard(rig, telemetry, source)
        raise
    return rig


def _telemetry(args, robot, policy):
    """``--telemetry PATH``: the MCAP recorder (Foxglove's schemas with the foxglove extra)."""
    if not args.telemetry:
        return None
    from sim2real.deploy.observe import foxglove
    from sim2real.deploy.observe.telemetry import Telemetry

    fox = {"robot": robot, "control_mode": policy.spec.action.mode}
    if not foxglove.available():
        fox = {}
        print(
            "deploy-run: note: foxglove-schemas-protobuf not installed (extra 'foxglove'): "
            "the telemetry has no Foxglove topics",
            file=sys.stderr,
        )
    return Telemetry(args.telemetry, args.envs, robot.n_joints, **fox)


def _run_rig(args, rig, realtime, injector, clock, rt_request) -> int:
    """Bring the backend up (built rig, real-time settings in force), run the rig for
    ``--duration``, print the summary, write ``--report``; the exit code."""
    from sim2real.deploy.backends.sim.plant import SimulationDivergedError
    from sim2real.deploy.runtime.realtime import RealtimeRequest, RealtimeSettings

    rt = rig.runtime
    ticks = int(round(args.duration / rig.robot.control_period))
    # priority, affinity and memory lock for the loop only (not the loading), restored after it
    settings = RealtimeSettings(rt_request or RealtimeRequest())
    try:
        with settings:  # RealtimeError (a ValueError: exit 3) if --require-rt and refused
            rig.backend.open()  # the bring-up, at the loop's priority: then straight to start
            wall = time.perf_counter()
            diverged = None
            rig.start()  # once per run: the runtime's start, the hooks' set-up (timed apart)
            start_s = time.perf_counter() - wall
            try:
                rig.run(ticks)
            except SimulationDivergedError as exc:
                diverged = str(exc)
            except KeyboardInterrupt:  # stopped by hand: the hooks keep what they recorded
                rig.close()
                raise
            rig.close()
            wall = time.perf_counter() - wall
        if rt.telemetry is not None:
            rt.telemetry.close(rt.long_ticks.rows(rt.dt, realtime), rt.dt)
    except Exception:  # refused (--require-rt, bring-up, a hook's start), failed: none left
        discard(rig, rt.telemetry)
        raise
    report = run_report(args, rig, wall, realtime, injector, clock)
    report["start_s"] = start_s  # of wall_s: paid once, not per tick
    report["realtime_settings"] = settings.summary()
    report["diverged"] = diverged
    report["own_loop"] = own_loop_verdict(args, rig, report)
    report["exit_code"] = exit_code(report, rig)
    print_summary(report)
    if args.report:
        atomic_write(args.report, json.dumps(report, indent=2))
    return report["exit_code"]


def run_report(args, rig, wall: float, realtime: bool, injector, clock) -> dict:
    """The run's report (the JSON of ``--report``): what ran, the rig's monitors, task and
    hooks (:meth:`~sim2real.deploy.rig.rig.Rig.report`), the faults, the costs and the deadlines."""
    from sim2real.deploy.runtime import STAGES

    rt, robot, backend = rig.runtime, rig.robot, rig.backend
    report = {
        "robot": robot.name,
        "backend": args.backend,
        "policy": str(next(iter(args.policies.values()))),
        "policies": dict(args.policies),
        "control_mode": rig.policy.spec.action.mode,
        "control_rate_hz": 1.0 / robot.control_period,
        "duration_s": rt.time,
        "wall_s": wall,
        "realtime": realtime,
        "envs": args.envs,
        "seed": args.seed,
        **rig.report(),
        "faults": fault_report(rig, injector),
        "final_state": rt.mode_names(),
        "final_cause": rt.cause_names(),
        "tick_cost_us": rt.tick_cost.summary(),
        "height_map": rt.height_map.summary() if rt.height_map is not None else None,
        "camera": camera_report(rt, backend),
        "stage_cost_us": {s: rt.latency.summary(i) for i, s in enumerate(STAGES)},
        "deadline": {
            "overruns": clock.overruns,
            "missed_periods": clock.missed_periods,
            "jitter_us": clock.jitter.summary() if realtime else None,
            "wait": clock.wait_mode,
            "long_ticks": rt.long_ticks.rows(rt.dt, realtime),
            "gc_collections": rt.gc_collections,
        },
        "bus": backend.bus_summary() if hasattr(backend, "bus_summary") else None,
    }
    report.setdefault("ros2", None)
    return report


def fault_report(rig, injector) -> dict:
    """The report's ``faults``: non-finite actions, safe stops and their causes, the joint
    estimator's stale and missing readings, the faults injected, the reader's context at the end
    (``reader``) and what went stale at each ``stale_sensor`` stop (``stale_stops``:
    :class:`sim2real.deploy.runtime.stale.StaleStops`), and the drives' errors."""
    from sim2real.deploy.core.stale import stale_context
    from sim2real.deploy.estimation.joint_tuning import reinit_warning

    rt, backend = rig.runtime, rig.backend
    return {
        "non_finite_actions": int(rt.counters.non_finite_actions.sum()),
        "safe_stops": int(rt.counters.safe_stops.sum()),
        "safe_stop_timeouts": int(rt.counters.safe_stop_timeouts.sum()),
        "by_cause": {k: int(v.sum()) for k, v in rt.counters.faults.items()},
        "estimator": {
            "stale_readings": int(rt.estimator.stale_readings.sum()),
            "missing_readings": int(rt.estimator.missing_readings.sum()),
            "reinitializations": int(rt.estimator.reinitializations.sum()),
            "warning": reinit_warning(
                rig.robot.joint_names, rt.estimator.reinitializations_per_joint, rt.time
            ),
        },
        "injected": injector.log if injector else [],
        # the reader (stream, arrivals, refusals; sim2real.deploy.core.stale) and each stale stop
        "reader": stale_context(backend),
        "stale_stops": rt.stale_stops.records,
        "stale_stops_dropped": rt.stale_stops.dropped,
        "smoothing_errors": list(rt.supervision.smoothing_errors),
        "drive_errors": [
            backend.describe_drive_error(int(j), int(rt.drive_errors[e, j]))
            for e, j in np.argwhere(rt.drive_errors)
        ],
    }


def deploy_run_main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    argv = attach_vectors(argv)
    try:
        args = build_parser(argv).parse_args(argv)  # BadOption is a ValueError
        args.policies = (
            {"excitation": f"excitation:{args.excitation}"}
            if args.excitation is not None
            else parse_policies(args.policy)
        )
        parse_terrain_option(args)
        parse_camera_source_option(args)
    except ValueError as exc:
        print(f"deploy-run: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.viewer:  # a window or nothing: refuse before the run starts
        from sim2real.deploy.observe.viewer import NoDisplayError, check_display

        try:
            check_display()
        except NoDisplayError as exc:
            print(f"deploy-run: error: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
    if args.video is not None:
        from sim2real.deploy.observe.video import headless_gl_default

        headless_gl_default()  # MUJOCO_GL=egl on a machine without a display, unless chosen
    if os.environ.get("MUJOCO_GL"):  # mujoco loads that GL backend when imported
        from sim2real.deploy.observe.video import import_mujoco

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
        from sim2real.deploy.observe.viewer import exit_now

        exit_now(code)
    return code


if __name__ == "__main__":
    raise SystemExit(deploy_run_main())
