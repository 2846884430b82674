"""The push benchmark's loops for a whole-body tracking policy (:mod:`bench.push_reference`
``--tracking``): one play of its clip under a sequence of pushes, in rl_sar's loop on the true
state or in our runtime.

- :func:`rl_sar_loop`: rl_sar's tracking loop (:mod:`sim2real.stacks.loops.rl_sar_tracking`: its
  observation, clip, clock and yaw alignment, :mod:`sim2real.stacks.loops.rl_sar_motion`; the
  TorchScript ``policy.pt`` of the folder, its ``rl_kp``/``rl_kd``, ``action_scale`` and
  ``default_dof_pos``), on our robot's
  MJCF with torque actuators (``robot.plant_model("torque")``, the plant of
  :func:`bench.push_loops.unitree_loop`): the IMU quaternion and gyro and the joints read from
  the true MuJoCo state, ``tau = kp (target - q) - kd dq`` at every physics step; no estimator,
  guard or sensor noise. The robot starts at the home pose (the policy's ``default_dof_pos``),
  held ``SETTLE`` s by the policy's gains at it (rl_sar's GetUp), then the dance state's
  ``Reset`` aligns the clip to its heading and the clip plays once.
- :func:`tracking_runtime_loop`: ``deploy-run``'s rig (:class:`~sim2real.deploy.rig.rig.Rig`
  with the ``tracking`` task, :class:`~sim2real.deploy.tasks.motion.tracking.TrackingTask`) over
  :class:`~sim2real.deploy.backends.sim.plant.SimBackend` (position mode, the robot's sensor
  noise seeded by the run's seed): RAMP_IN to home, then the clip from the first RUNNING tick.

Both push with the soak's schedule (:class:`~sim2real.eval.world.pushes.DomainPushes`) on the
clip's clock: push ``k`` of a seed lands after the same clip frame in both loops (the wait drawn
from the clip's start, ours' first RUNNING tick). A run ends at the clip's last frame or at the
first true fall (:func:`sim2real.stacks.loops.bare.true_fall`), ours also at a stop; the figures are those
of :class:`sim2real.stacks.loops.bare.Run`, walked meaning s of clip played, the pushes' times on the clip's
clock (the time of the frame read by the tick the push follows) and the fall's at its tick's end.
"""

from __future__ import annotations

import numpy as np

from bench.push_loops import count_running_tick, finish_run
from sim2real.deploy.core.modes import RUNNING
from sim2real.eval.world.pushes import DomainPushes
from sim2real.stacks.loops.bare import RAMP_TIMEOUT, STOP_RAISED, Run, true_fall, true_upright


def tracking_runtime_loop(robot, policy, seed: int, seconds: float | None, pushes) -> Run:
    """One play of ``policy``'s clip (an ``OnnxPolicy`` on ``robot``, fresh, whose contract names
    the clip) in our runtime (module docstring); arguments and result as
    :func:`~sim2real.stacks.loops.rl_sar_pushed.rl_sar_loop`."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.rig.rig import Rig
    from sim2real.deploy.smoothing.ruckig_state import SmoothingError
    from sim2real.deploy.tasks.motion.source import motion_for
    from sim2real.eval.soak.push_response import PushResponse

    plant = SimBackend(robot, "position", envs=1, seed=seed)
    motion = motion_for(policy, robot, 1, playback="once")
    task = {"period": 1.0, "rng": np.random.default_rng(seed), "task": "tracking"}
    rig = Rig(robot, policy, plant, envs=1, task={**task, "motion": motion})
    rig.start()
    rt, monitor, clock = rig.runtime, rig.interventions, rig.task.motion
    ticks = round(clock.length / rt.dt)
    if seconds is not None:
        ticks = min(ticks, round(seconds / rt.dt))
    run = Run(checks={})
    schedule = DomainPushes([seed], pushes, rt.dt) if pushes else None
    response = PushResponse(schedule, rt.dt) if schedule else None
    counts = monitor.counts
    before, last_any = {k: int(v[0]) for k, v in counts.items()}, int(monitor.any[0])
    truth = np.zeros((1, 13))
    start = 0  # the tick that read the clip's first frame (the first RUNNING tick)
    while run.ticks < ticks:
        try:
            rt.tick()
        except SmoothingError:  # the runtime raised: the run ends there, counted apart
            plant.true_base_state(out=truth)
            run.fell_at, run.cause = rt.time, STOP_RAISED
            run.upright_stop = true_upright(robot, truth[0, 2], truth[0, 3:7], truth[0, 9])
            break
        rig.after_tick(rt)  # the interventions, then the tracking task (no hooks)
        plant.true_base_state(out=truth)
        if rt.mode[0] != RUNNING:
            if run.ticks or rt.time > RAMP_TIMEOUT:  # it danced, and stopped
                run.fell_at, run.cause = run.ticks * rt.dt, rt.cause_names()[0]
                run.upright_stop = true_upright(robot, truth[0, 2], truth[0, 3:7], truth[0, 9])
                break
            before, last_any = {k: int(v[0]) for k, v in counts.items()}, int(monitor.any[0])
            continue
        start = start or rt.ticks
        last_any = count_running_tick(run, robot, rt, plant, monitor, last_any, schedule)
        if true_fall(robot, truth[0, 2], truth[0, 3:7]):
            run.fell_at, run.cause = run.ticks * rt.dt, "fall"
            break
        if schedule is not None:  # as the soak: the estimate judged, then the tick's push
            response(rt, plant)
            schedule(rt, plant)
    finish_run(run, rt, monitor, before, response)
    run.pushes = [t - start * rt.dt for t in schedule.times[0]] if schedule else []
    return run
