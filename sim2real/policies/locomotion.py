"""The legged velocity-tracking task on the sim plant, run through the deployed runtime.

Train what you deploy, to the letter: :class:`LocomotionTask` steps a
:class:`~sim2real.deploy.runtime.Runtime` (the tick the robot runs: joint and base estimators, the fall
check, the supervision and its safe stops, the guard, the Ruckig smoother, the damping of a
stopped legged robot) over a batched :class:`~sim2real.deploy.backends.sim.plant.SimBackend`. The learner
sits in the runtime's policy slot (:class:`LearnerPolicy`): the runtime hands it the observation it
built and receives the action, so the learner sees exactly what ``deploy-run`` feeds the exported
policy, one call per tick, in the tick's own order (read, estimate, supervise, observe, act,
guard, smooth, write, physics).

The learner's output is a *residual* on the trot generator of :mod:`sim2real.deploy.policy.gait_prior` (PMTG,
Iscen et al. 2018): the action the runtime receives is ``prior(obs) + residual``, the sum an
exported :class:`~sim2real.deploy.policy.mlp_checkpoint.MLPActor` with ``gait`` computes.

Episode: ``episode_seconds`` of walking from the MJCF's standing pose, after the runtime's RAMP_IN
to home. Each episode draws a soak session's randomization (:func:`sim2real.eval.world.session_draw.
sample_session` of the legged ranges: dynamics, encoder noise and latency, IMU noise and bias,
floor friction, and a fault schedule at the training interval, :mod:`sim2real.policies.episode_faults`,
which the runtime's injector applies), a velocity command every ``command_period`` s
(:class:`sim2real.deploy.tasks.commands.CommandRanges`, the soak's ranges) and pushes on the base (a
scheduled push adds to them). It ends (terminated) when the runtime leaves RUNNING for a safe stop
(a fall, a hard limit, a stale sensor...) and is truncated at its length.

The reward per control tick is :class:`LocomotionReward`'s (its docstring gives the terms). A spec
with a ``height_scan`` block reads the plant's ray casts with ``SCAN_NOISE``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from sim2real.deploy.backends.sim.height_scan import HeightScanNoise, attach_height_scanner
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.state import BaseState
from sim2real.deploy.rig.rig import Rig
from sim2real.deploy.runtime import Mode
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.deploy.tasks.commands import CommandRanges
from sim2real.deploy.tasks.task import follows_velocity_commands
from sim2real.eval.world.dynamics import randomized_model
from sim2real.eval.world.floor import apply_floor_friction
from sim2real.eval.world.sensors import SensorDraw, apply_imu, apply_sensors
from sim2real.eval.world.session_draw import sample_faults, sample_session
from sim2real.eval.world.session_ranges import SessionRanges, session_ranges
from sim2real.policies.episode_faults import EpisodeFaults, training_fault_ranges
from sim2real.robots import Robot

#: m, a height scan's uniform noise in training (legged_gym's ``noise_scales.height_measurements``
#: 0.1 at ``noise_level`` 1.0)
SCAN_NOISE = 0.1


@dataclass(frozen=True)
class LocomotionReward:
    """Reward coefficients per second (multiplied by the control period each tick), except
    ``intervention`` (per tick) and ``stop`` (once). Defaults: legged_gym's ``rewards.scales``
    for the terms it has (tracking 1.0 and 0.5, lin_vel_z -2.0, ang_vel_xy -0.05, action_rate
    -0.01, orientation -0.2 as unitree_rl_gym's go2 config sets it); ours for heat,
    intervention, stop and ``tracking_sigma``: 0.1 (m/s)^2 instead of legged_gym's 0.25, whose
    commands reach 1 m/s; over our 0-0.5 m/s its reward barely told 0.2 from 0.5 m/s, and with
    an intervention penalty of 0.02 per tick the policy learned to walk at 0.2 m/s.

    Reward per control tick (:class:`LocomotionReward`; legged_gym's terms and scales, Rudin et al.,
    CoRL 2021, ``legged_gym/envs/base/legged_robot_config.py``, each times the control period, plus
    ours)::

        + tracking_linear  * exp(-|v_cmd,xy - v_xy|^2 / sigma)   base frame, true velocity
        + tracking_angular * exp(-(w_cmd,z - w_z)^2 / sigma)
        + vertical_velocity * v_z^2 + angular_velocity_xy * |w_xy|^2            (negative)
        + orientation * |g_xy|^2      the projected gravity's tilt               (negative)
        + action_rate * |a - a_prev|^2                                           (negative)
        + heat * sum (tau / tau_cont)^2   Joule heating relative to each motor's rated continuous
                                          torque (ours: what overheats a Go2's thighs in a soak)
        + intervention     per tick on which the guard or the smoother changed the command (ours)
        + stop             once, when the runtime makes a safe stop (the episode ends)
    """

    tracking_linear: float = 1.0
    tracking_angular: float = 0.5
    tracking_sigma: float = 0.1
    vertical_velocity: float = -2.0
    angular_velocity_xy: float = -0.05
    orientation: float = -0.2
    action_rate: float = -0.01
    heat: float = -0.01
    intervention: float = -0.01
    stop: float = -2.0


@dataclass(frozen=True)
class LocomotionConfig:
    """Task settings.

    Attributes:
        episode_seconds: Episode length, s (legged_gym: 20 s).
        command_period: A new velocity command every this many s (the soak's default
            ``--goal-period``, 4 s).
        commands: The command ranges (the soak's :class:`~sim2real.deploy.tasks.commands.CommandRanges`).
        push_interval: Mean time between pushes on the base, s (exponential).
        push_force: Horizontal push force range, N (the soak pushes 5-25 N; ours up to 40).
        push_duration: Push duration range, s (the soak's).
        randomize: Draw each episode's dynamics, sensors, IMU and floor like a soak session.
        faults: Each episode meets a fault schedule drawn, like a soak session's, from the
            ranges' ``faults`` at ``fault_interval`` (False: none).
        fault_interval: Mean time between faults in training, s (replaces the soak's
            ``mean_interval``; our choice: most 20-s episodes meet one fault).
        ranges: The ranges they are drawn from; None (default): the robot's soak ranges
            (:func:`sim2real.eval.world.session_ranges.session_ranges`); a ranges file's:
            :func:`sim2real.eval.world.ranges_file.load_ranges`.
        reward: The coefficients.
    """

    episode_seconds: float = 20.0
    command_period: float = 4.0
    commands: CommandRanges = CommandRanges()
    push_interval: float = 8.0
    push_force: tuple[float, float] = (5.0, 40.0)
    push_duration: tuple[float, float] = (0.05, 0.5)
    randomize: bool = True
    faults: bool = True
    fault_interval: float = 10.0
    ranges: SessionRanges | None = None
    reward: LocomotionReward = field(default_factory=LocomotionReward)


class LearnerPolicy:
    """The runtime's policy slot during training: ``(envs, obs_dim) float32 -> (envs, 12)``.

    ``act`` (set by the trainer) maps the observation the runtime built to the action it must
    return; the policy keeps the observation so that the trainer can store it with the action.
    """

    def __init__(self, spec: PolicySpec, envs: int):
        self.spec = spec
        self.act = None
        self.obs = np.zeros((envs, spec.obs_dim), dtype=np.float32)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        np.copyto(self.obs, obs)
        return self.act(self.obs)


def learner_rig(robot, policy: LearnerPolicy, backend, envs: int, task: dict, runtime=None) -> Rig:
    """The run a trainer's episodes step (:class:`~sim2real.deploy.rig.rig.Rig`): ``policy`` in
    the policy's slot, the task with the options ``task`` (``period`` s between its goals or
    commands on the episodes' ``clock`` (envs,) s, drawn from ``rng``), no truth monitors (the
    reward judges), the task reset by the episodes, not once built. ``runtime``: keyword
    arguments of the runtime."""
    kw = {"truth": False, "reset_task": False}
    return Rig(robot, policy, backend, envs=envs, task=task, runtime=runtime, **kw)


class LocomotionTask:
    """``envs`` legged robots walking through one :class:`~sim2real.deploy.runtime.Runtime`.

    Args:
        robot: A floating-base robot.
        spec: The policy contract (the learner's observation and action).
        envs: Number of robots.
        config: Task settings.
        seed: Seed of the episodes' draws (session seeds, commands, pushes).

    Raises:
        ValueError: a fixed-base robot.
    """

    def __init__(
        self,
        robot: Robot,
        spec: PolicySpec,
        envs: int,
        config: LocomotionConfig | None = None,
        seed: int = 0,
    ):
        if not follows_velocity_commands(robot):
            raise ValueError(f"LocomotionTask: robot {robot.name} has no floating base")
        self.robot, self.spec, self.envs = robot, spec, envs
        self.config = config = config or LocomotionConfig()
        self.dt = robot.control_period
        self.rng = np.random.default_rng(seed)
        ranges = session_ranges(robot) if config.ranges is None else config.ranges
        #: what the episodes draw from: the soak's ranges, faults at the training interval
        self.ranges = dataclasses.replace(
            ranges, faults=training_fault_ranges(ranges.faults, config.fault_interval)
        )
        self.backend = SimBackend(robot, mode=spec.action.mode, envs=envs, seed=seed + 1)
        # a perceptive spec: the plant's ray casts feed its height_scan (legged_gym's noise)
        attach_height_scanner(self.backend, spec, HeightScanNoise(noise=SCAN_NOISE), seed + 2)
        self.policy = LearnerPolicy(spec, envs)
        self.push_force = np.zeros((envs, 3))  # N, each env's push of _disturb
        #: the episodes' fault schedules (None: faults off)
        self.faults = EpisodeFaults(self.backend, self.push_force) if config.faults else None
        self.t_episode = np.zeros(envs)
        #: the run (sim2real.deploy.rig): the runtime, the intervention monitor, the velocity commands
        #: (sim2real.deploy.tasks.episodes.EpisodeCommands) and their tracking; episodes judge the truth
        #: their own way (the reward), so no truth monitors
        self.rig = learner_rig(
            robot,
            self.policy,
            self.backend,
            envs,
            {
                "period": config.command_period,
                "rng": self.rng,
                "clock": self.t_episode,
                "ranges": config.commands,
            },
            runtime={"injector": self.faults},
        )
        self.runtime, self.task = self.rig.runtime, self.rig.task
        self.monitor = self.rig.interventions
        self._continuous = np.array([m.continuous_torque for m in robot.motors])
        self._previous_action = np.zeros((envs, robot.n_joints))
        self._before = np.zeros(envs, dtype=np.int64)
        self._true_base = BaseState.zeros(envs)  # the plant's base in the estimate's terms
        self._one = np.eye(envs, dtype=bool)  # env e's mask, row e
        self.push_until = np.zeros(envs)
        self.episode_return = np.zeros(envs)
        self.episode_ticks = np.zeros(envs, dtype=np.int64)
        self.distance = np.zeros(envs)
        self.policy.act = lambda obs: np.zeros((envs, robot.n_joints), dtype=np.float32)
        self.runtime.start()
        self.reset(np.ones(envs, dtype=bool))

    # ------------------------------------------------------------------ episodes
    def reset(self, which: np.ndarray) -> None:
        """New episodes for the envs of the boolean mask ``which``: a new randomization, the robot
        standing at the start, the runtime restarted there (RAMP_IN), a new command."""
        b, rt, cfg = self.backend, self.runtime, self.config
        idx = np.nonzero(which)[0]
        self.push_force[idx] = 0.0
        for e in idx:
            if self.faults is not None:  # a fault of the last episode still in force ends
                self.faults.stop(e)
            if cfg.randomize:
                draw = sample_session(
                    self.robot,
                    int(self.rng.integers(2**31)),
                    cfg.episode_seconds,
                    self.ranges,
                    faults=cfg.faults,
                )
                model = randomized_model(self.robot, self.spec.action.mode, draw.dynamics)
                apply_floor_friction(model, draw.floor_friction)
                b.set_model(e, model)
                apply_sensors(b, e, draw.sensors)
                apply_imu(b, e, draw.imu)
                if self.faults is not None:  # its times from the episode's start
                    self.faults.start(e, draw.faults, rt.time)
            elif self.faults is not None:  # the nominal world: sized against the plant's sensors
                sensors = SensorDraw(
                    float(b.noise_sigma[e]),
                    int(b.latency_ticks[e]),
                    float(b.dropout_probability[e]),
                )
                seed = int(self.rng.integers(2**31))
                schedule = sample_faults(
                    self.robot, seed, cfg.episode_seconds, sensors, self.ranges.faults, b.models[e]
                )
                self.faults.start(e, schedule, rt.time)
            b.set_external_force(e, np.zeros(3))
            self.task.reset(rt, self._one[e])  # a new command, drawn after the episode's world
        b.reset(envs=which)
        rt.restart(which, self.robot.home, b.frame.time)
        self.t_episode[idx] = 0.0
        self.push_until[idx] = 0.0
        self.episode_return[idx] = 0.0
        self.episode_ticks[idx] = 0
        self.distance[idx] = 0.0
        self._previous_action[idx] = 0.0

    def _disturb(self) -> None:
        """New commands where their period ended; pushes start and end."""
        cfg, b = self.config, self.backend
        self.task(self.runtime)
        ended = (self.push_until > 0) & (self.t_episode >= self.push_until)
        for e in np.nonzero(ended)[0]:
            self.push_force[e] = 0.0
            b.set_external_force(e, self.push_force[e])
            self.push_until[e] = 0.0
        start = (self.push_until == 0) & (self.rng.random(self.envs) < self.dt / cfg.push_interval)
        for e in np.nonzero(start)[0]:
            angle = self.rng.uniform(0, 2 * np.pi)
            force = self.rng.uniform(*cfg.push_force)
            self.push_force[e] = force * np.array([np.cos(angle), np.sin(angle), 0.0])
            b.set_external_force(e, self.push_force[e])
            self.push_until[e] = self.t_episode[e] + self.rng.uniform(*cfg.push_duration)

    # ------------------------------------------------------------------ the step
    def tick(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One runtime tick for every env (the learner acts inside it, through
        :class:`LearnerPolicy`), then the reward from the plant's true state.

        Returns:
            ``(reward, terminated, truncated)``, (envs,) each. Finished envs are not reset here.
        """
        rew, rt = self.config.reward, self.runtime
        self._disturb()
        running_before = rt.mode == Mode.RUNNING
        np.copyto(self._before, self.monitor.any)
        rt.tick()
        self.monitor.update()
        intervened = (self.monitor.any > self._before) & running_before

        base = self._true_base.set_truth(self.backend.true_base_state())
        v, omega, gravity = base.linear_velocity, base.angular_velocity, base.projected_gravity
        command = rt.velocity_command
        tau = self.backend.joint_torque()
        action = rt.action
        error = np.square(command[:, :2] - v[:, :2]).sum(axis=1)
        r = rew.tracking_linear * np.exp(-error / rew.tracking_sigma)
        r += rew.tracking_angular * np.exp(
            -np.square(command[:, 2] - omega[:, 2]) / rew.tracking_sigma
        )
        r += rew.vertical_velocity * np.square(v[:, 2])
        r += rew.angular_velocity_xy * np.square(omega[:, :2]).sum(axis=1)
        r += rew.orientation * np.square(gravity[:, :2]).sum(axis=1)
        r += rew.action_rate * np.square(action - self._previous_action).sum(axis=1)
        r += rew.heat * np.square(tau / self._continuous).sum(axis=1)
        r *= self.dt
        r *= running_before  # RAMP_IN: the runtime, not the learner, drives the joints
        r += rew.intervention * intervened
        self._previous_action[:] = action
        stopped = (rt.mode == Mode.SAFE_STOP) | (rt.mode == Mode.FAULTED)
        r += rew.stop * stopped

        self.t_episode += self.dt
        self.episode_ticks += 1
        self.episode_return += r
        self.task.track(running_before, error)
        self.distance += running_before * v[:, 0] * self.dt
        truncated = (self.t_episode >= self.config.episode_seconds - 1e-9) & ~stopped
        return r, stopped, truncated

    def episode_info(self, e: int) -> dict:
        """Env ``e``'s episode so far, for the logs: SB3's ``episode`` (return, length, time),
        ``tracking`` (fraction of RUNNING time within 0.2 m/s of the command) and ``distance``
        (m, forward, base frame)."""
        return {
            "episode": {
                "r": float(self.episode_return[e]),
                "l": int(self.episode_ticks[e]),
                "t": float(self.t_episode[e]),
            },
            "tracking": self.task.success(e),
            "distance": float(self.distance[e]),
        }
