"""The seed's reach task (sections 6 and 8) on the sim plant, for training.

A policy trained here sees exactly what the runtime will show it: observations are built by the
policy's :class:`~deploy.spec.PolicySpec` from the state the runtime's Kalman filter
(:class:`~deploy.estimation.JointStateEstimator`) estimates from noisy, quantized encoder
readings of :class:`~deploy.backends.sim.SimBackend`, and its actions pass through the runtime's
Ruckig :class:`~deploy.smoothing.CommandSmoother` before they reach the drives. Only the safety
guard is left out: the policy must learn the limits from the reward (seed section 6), the guard is
the last line behind it.

:class:`ReachTask` is the batched core (arrays shaped (envs, ...)); :class:`ArmReachEnv` is the
Gymnasium env of one robot, :class:`ReachVecEnv` the Stable-Baselines3 ``VecEnv`` of many robots
stepped in lockstep by one ``SimBackend``.

Episode: the robot starts at rest at a random pose inside its soft limits, with dynamics drawn by
:func:`eval.randomization.sample_dynamics` and an encoder noise sigma drawn per episode (seed
section 5). A goal is drawn from the robot's task region; when the end effector comes within
``task.success_radius`` of it, or ``goal_timeout`` s pass, a new goal is drawn. The episode ends
at a hard joint limit (terminated) or after ``episode_seconds`` (truncated).

Reward per control tick (:class:`RewardConfig`, seed section 6 coefficients by default)::

    + success        at each goal reached
    + soft_limit     per joint beyond the soft limit (90 % of the range), or    (negative)
                     driven toward it faster than it can brake (the smoother cut the target:
                     in velocity mode the brake keeps the joint itself out of the band)
    + workspace      end effector outside the guard's workspace box            (negative; ours:
                     the runtime's guard would reject the command and hold)
    + hard_limit     at a hard limit, and the episode terminates                (negative)
    - energy   * sum |tau * dq|                                                  (W)
    - jerk     * |dq - dq_prev| / dt     (the seed's "jerk": rate of change of velocity)
    + survival
    + shaping  * (d_prev - gamma_s * d)  potential-based shaping F = gamma_s Phi(s') - Phi(s) with
                                         Phi = -shaping * d, d the goal distance (m). It leaves the
                                         optimal policy unchanged when gamma_s is the learner's
                                         discount (Ng, Harada and Russell, ICML 1999). The shipped
                                         recipe uses gamma_s = 1, the plain distance difference,
                                         which adds -(1 - gamma) * shaping * d per tick: a pull
                                         toward the goal that learned faster in our comparison
                                         (success 0.46 against 0.20 after 0.75 M PPO steps), at
                                         the price of making detours (refolding the arm around a
                                         joint limit) look worse than they are.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np

from deploy.backends.sim import SimBackend
from deploy.cli import sample_goal
from deploy.estimation import JointStateEstimator
from deploy.smoothing import CommandSmoother
from deploy.spec import PolicySpec
from deploy.state import Kinematics, RobotState
from eval.randomization import Dynamics, DynamicsRanges, randomized_model, sample_dynamics
from robots import Robot


@dataclass(frozen=True)
class RewardConfig:
    """Reward coefficients; defaults are the seed's section 6 stack plus goal-distance shaping.

    Attributes:
        success: Reward per goal reached (seed: +1).
        soft_limit: Per joint and tick beyond the soft limit, or whose target the smoother
            cut to brake before it (seed: -0.1 in the soft band).
        hard_limit: At a hard limit; the episode terminates (seed: -1).
        workspace: Per tick with the end effector outside ``safety.workspace_min/max`` (ours, the
            soft-limit coefficient: there the runtime's guard rejects commands and holds).
        energy: Coefficient of the mechanical power sum |tau dq|, per W (seed: 1e-4).
        jerk: Coefficient of |dq - dq_prev| / dt, per rad/s^2 (seed: 1e-5).
        survival: Per tick (seed: +0.001).
        shaping: Per metre the end effector comes closer to the goal (ours; 0 disables it).
        shaping_gamma: The discount of the potential-based shaping: 1.0 (default, the shipped
            recipe) gives the plain distance difference; the learner's ``gamma`` gives the
            policy-invariant form.
    """

    success: float = 1.0
    soft_limit: float = -0.1
    hard_limit: float = -1.0
    workspace: float = -0.1
    energy: float = 1e-4
    jerk: float = 1e-5
    survival: float = 0.001
    shaping: float = 5.0
    shaping_gamma: float = 1.0


@dataclass(frozen=True)
class ReachConfig:
    """Task settings.

    Attributes:
        mode: Control mode ('velocity' as seed section 8; 'position' as the variant).
        episode_seconds: Episode length, s (truncation).
        goal_timeout: A goal not reached within this time is replaced, s (the runtime's success
            window is 3 s).
        noise_range: Encoder noise sigma drawn per episode, rad. Default: seed section 5's
            0.002-0.010 on angle / pi.
        dynamics: Ranges of the dynamics randomization; ``DynamicsRanges.none()`` for the nominal
            robot.
        start_fraction: Start poses are drawn uniformly within this fraction of the soft limits.
        reward: The reward coefficients.
    """

    mode: str = "velocity"
    episode_seconds: float = 10.0
    goal_timeout: float = 3.0
    noise_range: tuple[float, float] = (0.002 * np.pi, 0.010 * np.pi)
    dynamics: DynamicsRanges = field(default_factory=DynamicsRanges)
    start_fraction: float = 0.9
    reward: RewardConfig = field(default_factory=RewardConfig)


class ReachTask:
    """``envs`` reach tasks stepped in lockstep (the batched core of both env classes).

    Args:
        robot: The robot.
        envs: Number of robots.
        config: Task settings.
        spec: The policy contract; default ``PolicySpec.for_robot(robot, mode=config.mode)``.
        seed: Seed of every random stream (poses, goals, dynamics, noise, sensors).

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
        self.config = config = config or ReachConfig()
        self.spec = spec or PolicySpec.for_robot(robot, mode=config.mode)
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
        self.estimator = JointStateEstimator(robot, envs)
        self.kinematics = Kinematics(robot)
        self.smoother = CommandSmoother(robot, envs, config.mode)
        # the estimator's control input, as in the runtime (deploy.runtime.Runtime)
        self._input = None if config.mode == "torque" else self.smoother.mean_acceleration
        self.state = RobotState.zeros(envs, self.n, robot.config.sensors.ambient_temperature)
        self.randomize = config.dynamics != DynamicsRanges.none()
        self.dynamics = [Dynamics.nominal(self.n)] * envs
        self.goal = np.zeros((envs, 3))
        self._ws_min = np.asarray(robot.config.safety.workspace_min)
        self._ws_max = np.asarray(robot.config.safety.workspace_max)
        self.obs = np.zeros((envs, self.spec.obs_dim), dtype=np.float32)
        self._target = np.zeros((envs, self.n))
        self._cmd = np.zeros((envs, self.n))
        self._clamps = np.zeros((envs, self.n), dtype=np.int64)
        self._distance = np.zeros(envs)
        self._prev_dq = np.zeros((envs, self.n))
        self.t_episode = np.zeros(envs)
        self.t_goal = np.zeros(envs)
        # per-episode statistics
        self.goals = np.zeros(envs, dtype=np.int64)
        self.reached = np.zeros(envs, dtype=np.int64)
        self.missed = np.zeros(envs, dtype=np.int64)
        self.limit_violations = np.zeros(envs, dtype=np.int64)
        self.episode_return = np.zeros(envs)
        self.reset(np.ones(envs, dtype=bool))

    # ------------------------------------------------------------------ resets
    def reset(self, which: np.ndarray) -> None:
        """Start new episodes for the envs in the boolean mask ``which``."""
        robot, cfg = self.robot, self.config
        idx = np.nonzero(which)[0]
        if self.randomize:
            for e in idx:
                self.dynamics[e] = sample_dynamics(robot, self.rng, cfg.dynamics)
                self.backend.set_model(e, randomized_model(robot, cfg.mode, self.dynamics[e]))
        lo = robot.home + cfg.start_fraction * (robot.soft_lower - robot.home)
        hi = robot.home + cfg.start_fraction * (robot.soft_upper - robot.home)
        q0 = np.array(self.backend.true_position())
        q0[idx] = self.rng.uniform(lo, hi, (len(idx), self.n))
        self.backend.reset(q0, envs=which)
        self.backend.noise_sigma[idx] = self.rng.uniform(*cfg.noise_range, len(idx))
        frame = self.backend.read()
        self.estimator.reset(frame.position, frame.position_stamp, envs=which)
        self.state.q[idx] = frame.position[idx]
        self.state.dq[idx] = 0.0
        self.state.last_action[idx] = 0.0
        self.state.winding_temperature[idx] = frame.winding_temperature[idx]
        self.smoother.sync(self.state.q, self.state.dq, envs=which)
        self._prev_dq[idx] = 0.0
        self.t_episode[idx] = 0.0
        self.goals[idx] = 0
        self.reached[idx] = 0
        self.missed[idx] = 0
        self.limit_violations[idx] = 0
        self.episode_return[idx] = 0.0
        for e in idx:
            self._new_goal(e)
        self.kinematics.update(self.state)
        self.spec.observation(self.state, self.goal, out=self.obs)
        self._distance[idx] = self._true_distance()[idx]

    def spaces(self) -> tuple[gym.spaces.Box, gym.spaces.Box]:
        """Observation space ``Box(-clip, clip, (obs_dim,))`` and action space
        ``Box(-1, 1, (act_dim,))`` of one robot, float32."""
        clip = max(b.clip for b in self.spec.observation_blocks)
        obs = gym.spaces.Box(-clip, clip, (self.spec.obs_dim,), np.float32)
        return obs, gym.spaces.Box(-1.0, 1.0, (self.spec.act_dim,), np.float32)

    def _new_goal(self, e: int) -> None:
        self.goal[e] = sample_goal(self.robot, self.rng)
        self.t_goal[e] = self.t_episode[e]
        self.goals[e] += 1

    def _true_distance(self) -> np.ndarray:
        return np.linalg.norm(self.backend.end_effector_position() - self.goal, axis=1)

    # ------------------------------------------------------------------ the step
    def step(self, action: np.ndarray):
        """Advance every env one control period under ``action`` ((envs, n) in [-1, 1]).

        Returns:
            ``(obs, reward, terminated, truncated)``: float32 (envs, obs_dim) observation after
            the step, (envs,) reward, (envs,) bool each. Finished envs are *not* reset here.
        """
        robot, rew = self.robot, self.config.reward
        action = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        target = self.spec.action_to_target(action, self.state, out=self._target)
        np.copyto(self._clamps, self.smoother.stopping_distance_clamps_per_joint)
        cmd = self.smoother.step(target, out=self._cmd)
        # joints whose target the smoother cut to brake before a soft limit: the policy drove
        # into the soft band, which the brake now keeps the joint out of
        pushed = self.smoother.stopping_distance_clamps_per_joint > self._clamps
        self.backend.write(cmd)
        self.backend.advance()
        frame = self.backend.read()
        state = self.estimator.update(frame, self.state, self._input)
        state.last_action[:] = action
        self.kinematics.update(state)
        self.spec.observation(state, self.goal, out=self.obs)
        self.t_episode += self.dt

        q = self.backend.true_position()
        dq = self.backend.true_velocity()
        tau = self.backend.joint_torque()
        hard = ((q < robot.position_lower) | (q > robot.position_upper)).any(axis=1)
        soft = ((q < robot.soft_lower) | (q > robot.soft_upper) | pushed).sum(axis=1)
        ee = self.backend.end_effector_position()
        outside = ((ee < self._ws_min) | (ee > self._ws_max)).any(axis=1)
        distance = np.linalg.norm(ee - self.goal, axis=1)
        success = distance <= robot.config.task.success_radius

        reward = np.full(self.envs, rew.survival)
        reward += rew.shaping * (self._distance - rew.shaping_gamma * distance)
        reward += rew.success * success
        reward += rew.soft_limit * soft
        reward += rew.hard_limit * hard
        reward += rew.workspace * outside
        reward -= rew.energy * np.abs(tau * dq).sum(axis=1)
        reward -= rew.jerk * np.linalg.norm(dq - self._prev_dq, axis=1) / self.dt
        self._prev_dq[:] = dq

        self.reached += success
        self.limit_violations += hard
        self.episode_return += reward
        expired = ((self.t_episode - self.t_goal) >= self.config.goal_timeout) & ~success
        self.missed += expired
        new = success | expired
        for e in np.nonzero(new)[0]:
            self._new_goal(e)
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
        decided = int(self.reached[e] + self.missed[e])
        return {
            "is_success": float(self.reached[e]) / decided if decided else 0.0,
            "goals_reached": int(self.reached[e]),
            "goals_missed": int(self.missed[e]),
            "joint_limit_violations": int(self.limit_violations[e]),
        }


class ArmReachEnv(gym.Env):
    """Gymnasium env of one robot's reach task (see the module docstring).

    Observation: ``Box(-clip, clip, (spec.obs_dim,), float32)``; action: ``Box(-1, 1, (n,),
    float32)``. ``info`` holds ``is_success`` (fraction of goals reached), ``goals_reached``,
    ``goals_missed`` and ``joint_limit_violations`` of the episode.
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
