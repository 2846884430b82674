"""The loops of the push benchmark (:mod:`bench.push_reference`): one run of a policy, walking at a
constant command under a sequence of pushes, in its own loop on the true state or in our runtime.

- :func:`unitree_loop`: unitree_rl_gym's own loop (``deploy_mujoco.py``'s control step,
  :func:`sim2real.stacks.loops.unitree_rl_gym.controller`) on our robot's MJCF with torque
  actuators (``robot.plant_model("torque")``): the PD law at every physics step, the true state;
  no estimator, guard or sensor noise.
- :func:`truth_loop`: the same loop for a policy that has no published loop of its own (the
  shipped go2, an mjlab export): its exported ONNX file and its spec's observation built from the
  true state (:meth:`sim2real.deploy.core.state.BaseState.set_truth`), the robot's PD gains.
- :func:`runtime_loop`: ``deploy-run``'s rig (:class:`~sim2real.deploy.rig.rig.Rig`, no task) over
  :class:`~sim2real.deploy.backends.sim.plant.SimBackend` (position mode, the robot's shipped
  sensor noise, seeded by the run's seed) with the policy's drive applied, as ``deploy-run`` runs
  it; its interventions (:class:`~sim2real.deploy.monitors.interventions.InterventionMonitor`)
  and the base estimate's error in the second after each push
  (:class:`~sim2real.eval.soak.push_response.PushResponse`).

Every loop pushes with the soak's own schedule (:class:`~sim2real.eval.world.pushes.DomainPushes`
on the loop's clock, which is the policy's gait clock: the same push ``k`` of a seed at the same
time and gait phase in every loop; ours walks once its RAMP_IN is over and is pushed only
RUNNING), as a force over the push's window or by setting the velocity (``PushRanges.apply``),
and runs ``seconds`` on that clock; it ends at the first true fall: the
base below ``TRUE_FALL_HEIGHT`` of its standing height or tilted past the fall tilt (the soak's
:class:`~sim2real.deploy.monitors.estimation.EstimationMonitor`), or, in ours, a safe stop.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.sim.disturbances import SimDisturbances
from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.core.stacks import STACK_REGISTRY
from sim2real.eval.world.pushes import DomainPushes, PushRanges
from sim2real.stacks.loops.bare import (
    RAMP_TIMEOUT,
    STOP_RAISED,
    Run,
    bare_plant,
    judge_tick,
    past_hard_limit,
    quiet,
    true_fall,
    true_upright,
)
from sim2real.stacks.loops.walk import Walk


def _bare_run(
    robot,
    plant,
    seed,
    seconds,
    pushes: PushRanges | None,
    act,
    path=None,
    watch=None,
    walk=None,
    pushed=None,
) -> Run:
    """The own loops' common body on ``plant`` (a :class:`BarePlant`): ``act(t)`` writes the
    policy's next PD target from the true state after a control period, and returns it;
    ``watch(t, d, target)`` (optional) sees each tick's true state and next target
    (:mod:`bench.guard_replay`); ``walk``: what the pushes read (``ticks``, ``mode``; default a
    :class:`~sim2real.stacks.loops.walk.Walk`), its ``ticks`` set here; ``pushed``: what the
    pushes act through (default
    :class:`~sim2real.deploy.backends.sim.disturbances.SimDisturbances` on ``plant``'s model)."""
    m, d = plant.m, plant.d
    walk, run = walk or Walk(), Run()
    schedule = DomainPushes([seed], pushes, robot.control_period) if pushes else None
    base = pushed or SimDisturbances(robot, [m], [d])  # the plant's push methods
    for tick in range(1, round(seconds / robot.control_period) + 1):
        plant.advance()
        t = tick * robot.control_period
        target = act(t)
        if watch is not None:
            watch(t, d, target)
        if path is not None:
            path.append((t, float(d.qpos[0]), float(d.qpos[1])))
        if judge_tick(run, walk, robot, d, tick, robot.control_period, schedule, base):
            break
    run.walked *= robot.control_period
    run.pushes = list(schedule.times[0]) if schedule else []
    return run


def unitree_loop(
    robot, cfg: dict, net, seed: int, seconds: float, pushes, command=None, path=None, watch=None
):
    """One run of unitree's loop (module docstring) with ``net`` (the TorchScript policy, eval
    mode) and deploy config ``cfg``, walking at ``command`` (default the config's ``cmd_init``)
    under ``pushes`` (a :class:`PushRanges`; None: none) for ``seconds``; returns a :class:`Run`.
    ``path``: a list that receives ``(t, x, y)`` (s, m) of the base after each control tick;
    ``watch``: as :func:`_bare_run`'s."""
    default = np.array(cfg["default_angles"], float)
    kp, kd = np.array(cfg["kps"], float), np.array(cfg["kds"], float)
    plant = bare_plant(robot, (kp, kd, default.copy()))
    # legged_gym's own loop, through the stacks' registry (sim2real/stacks/legged_gym.py)
    controller = STACK_REGISTRY.get("legged_gym").face("own_loop")
    act = controller(cfg, net, plant, command)
    return _bare_run(robot, plant, seed, seconds, pushes, act, path, watch)


def truth_loop(
    robot, policy, seed: int, seconds: float, pushes, command, path=None, watch=None
) -> Run:
    """One run of ``policy`` (an :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy` on
    ``robot``, fresh: a recurrent policy's memory) on the true state (module docstring), its
    gait clock the time walked; arguments and result as :func:`unitree_loop`."""
    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.rig.own_loop import OwnLoop

    state = RobotState.legged(1, robot.n_joints, robot.n_feet)
    state.command[0] = command
    kp = np.array([j.kp for j in robot.config.joints], dtype=float)
    kd = np.array([j.kd for j in robot.config.joints], dtype=float)
    plant = bare_plant(robot, (kp, kd, np.array(robot.home, dtype=float)))
    loop = OwnLoop(policy, plant, state, np.zeros((1, 3)), robot.control_period)

    def act(t):  # the gait clock: the bench's tick times
        return loop.act(t)[0]

    return _bare_run(robot, plant, seed, seconds, pushes, act, path, watch, walk=loop)


def observes_base_velocity(policy) -> bool:
    """Whether ``policy``'s observation holds the base's linear velocity (a
    ``base_linear_velocity`` block): what our runtime feeds it is the base estimator's estimate."""
    return any(b.name == "base_linear_velocity" for b in policy.spec.observation_blocks)


class _OurPlant:
    """:class:`~sim2real.deploy.backends.sim.plant.SimBackend`'s one env as :func:`_bare_run`'s
    plant: its model and data, its ``advance``."""

    def __init__(self, sim):
        self.sim, self.m, self.d = sim, sim.models[0], sim.datas[0]

    def advance(self) -> None:
        self.sim.advance()


def plant_loop(
    robot, policy, seed: int, seconds: float, pushes, command, estimate: bool = False
) -> Run:
    """The truth-fed loop (:func:`truth_loop`) on our plant: :class:`~sim2real.deploy.backends.
    sim.plant.SimBackend` in position mode, seeded by ``seed`` (the drives, motors and sensors
    :func:`runtime_loop` runs on), pushed through the plant as ours is. ``estimate``: the policy
    sees the base (attitude, angular and linear velocity) as the runtime's base estimator
    (:class:`~sim2real.deploy.estimation.base.BaseStateEstimator`) gives it from the plant's
    sensor frame of each tick (IMU, foot contacts) and the true joints; False: the truth. The
    two differ by the estimate alone: what it costs a policy that observes the base's velocity.
    Arguments and result as :func:`truth_loop`."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.estimation.base import BaseStateEstimator
    from sim2real.deploy.rig.own_loop import OwnLoop

    sim = SimBackend(robot, "position", envs=1, seed=seed)
    state = RobotState.legged(1, robot.n_joints, robot.n_feet)
    state.command[0] = command
    feed = None
    if estimate:
        estimator = BaseStateEstimator(robot, 1)
        frame = sim.read()
        estimator.reset(frame.time, frame.imu_acceleration, orientation=frame.imu_orientation)

        def feed(s):  # the tick's sensor frame, after the plant's advance
            estimator.update(sim.read(), s.q, s.dq, out=s.base)

    loop = OwnLoop(policy, sim, state, np.zeros((1, 3)), robot.control_period, base=feed)

    def act(t):
        return loop.act(t)[0]

    plant = _OurPlant(sim)
    return _bare_run(robot, plant, seed, seconds, pushes, act, walk=loop, pushed=sim)


def runtime_loop(robot, policy, seed: int, seconds: float, pushes, command, terrain=None) -> Run:
    """One run of our runtime (module docstring) with ``policy`` (an ``OnnxPolicy`` on ``robot``,
    fresh); arguments and result as :func:`truth_loop`. ``terrain``: a
    :class:`~sim2real.eval.world.terrain.TerrainDraw` the plant's ground is laid from (its
    random parts from ``seed`` as ``deploy-run --terrain --seed`` draws them), the true fall
    judged above the ground under the base (None: the plane)."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.rig.rig import Rig
    from sim2real.deploy.smoothing.ruckig_state import SmoothingError
    from sim2real.eval.soak.push_response import PushResponse

    ground, models = None, None
    if (
        terrain is not None
    ):  # as deploy-run --terrain lays it (sim2real.deploy.backends.sim.options)
        spec = robot.mjspec("position")
        ground = terrain.apply(spec, np.random.default_rng([seed, 0]))
        models = [spec.compile()]
    plant = SimBackend(robot, "position", envs=1, seed=seed, models=models)
    if ground is not None:
        plant.grounds = [ground]

    def above() -> float:  # m, the true base above the ground under it
        return float(truth[0, 2]) - (
            0.0 if ground is None else float(plant.ground_height(truth)[0])
        )

    rig = Rig(robot, policy, plant, envs=1, truth=False)  # its interventions; no task
    rt, monitor = rig.runtime, rig.interventions
    rt.velocity_command[0] = command
    rig.start()
    run = Run(checks={})
    schedule = DomainPushes([seed], pushes, rt.dt) if pushes else None
    response = PushResponse(schedule, rt.dt) if schedule else None
    counts = monitor.counts
    before, last_any = {k: int(v[0]) for k, v in counts.items()}, int(monitor.any[0])
    truth = np.zeros((1, 13))
    while rt.ticks < round(seconds / rt.dt):
        try:
            rt.tick()
        except SmoothingError:  # the runtime raised: the run ends there, counted apart
            plant.true_base_state(out=truth)
            run.fell_at, run.cause = rt.time, STOP_RAISED
            run.upright_stop = true_upright(robot, above(), truth[0, 3:7], truth[0, 9])
            break
        rig.after_tick(rt)  # the interventions
        plant.true_base_state(out=truth)
        if rt.mode[0] != RUNNING:
            if run.ticks or rt.time > RAMP_TIMEOUT:  # it walked, and stopped
                run.fell_at, run.cause = rt.time, rt.cause_names()[0]
                run.upright_stop = true_upright(robot, above(), truth[0, 3:7], truth[0, 9])
                break
            before, last_any = {k: int(v[0]) for k, v in counts.items()}, int(monitor.any[0])
            continue
        last_any = count_running_tick(run, robot, rt, plant, monitor, last_any, schedule)
        if true_fall(robot, above(), truth[0, 3:7]):
            run.fell_at, run.cause = rt.time, "fall"
            break
        if schedule is not None:  # as the soak: the estimate judged, then the tick's push
            response(rt, plant)
            schedule(rt, plant)
    finish_run(run, rt, monitor, before, response)
    run.pushes = list(schedule.times[0]) if schedule else []
    return run


def count_running_tick(run: Run, robot, rt, plant, monitor, last_any: int, schedule) -> int:
    """Count one RUNNING tick of our runtime into ``run``: the tick, its interventions (the
    monitor's ``any`` since ``last_any``; those of a quiet tick apart), a true joint past its
    hard limit. Returns the monitor's ``any`` now."""
    run.ticks += 1
    changed = int(monitor.any[0]) - last_any
    run.intervened += changed
    run.past_limit += past_hard_limit(robot, plant.true_position()[0])
    if quiet(rt.time, schedule.times[0] if schedule else []):
        run.quiet_ticks += 1
        run.quiet_intervened += changed
    return int(monitor.any[0])


def finish_run(run: Run, rt, monitor, before: dict, response) -> None:
    """``run``'s time walked, the checks that intervened since ``before`` and the after-push
    error, at the end of our runtime's run."""
    run.walked = run.ticks * rt.dt
    run.checks = {k: int(v[0]) - before[k] for k, v in monitor.counts.items() if v[0] > before[k]}
    run.after_push = response.summary() if response else None
