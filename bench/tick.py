"""Tick cost: the full runtime against a bare sim2sim loop, same robot, same policy, same process.

**Full runtime** (:class:`sim2real.deploy.runtime.Runtime`, ``SimClock``, ``SimBackend(envs=1)``, the
benchmark policy through :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy`, goals from
:class:`sim2real.deploy.tasks.goals.GoalScheduler` every 4 s as in ``deploy-run``), driven by
``Runtime.run`` (the
garbage collector frozen and disabled). Per stage: the runtime's own stamps (``rt.latency``; the
stages of ``sim2real.deploy.runtime.STAGES``: read, estimate, observe, infer, guard, smooth, write,
physics). ``overhead`` is ``rt.tick_cost``: one tick without the physics stage
(``backend.advance``: MuJoCo steps, the plant's thermal and sensor models). ``tick`` is one tick
as the loop sees it, physics and the runtime's own bookkeeping included: the time between two
consecutive ``on_tick`` calls minus the goal scheduling (stamped in ``on_tick``; the first tick
of each round has no predecessor, so this one has ``ticks - rounds`` samples).

**Bare loop** (:class:`BareLoop`): the loop of unitree_rl_gym's sim2sim script
(``deploy/deploy_mujoco/deploy_mujoco.py``), written for our robots: ``robot.plant_model("torque")``
(direct motors, ``ctrlrange`` = effort limit), PD gains ``kp``/``kd`` of robot.toml. Per control
tick: read ``qpos``/``qvel`` from ``MjData`` into a :class:`~sim2real.deploy.core.state.RobotState`; the same
observation as the runtime (``Kinematics.update`` for the end effector, ``spec.observation`` with
the same PolicySpec and goals); the same MLPActor weights in torch eager
(``torch.set_num_threads(1)``, the loop inside ``torch.no_grad()``); ``target = action * 0.25 +
home`` (unitree's ``action_scale`` and ``default_angles``); then ``decimation`` times ``tau = kp
(target - q) + kd (0 - dq)``, ``d.ctrl = tau``, ``mj_step``. No estimator, guard, smoother,
sensor or thermal model. Its ``physics`` is the time inside ``mj_step`` alone; ``overhead`` is
the tick minus that (the Python PD at the physics rate counts as overhead: it is the controller).

**Floors** (:mod:`bench.floors`): the library calls of a tick alone, each beside its stage
(``FLOORS_OF_STAGE``). The three loops run in alternating blocks (``rounds``), so a load change
on the machine hits all. Ratios are full / bare, of the medians (``*_p50``, the PASS/FAIL
figure) and of the means.
"""

from __future__ import annotations

import gc
import time

import mujoco
import numpy as np

from bench.common import LEGGED_COMMAND, BenchPolicy, clear, histogram, is_legged, ratio, summary
from bench.floors import FLOOR_OUTSIDE_PHYSICS, FLOOR_STAGES, FloorLoop

#: Bare loop: unitree_rl_gym's ``action_scale`` (rad per unit action) around the home pose.
BARE_ACTION_SCALE = 0.25
#: Seconds between goals (deploy-run's default ``--goal-period``).
GOAL_PERIOD = 4.0
#: Ticks after RAMP_IN before the histograms are cleared.
WARMUP_TICKS = 500
BARE_STAGES = ("read", "observe", "infer", "target", "pd", "physics")
#: The floors (:mod:`bench.floors`) each stage of the runtime wraps: the guard's drive model
#: checks the smoother's motion inside the ``smooth`` stamp.
FLOORS_OF_STAGE = {
    "infer": ("infer",),
    "smooth": ("ruckig", "dynamics"),
    "estimate": ("fk",),
    "physics": ("mj_step",),
}


