"""The reach task on the sim plant, for training.

Train what you deploy: a policy trained here meets exactly the stack the runtime runs. Its
observations are built by the policy's :class:`~sim2real.deploy.spec.policy_spec.PolicySpec` from the state
the runtime's Kalman filter (:class:`~sim2real.deploy.estimation.joints.JointStateEstimator`) estimates from
noisy, quantized, late and sometimes missing encoder readings of
:class:`~sim2real.deploy.backends.sim.plant.SimBackend`;
its actions pass through the runtime's :class:`~sim2real.deploy.safety.guard.SafetyGuard` and Ruckig
:class:`~sim2real.deploy.smoothing.CommandSmoother` (re-anchored to the measured pose as the runtime does)
before they reach the drives. What the guard and the smoother changed is an *intervention* and is
penalized: a policy that leans on the guard fails on a robot whose guard is tuned differently.

:class:`ReachTask` is the batched core (arrays (envs, ...)), built through the one assembly of a run
(:class:`~sim2real.deploy.rig.rig.Rig`: the runtime's stages and state, the intervention monitor, the
goals), its stages stepped by the rig's :class:`~sim2real.deploy.rig.learner_tick.LearnerTick` without
the runtime's supervision; :class:`ArmReachEnv` is the Gymnasium env of one robot, :class:`ReachVecEnv`
the Stable-Baselines3 ``VecEnv`` of many in lockstep in one ``SimBackend``.

Episode: continuous operation, as in the soak. The robot starts at rest at a random pose inside its
soft limits (or, with ``ReachConfig.start_poses``, at one of the poses where a soak saw a policy
miss its goal), with dynamics, encoder noise, latency and dropout drawn from the robot's soak ranges
(:func:`sim2real.eval.world.session_ranges.session_ranges`) and a fault schedule from its soak's fault
ranges at the training interval (:mod:`sim2real.policies.episode_faults`). Goals are chained without
resets: a new goal is drawn when the end effector comes within ``task.success_radius`` of it or
after ``goal_timeout`` s. The episode ends at a hard joint limit crossed by the joint or by the
guard's estimate (terminated: the runtime would make a safe stop) or after ``episode_seconds``
(truncated; minutes, so that the policy meets the states of continuous operation).

The reward per control tick is :class:`RewardConfig`'s (its docstring gives the terms).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import gymnasium as gym
import numpy as np

from sim2real.deploy.backends.sim.camera import attach_plant_camera
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.rig.learner_tick import LearnerTick
from sim2real.deploy.rig.rig import Rig
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.eval.world.dynamics import Dynamics, DynamicsRanges, randomized_model, sample_dynamics
from sim2real.eval.world.fault_schedule import FaultRanges
from sim2real.eval.world.sensors import SensorRanges, apply_sensors, sample_sensors
from sim2real.eval.world.session_draw import sample_faults
from sim2real.eval.world.session_ranges import session_ranges
from sim2real.policies.episode_faults import EpisodeFaults, training_fault_ranges
from sim2real.policies.locomotion import LearnerPolicy, learner_rig
from sim2real.robots import Robot

#: The stream of the episodes' fault seeds (``numpy.random.default_rng([seed, FAULT_SEEDS])``):
#: apart from the task's own stream, so that the other draws do not depend on the faults.
FAULT_SEEDS = 3


@dataclass(frozen=True)
class RewardConfig:
    """Reward coefficients: the course's reach reward stack plus goal-distance shaping.

    Reward per control tick::

        + success        at each goal reached
        + soft_limit     per joint whose true position is in the soft band (beyond 90 % of the
                         range)                                                       (negative)
        + intervention   per tick on which the guard or the smoother changed the     (negative)
                         command (velocity clamp, workspace / collision / effort hold, the
                         smoother's brake before a soft limit; ours)
        + workspace      end effector outside the guard's workspace box            (negative)
        + hard_limit     at a hard limit, and the episode terminates                (negative)
        - energy   * sum |tau * dq|                                                  (W)
        - heat     * sum (tau / tau_cont)^2  Joule heating of the windings relative to the motor's
                                             rated continuous torque (ours: over hours, copper loss,
                                             not mechanical power, is what overheats a motor)
        - jerk     * |dq - dq_prev| / dt     (rate of change of velocity)
        + survival
        + shaping  * (d_prev - gamma_s * d)  potential-based shaping F = gamma_s Phi(s') - Phi(s)
                                             with Phi = -shaping * d, d the goal distance (m): it
                                             leaves the optimal policy unchanged when gamma_s is
                                             the learner's discount (Ng, Harada and Russell, ICML
                                             1999); the shipped recipe uses gamma_s = 1, the plain
                                             distance difference, a constant pull toward the goal.

    Attributes:
        success: Reward per goal reached (default: +1).
        soft_limit: Per joint and tick whose true position is beyond the soft limit (default: -0.1
            in the soft band).
        intervention: Per tick on which the guard or the smoother changed the command (ours,
            twice the soft-limit coefficient: the soak counts these and fails above 1 % of
            ticks).
        hard_limit: At a hard limit; the episode terminates (default: -1).
        workspace: Per tick with the end effector outside ``safety.workspace_min/max`` (ours, the
            soft-limit coefficient: there the runtime's guard rejects commands and holds).
        energy: Coefficient of the mechanical power sum |tau dq|, per W (default: 1e-4).
        heat: Coefficient of ``sum_j (tau_j / continuous_torque_j)^2``, the windings' copper
            loss relative to the rated continuous load (ours; at 5e-4 a joint at its rated
            torque for a 4-s goal period costs 0.4). It trades reaching speed for cooler drives
            and, the arm being redundant, postures that load them less; 0 (off) in the shipped
            recipe, the README gives the comparison.
        jerk: Coefficient of |dq - dq_prev| / dt, per rad/s^2 (default: 1e-5).
        survival: Per tick (default: +0.001).
        shaping: Per metre the end effector comes closer to the goal (ours; 0 disables it).
        shaping_gamma: The discount of the potential-based shaping: 1.0 (default, the shipped
            recipe) gives the plain distance difference; the learner's ``gamma`` gives the
            policy-invariant form.
    """

    success: float = 1.0
    soft_limit: float = -0.1
    intervention: float = -0.2
    hard_limit: float = -1.0
    workspace: float = -0.1
    energy: float = 1e-4
    heat: float = 0.0
    jerk: float = 1e-5
    survival: float = 0.001
    shaping: float = 5.0
    shaping_gamma: float = 1.0


@dataclass(frozen=True)
class ReachConfig:
    """Task settings.

    Attributes:
        mode: Control mode ('velocity', the shipped recipe; 'position' as the variant).
        reference: Position mode: 'absolute' (an action spans the joint range) or 'current' (an
            action is a step from the estimated position, at most one control period at the
            velocity limit); see :class:`sim2real.deploy.spec.policy_spec.ActionSpec`.
        episode_seconds: Episode length, s (truncation).
        goal_timeout: A goal not reached within this time is replaced, s (the runtime's success
            window is 3 s).
        sensors: Encoder noise sigma (rad), latency (ticks) and dropout drawn per episode; None
            (default): the robot's soak ranges, ``session_ranges(robot).sensors``
            (:func:`sim2real.eval.world.session_ranges.session_ranges`: a noise range scaled to the
            robot's own encoder noise).
        dynamics: Ranges of the dynamics randomization; ``DynamicsRanges.none()`` for the nominal
            robot; None (default): the robot's soak ranges, ``session_ranges(robot).dynamics``.
        start_fraction: Start poses are drawn uniformly within this fraction of the soft limits.
        start_poses: Optional joint poses (rad, each of length n) to start episodes from, e.g.
            where a soak saw the policy miss (:func:`sim2real.eval.report.build.missed_states`); poses
            outside the soft limits are clipped into them.
        start_pose_probability: Probability that an episode starts at one of ``start_poses``.
        success_radius: m, the goal counts as reached within this distance; default the robot's
            ``task.success_radius`` (what the soak judges). A smaller one trains the policy to
            come closer than the soak requires, a margin for the gap between the runtime's
            nominal kinematics and a randomized arm (link lengths +-10 %).
        faults: Each episode meets a fault schedule drawn from ``fault_ranges`` (False: none).
        fault_interval: Mean time between faults in training, s (replaces the soak's
            ``mean_interval``; our choice: most 120-s episodes meet one or two faults).
        fault_ranges: The soak's fault ranges; None (default): the robot's,
            ``session_ranges(robot).faults``.
        reward: The reward coefficients.
    """

    mode: str = "velocity"
    reference: str = "absolute"
    episode_seconds: float = 120.0
    goal_timeout: float = 3.0
    sensors: SensorRanges | None = None
    dynamics: DynamicsRanges | None = None
    start_fraction: float = 0.9
    start_poses: tuple[tuple[float, ...], ...] = ()
    start_pose_probability: float = 0.5
    success_radius: float | None = None
    faults: bool = True
    fault_interval: float = 90.0
    fault_ranges: FaultRanges | None = None
    reward: RewardConfig = field(default_factory=RewardConfig)


class ReachTask:
    """``envs`` reach tasks stepped in lockstep (the batched core of both env classes).

    Args:
        robot: The robot.
        envs: Number of robots.
        config: Task settings; its ``sensors`` and ``dynamics`` left None become the robot's soak
            ranges (``self.config`` holds the ranges drawn from).
        spec: The policy contract; default ``PolicySpec.for_robot(robot, mode=config.mode,
            reference=config.reference)``.
        seed: Seed of every random stream (poses, goals, dynamics, noise, sensors; the episodes'
            fault seeds from their own stream, ``FAULT_SEEDS``).

    Raises:
        ValueError: the spec's action mode differs from ``config.mode``.
    """

    def __init__(
        self,
        robot: Robot,
        envs: int,
        config: ReachConfig | None = None,
        spec: PolicySpec | None = None,
        seed: int = 0,
    ):
        self.config = config = _with_soak_ranges(robot, config or ReachConfig())
        self.spec = spec or PolicySpec.for_robot(
            robot, mode=config.mode, reference=config.reference
        )
        if self.spec.action.mode != config.mode:
            raise ValueError(
                f"spec.action.mode '{self.spec.action.mode}' differs from config.mode "
                f"'{config.mode}'"
            )
        self.spec.check_robot(robot)
        self.robot, self.envs, self.n = robot, envs, robot.n_joints
        self.dt = robot.control_period
        self.rng = np.random.default_rng(seed)
        self.backend = SimBackend(robot, mode=config.mode, envs=envs, seed=seed + 1)
        #: a spec with an image block: the plant's camera, rendered as deploy-run renders it (its
        #: rate, latency and depth model; the robot's task scene, its marker at the goal), read
        #: by the runtime's own camera stage (``self.rig.runtime.cameras``) each tick
        self.camera = attach_plant_camera(self.backend, self.spec, seed=seed + 2)
        #: the episodes' fault schedules (None: faults off) and what they are drawn from
        self.faults = EpisodeFaults(self.backend) if config.faults else None
        self.fault_ranges = training_fault_ranges(config.fault_ranges, config.fault_interval)
        self._fault_seeds = np.random.default_rng([seed, FAULT_SEEDS])
        self.fault_seed = np.zeros(envs, dtype=np.int64)  # each env's episode fault seed
        self.success_radius = (
            robot.config.task.success_radius
            if config.success_radius is None
            else float(config.success_radius)
        )
        self.t_episode = np.zeros(envs)
        #: the run (sim2real.deploy.rig): the runtime's stages and state, the intervention
        #: monitor, the chained goals (sim2real.deploy.tasks.episodes.EpisodeGoals: issued,
        #: reached, missed). :meth:`step` runs the rig's LearnerTick: the tick's stages without
        #: the runtime's supervision (no RAMP_IN, no safe stops: an episode ends instead), the
        #: learner's action given to it, so the runtime's policy slot is never called.
        self.rig = self._rig(config)
        self.learner_tick = LearnerTick(self.rig, self.spec, self.faults)
        rt = self.rig.runtime
        self.estimator, self.kinematics, self.state = rt.estimator, rt.kinematics, rt.state
        self.guard, self.smoother = rt.guard, rt.smoother
        self._continuous = np.array([m.continuous_torque for m in robot.motors])
        self._start_poses = np.asarray(config.start_poses, dtype=np.float64).reshape(-1, self.n)
        self.randomize = config.dynamics != DynamicsRanges.none()
        self.dynamics = [Dynamics.nominal(self.n)] * envs
        self._ws_min = np.asarray(robot.config.safety.workspace_min)
        self._ws_max = np.asarray(robot.config.safety.workspace_max)
        self.obs = np.zeros((envs, self.spec.obs_dim), dtype=np.float32)
        self._distance = np.zeros(envs)
        self._prev_dq = np.zeros((envs, self.n))
        self.task = self.rig.task
        self.goal = self.task.goal  # (envs, 3) m
        if self.camera is not None:
            self.camera.show_goal(self.goal)  # the marker shows the episodes' goals
        # per-episode statistics
        self.limit_violations = np.zeros(envs, dtype=np.int64)
        self.interventions = np.zeros(envs, dtype=np.int64)
        self.ticks = np.zeros(envs, dtype=np.int64)
        self.episode_return = np.zeros(envs)
        self.reset(np.ones(envs, dtype=bool))
        # the soak's definition of an intervention (sim2real.deploy.monitors.interventions), counted
        # per tick from the counters as the first episodes start
        self.monitor = self.rig.interventions
        self.monitor.resync()

    def _rig(self, config: ReachConfig) -> Rig:
        """The run (:mod:`sim2real.deploy.rig`): the runtime's stages with the learner in the
        policy's slot, the chained goals on the episodes' clock, no truth, no task reset."""
        robot, envs = self.robot, self.envs
        return learner_rig(
            robot,
            LearnerPolicy(self.spec, envs),
            self.backend,
            envs,
            {
                "period": config.goal_timeout,
                "rng": self.rng,
                "clock": self.t_episode,
                "success_radius": self.success_radius,
            },
        )

    # ------------------------------------------------------------------ resets
    def reset(self, which: np.ndarray) -> None:
        """Start new episodes for the envs in the boolean mask ``which``."""
        robot, cfg = self.robot, self.config
        idx = np.nonzero(which)[0]
        if self.faults is not None:
            for e in idx:  # a fault of the last episode still in force ends with it
                self.faults.stop(e)
        if self.randomize:
            for e in idx:
                self.dynamics[e] = sample_dynamics(robot, self.rng, cfg.dynamics)
                self.backend.set_model(e, randomized_model(robot, cfg.mode, self.dynamics[e]))
        lo = robot.home + cfg.start_fraction * (robot.soft_lower - robot.home)
        hi = robot.home + cfg.start_fraction * (robot.soft_upper - robot.home)
        q0 = np.array(self.backend.true_position())
        q0[idx] = self.rng.uniform(lo, hi, (len(idx), self.n))
        if len(self._start_poses):
            listed = idx[self.rng.random(len(idx)) < cfg.start_pose_probability]
            picks = self._start_poses[self.rng.integers(len(self._start_poses), size=len(listed))]
            q0[listed] = np.clip(picks, robot.soft_lower, robot.soft_upper)
        self.backend.reset(q0, envs=which)
        for e in idx:
            draw = sample_sensors(self.rng, cfg.sensors)
            apply_sensors(self.backend, e, draw)
            if self.faults is not None:  # sized against this episode's sensors and plant
                self.fault_seed[e] = self._fault_seeds.integers(2**31)
                schedule = sample_faults(
                    robot,
                    int(self.fault_seed[e]),
                    cfg.episode_seconds,
                    draw,
                    self.fault_ranges,
                    self.backend.models[e],
                )
                self.faults.start(e, schedule, self.backend.time)
        frame = self.backend.read()
        # the robot has rested at q0: where no reading has arrived yet (latency at the plant's
        # first ticks, a dropout), the pose itself stands in for it, as Runtime.start waits for
        position = np.where(np.isnan(frame.position), q0, frame.position)
        stamp = np.where(np.isnan(frame.position_stamp), self.backend.time, frame.position_stamp)
        self.estimator.reset(position, stamp, envs=which)
        self.state.q[idx] = position[idx]
        self.state.dq[idx] = 0.0
        self.state.last_action[idx] = 0.0
        self.state.winding_temperature[idx] = frame.winding_temperature[idx]
        self.smoother.sync(self.state.q, self.state.dq, envs=which)
        self.guard.reset(self.state.q, envs=which)
        self._prev_dq[idx] = 0.0
        self.t_episode[idx] = 0.0
        self.limit_violations[idx] = 0
        self.interventions[idx] = 0
        self.ticks[idx] = 0
        self.episode_return[idx] = 0.0
        self.task.reset(self, which)  # new goals
        self.kinematics.update(self.state)
        self.spec.observation(self.state, self.goal, out=self.obs)
        self._distance[idx] = self._true_distance()[idx]

    def spaces(self) -> tuple[gym.spaces.Box, gym.spaces.Box]:
        """Observation space ``Box(-clip, clip, (obs_dim,))`` and action space
        ``Box(-1, 1, (act_dim,))`` of one robot, float32."""
        clip = max(b.clip for b in self.spec.observation_blocks)
        obs = gym.spaces.Box(-clip, clip, (self.spec.obs_dim,), np.float32)
        return obs, gym.spaces.Box(-1.0, 1.0, (self.spec.act_dim,), np.float32)

    def _true_distance(self) -> np.ndarray:
        return np.linalg.norm(self.backend.end_effector_position() - self.goal, axis=1)

    # ------------------------------------------------------------------ the step
    def step(self, action: np.ndarray):
        """Advance every env one control period under ``action`` ((envs, n) in [-1, 1]).

        The stages and their order are the runtime's tick (:meth:`sim2real.deploy.runtime.Runtime.tick`):
        target, guard, smoother, drives, physics, encoders, Kalman filter, re-anchoring.

        Returns:
            ``(obs, reward, terminated, truncated)``: float32 (envs, obs_dim) observation after
            the step, (envs,) reward, (envs,) bool each. Finished envs are *not* reset here.
        """
        robot, rew, guard, state = self.robot, self.config.reward, self.guard, self.state
        action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        # target, guard, smoother, drives, physics, encoders, Kalman filter, re-anchoring
        intervened = self.learner_tick.step(action, self.goal, self.obs)
        self.t_episode += self.dt
        self.ticks += 1

        q = self.backend.true_position()
        dq = self.backend.true_velocity()
        tau = self.backend.joint_torque()
        hard = ((q < robot.position_lower) | (q > robot.position_upper)).any(axis=1)
        hard |= guard.hard_violation  # the runtime would make a safe stop
        soft = ((q < robot.soft_lower) | (q > robot.soft_upper)).sum(axis=1)
        ee = self.backend.end_effector_position()
        outside = ((ee < self._ws_min) | (ee > self._ws_max)).any(axis=1)
        distance, success = self.task.judge(ee)

        reward = np.full(self.envs, rew.survival)
        reward += rew.shaping * (self._distance - rew.shaping_gamma * distance)
        reward += rew.success * success
        reward += rew.soft_limit * soft
        reward += rew.intervention * intervened
        reward += rew.hard_limit * hard
        reward += rew.workspace * outside
        reward -= rew.energy * np.abs(tau * dq).sum(axis=1)
        reward -= rew.heat * np.square(tau / self._continuous).sum(axis=1)
        reward -= rew.jerk * np.linalg.norm(dq - self._prev_dq, axis=1) / self.dt
        self._prev_dq[:] = dq

        self.limit_violations += hard
        self.interventions += intervened
        self.episode_return += reward
        self.task(self)  # goals reached or timed out: new ones
        new = self.task.new
        if new.any():  # the goal changed: distances and observations refer to the new goal
            distance[new] = np.linalg.norm(ee[new] - self.goal[new], axis=1)
            self.spec.observation(state, self.goal, out=self.obs)
        self._distance[:] = distance
        truncated = (self.t_episode >= self.config.episode_seconds - 1e-9) & ~hard
        return self.obs, reward, hard, truncated

    def episode_info(self, e: int) -> dict:
        """Statistics of env ``e``'s episode so far (for the training logs).

        ``is_success`` is the fraction of decided goals (reached, or timed out) that were reached.
        """
        return {
            "is_success": self.task.success(e),
            "goals_reached": int(self.task.reached[e]),
            "goals_missed": int(self.task.missed[e]),
            "joint_limit_violations": int(self.limit_violations[e]),
            "intervention_rate": float(self.interventions[e]) / max(int(self.ticks[e]), 1),
        }


class ArmReachEnv(gym.Env):
    """Gymnasium env of one robot's reach task (see the module docstring).

    Observation: ``Box(-clip, clip, (spec.obs_dim,), float32)``; action: ``Box(-1, 1, (n,),
    float32)``. ``info`` holds ``is_success`` (fraction of goals reached), ``goals_reached``,
    ``goals_missed``, ``joint_limit_violations`` and ``intervention_rate`` (fraction of ticks on
    which the guard or the smoother changed the command) of the episode.
    """

    metadata = {"render_modes": []}

    def __init__(self, robot: Robot, config: ReachConfig | None = None, seed: int = 0):
        self.robot, self.config = robot, config
        self.task = ReachTask(robot, 1, config, seed=seed)
        self.observation_space, self.action_space = self.task.spaces()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:  # every stream (plant sensors, goals, dynamics) restarts from seed
            self.task = ReachTask(self.robot, 1, self.config, seed=seed)
        else:
            self.task.reset(np.ones(1, dtype=bool))
        return self.task.obs[0].copy(), {}

    def step(self, action):
        obs, reward, terminated, truncated = self.task.step(np.asarray(action)[None])
        info = self.task.episode_info(0)
        return obs[0].copy(), float(reward[0]), bool(terminated[0]), bool(truncated[0]), info


def _with_soak_ranges(robot: Robot, config: ReachConfig) -> ReachConfig:
    """``config`` with the soak's ranges of ``robot`` where it gives no sensors, dynamics or
    fault ranges of its own."""
    if (
        config.sensors is not None
        and config.dynamics is not None
        and config.fault_ranges is not None
    ):
        return config
    soak = session_ranges(robot)
    return replace(
        config,
        sensors=soak.sensors if config.sensors is None else config.sensors,
        dynamics=soak.dynamics if config.dynamics is None else config.dynamics,
        fault_ranges=soak.faults if config.fault_ranges is None else config.fault_ranges,
    )