class BareLoop:
    """The bare sim2sim loop on one robot (see the module docstring).

    Args:
        bp: The benchmark policy (its torch ``actor`` and ``spec`` are used).
        seed: Seed of the goal sequence (goals from ``sim2real.deploy.tasks.goals.sample_goal``).

    Attributes:
        samples: (ticks, 7) int64 ns per tick: the stages of ``BARE_STAGES`` and the whole tick.
    """

    def __init__(self, bp: BenchPolicy, seed: int = 1):
        from sim2real.deploy.core.state import Kinematics, RobotState

        robot = bp.robot
        self.robot, self.spec, self.actor = robot, bp.spec, bp.actor
        self.m = robot.plant_model("torque")
        self.d = mujoco.MjData(self.m)
        self.d.qpos[:] = robot.home
        mujoco.mj_forward(self.m, self.d)
        self.kp = np.array([j.kp for j in robot.config.joints])
        self.kd = np.array([j.kd for j in robot.config.joints])
        self.default = np.array(robot.home, dtype=np.float64)
        self.decimation = robot.decimation
        self.dt = robot.control_period
        self.kinematics = Kinematics(robot)
        self.state = RobotState.zeros(1, robot.n_joints, robot.config.sensors.ambient_temperature)
        self.goal = np.zeros((1, 3))
        self.obs = np.zeros((1, bp.spec.obs_dim), dtype=np.float32)
        self.rng = np.random.default_rng(seed)
        self.time = 0.0
        self.next_goal = 0.0
        self.samples = np.zeros((0, 7), dtype=np.int64)

    def run(self, ticks: int) -> np.ndarray:
        """Run ``ticks`` control ticks (garbage collector frozen and disabled, as
        ``Runtime.run``); returns and appends to :attr:`samples` the (ticks, 7) ns stamps."""
        import torch

        from sim2real.deploy.tasks.goals import sample_goal

        m, d, st, kin, spec = self.m, self.d, self.state, self.kinematics, self.spec
        actor, goal, obs = self.actor, self.goal, self.obs
        obs_t = torch.from_numpy(obs)  # shares memory with obs
        kp, kd, default, scale = self.kp, self.kd, self.default, BARE_ACTION_SCALE
        decimation, clock, step = self.decimation, time.perf_counter_ns, mujoco.mj_step
        rec = np.zeros((ticks, 7), dtype=np.int64)
        gc.collect()
        gc.freeze()
        was_enabled = gc.isenabled()
        gc.disable()
        try:
            with torch.no_grad():
                for i in range(ticks):
                    if self.time >= self.next_goal:  # not timed: the harness, not the loop
                        goal[0] = sample_goal(self.robot, self.rng)
                        self.next_goal += GOAL_PERIOD
                    t0 = clock()
                    st.q[0] = d.qpos
                    st.dq[0] = d.qvel
                    t1 = clock()
                    kin.update(st)
                    spec.observation(st, goal, out=obs)
                    t2 = clock()
                    action = actor(obs_t).numpy()[0]
                    t3 = clock()
                    target = action * scale + default
                    st.last_action[0] = action
                    t4 = clock()
                    physics = 0
                    for _ in range(decimation):
                        tau = kp * (target - d.qpos) + kd * (0.0 - d.qvel)
                        d.ctrl[:] = tau
                        s = clock()
                        step(m, d)
                        physics += clock() - s
                    t5 = clock()
                    rec[i] = (
                        t1 - t0,
                        t2 - t1,
                        t3 - t2,
                        t4 - t3,
                        t5 - t4 - physics,
                        physics,
                        t5 - t0,
                    )
                    self.time += self.dt
        finally:
            if was_enabled:
                gc.enable()
            gc.unfreeze()
        if not (np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()):
            raise RuntimeError(f"bare loop on {self.robot.name}: the simulation diverged")
        self.samples = np.concatenate([self.samples, rec])
        return rec


class _TickTimer:
    """``on_tick`` for ``Runtime.run``: stamps each tick (between two calls, goal scheduling
    excluded), runs the goal scheduler, counts ticks spent outside RUNNING."""

    def __init__(self, goals, capacity: int):
        self.goals = goals
        self.samples = np.zeros(capacity, dtype=np.int64)
        self.n = 0
        self.last = 0
        self.not_running = 0

    def new_round(self) -> None:
        self.last = 0  # Runtime.run collects garbage before its first tick: skip that sample

    def __call__(self, rt) -> None:
        now = time.perf_counter_ns()
        if self.last and self.n < self.samples.shape[0]:
            self.samples[self.n] = now - self.last
            self.n += 1
        if rt.mode[0] != 2:  # Mode.RUNNING
            self.not_running += 1
        self.goals(rt)
        self.last = time.perf_counter_ns()


def make_runtime(bp: BenchPolicy, envs: int = 1, seed: int = 0, clock=None):
    """A Runtime as ``deploy-run`` builds it (SimBackend in the policy's mode, SimClock by
    default) and its task (:func:`sim2real.deploy.tasks.task.task_for`): an arm's goals every 4 s
    (3 s success time, seeded ``seed + 1``), a legged robot's fixed command ``LEGGED_COMMAND``."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime
    from sim2real.deploy.tasks.goals import GoalScheduler
    from sim2real.deploy.tasks.task import task_for

    robot = bp.robot
    policy = OnnxPolicy(bp.path, robot)
    backend = SimBackend(robot, mode=policy.spec.action.mode, envs=envs, seed=seed)
    rt = Runtime(robot, policy, backend, clock=clock)
    if not is_legged(robot):
        rng = np.random.default_rng(seed + 1)
        return rt, GoalScheduler(robot, envs, GOAL_PERIOD, None, 3.0, rng)
    rngs = [np.random.default_rng([seed + 1, e]) for e in range(envs)]
    task = task_for(
        robot, envs, backend, period=GOAL_PERIOD, rng=rngs, command=LEGGED_COMMAND, schedule=False
    )
    task.reset(rt, np.ones(envs, dtype=bool))
    return rt, task


def warm_up(rt, goals, max_seconds: float = 20.0) -> int:
    """Start the runtime, run through RAMP_IN (at most ``max_seconds`` simulated) and
    ``WARMUP_TICKS`` more ticks, then clear the runtime's histograms. Returns the ticks run."""
    rt.start()
    ticks = 0
    chunk = 100
    while (rt.mode != 2).any() and ticks * rt.dt < max_seconds:
        rt.run(chunk, on_tick=goals)
        ticks += chunk
    rt.run(WARMUP_TICKS, on_tick=goals)
    clear(rt.latency)
    clear(rt.tick_cost)
    return ticks + WARMUP_TICKS


def measure(bp: BenchPolicy, ticks: int, rounds: int) -> dict:
    """Full runtime vs bare loop on ``bp.robot``: ``ticks`` measured ticks of each, in ``rounds``
    alternating blocks. Returns the ``tick.<robot>`` entry of results.json (see bench/__init__)."""
    import torch

    from sim2real.deploy.runtime import STAGES

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        rt, goals = make_runtime(bp)
        warm = warm_up(rt, goals)
        timer = _TickTimer(goals, ticks)
        bare = BareLoop(bp) if bp.actor is not None else None  # a shipped policy: no bare loop
        if bare is not None:
            bare.run(WARMUP_TICKS)
            bare.samples = bare.samples[:0]
        floors = FloorLoop(rt)
        floors.run(WARMUP_TICKS)
        floors.samples = floors.samples[:0]
        per_round = [ticks // rounds + (1 if r < ticks % rounds else 0) for r in range(rounds)]
        for n in per_round:
            timer.new_round()
            rt.run(n, on_tick=timer)
            if bare is not None:
                bare.run(n)
            floors.run(n)
    finally:
        torch.set_num_threads(threads)

    full_stages = {s: summary(rt.latency, i) for i, s in enumerate(STAGES)}
    full_overhead = summary(rt.tick_cost)
    full_tick = summary(histogram(timer.samples[: timer.n]))
    b = bare.samples if bare is not None else np.zeros((0, 7), dtype=np.int64)
    bare_stages = {s: summary(histogram(b[:, i])) for i, s in enumerate(BARE_STAGES)}
    bare_overhead = summary(histogram(b[:, 6] - b[:, 5]))
    bare_tick = summary(histogram(b[:, 6]))
    f = floors.samples
    floor_stages = {s: summary(histogram(f[:, i])) for i, s in enumerate(FLOOR_STAGES)}
    outside = [FLOOR_STAGES.index(s) for s in FLOOR_OUTSIDE_PHYSICS]
    floor_overhead = summary(histogram(f[:, outside].sum(axis=1)))
    return {
        "ticks": int(ticks),
        "rounds": int(rounds),
        "warmup_ticks": int(warm),
        "control_rate_hz": 1.0 / bp.robot.control_period,
        "decimation": bp.robot.decimation,
        "full": {
            "stages": full_stages,
            "overhead": full_overhead,
            "tick": full_tick,
            "ticks_not_running": int(timer.not_running),
            "final_state": rt.mode_names(),
            "safe_stops": int(rt.counters.safe_stops.sum()),
            "goals_issued": int(getattr(goals, "goals", 0)),
        },
        "bare": {
            "stages": bare_stages,
            "overhead": bare_overhead,
            "tick": bare_tick,
        },
        "floors": {
            "stages": floor_stages,
            "overhead": floor_overhead,
            "glue_p50_us": {
                stage: full_stages[stage]["p50_us"] - sum(floor_stages[f]["p50_us"] for f in floors)
                for stage, floors in FLOORS_OF_STAGE.items()
            },
        },
        "ratio": {
            "tick_p50": ratio(full_tick["p50_us"], bare_tick["p50_us"]),
            "tick_mean": ratio(full_tick["mean_us"], bare_tick["mean_us"]),
            "overhead_p50": ratio(full_overhead["p50_us"], bare_overhead["p50_us"]),
            "overhead_mean": ratio(full_overhead["mean_us"], bare_overhead["mean_us"]),
        },
    }
