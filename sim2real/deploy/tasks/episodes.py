"""Training's tasks (:class:`sim2real.deploy.tasks.task.Task`), episodic: what a learner is asked during an
episode, on the episode's clock and from one generator it shares with the episode's other draws
(the draws keep their order, so a seed gives the same run).

:class:`EpisodeGoals` (an arm, :class:`sim2real.policies.envs.ReachTask`): a goal from the robot's task
region at the episode's start and whenever the last one was reached (the end effector within the
success radius) or ``timeout`` s passed. :class:`EpisodeCommands` (a legged robot,
:class:`sim2real.policies.locomotion.LocomotionTask`): a velocity command at the episode's start and every
``period`` s of the episode.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.stateful import load_parts, parts_state_dict, put, take
from sim2real.deploy.tasks.commands import CommandRanges
from sim2real.deploy.tasks.goals import sample_goal
from sim2real.deploy.tasks.locomotion import TRACKING_TOLERANCE


class _Arrays:
    """A task's arrays as one stateful part (:mod:`sim2real.deploy.core.stateful`): ``fields()`` names
    them."""

    def __init__(self, fields):
        self.fields = fields

    def state_dict(self, env: int | None = None) -> dict:
        return take(self.fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        put(self.fields(), state, env)


class EpisodeGoals:
    """Chained goals of ``envs`` training episodes (module docstring).

    Args:
        robot: The robot (its task region).
        envs: Batch size.
        timeout: s of episode time after which an unreached goal is replaced.
        rng: The episodes' numpy generator (goals drawn in env order).
        clock: (envs,) s, the episodes' clock, the trainer's array (read only).
        success_radius: m, a goal is reached within this distance.

    Attributes:
        goal: (envs, 3) m, base frame: the goals (the trainer's observation reads it).
        t_goal: (envs,) s of episode time when each goal was drawn.
        issued, reached, missed: (envs,) int64, goals drawn, reached and timed out this episode.
        hit: (envs,) bool, the goals reached at the last :meth:`judge`. new: (envs,) bool, the
            envs given a new goal at the last call.
    """

    name = "goals"

    def __init__(self, robot, envs: int, timeout: float, rng, clock, success_radius: float):
        self.robot, self.timeout, self.rng, self.clock = robot, timeout, rng, clock
        self.success_radius = success_radius
        self.goal = np.zeros((envs, 3))
        self.t_goal = np.zeros(envs)
        self.issued = np.zeros(envs, dtype=np.int64)
        self.reached = np.zeros(envs, dtype=np.int64)
        self.missed = np.zeros(envs, dtype=np.int64)
        self.hit = np.zeros(envs, dtype=bool)
        self.new = np.zeros(envs, dtype=bool)

    def reset(self, runtime, envs: np.ndarray) -> None:
        """New episodes for the envs of the bool mask ``envs``: counts zeroed, goals drawn (in
        env order)."""
        idx = np.nonzero(envs)[0]
        self.issued[idx] = 0
        self.reached[idx] = 0
        self.missed[idx] = 0
        for e in idx:
            self._draw(e)

    def _draw(self, e: int) -> None:
        self.goal[e] = sample_goal(self.robot, self.rng)
        self.t_goal[e] = self.clock[e]
        self.issued[e] += 1

    def judge(self, ee: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(distance, hit)`` of the end effectors ``ee`` (envs, 3) m to the goals: (envs,) m and
        (envs,) bool within the success radius (kept in :attr:`hit`)."""
        distance = np.linalg.norm(ee - self.goal, axis=1)
        self.hit = distance <= self.success_radius
        return distance, self.hit

    def __call__(self, runtime) -> None:
        """After a step: count the goals reached (:meth:`judge`) and timed out, and draw new
        goals for them (:attr:`new`)."""
        success = self.hit
        self.reached += success
        expired = ((self.clock - self.t_goal) >= self.timeout) & ~success
        self.missed += expired
        self.new = success | expired
        for e in np.nonzero(self.new)[0]:
            self._draw(e)

    def success(self, env: int | None = None) -> float | None:
        """Goals reached / goals decided (reached or timed out) this episode; 0 before any."""
        reached = int(self.reached.sum() if env is None else self.reached[env])
        decided = reached + int(self.missed.sum() if env is None else self.missed[env])
        return float(reached) / decided if decided else 0.0

    def parts(self) -> dict:
        """``goals``: ``goal`` (envs, 3) m, ``t_goal`` s, ``issued``, ``reached``, ``missed``
        (int64); the generator is the trainer's."""
        names = ("goal", "t_goal", "issued", "reached", "missed")
        return {"goals": _Arrays(lambda: {k: getattr(self, k) for k in names})}

    def state_dict(self, env: int | None = None) -> dict:
        return parts_state_dict(self.parts(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        load_parts(self.parts(), state, env)


class EpisodeCommands:
    """Velocity commands of ``envs`` training episodes (module docstring), written into
    ``runtime.velocity_command``.

    Args:
        envs: Batch size.
        period: s of episode time between commands.
        ranges: What the commands are drawn from (:class:`CommandRanges`).
        rng: The episodes' numpy generator.
        clock: (envs,) s, the episodes' clock, the trainer's array (read only).

    Attributes:
        t_command: (envs,) s of episode time when each command was drawn.
        running, tracked: (envs,) RUNNING ticks this episode, and those within
            ``TRACKING_TOLERANCE`` of the command (:meth:`track`).
    """

    name = "locomotion"

    def __init__(self, envs: int, period: float, ranges: CommandRanges, rng, clock):
        self.period, self.ranges, self.rng, self.clock = period, ranges, rng, clock
        self.t_command = np.zeros(envs)
        self.running = np.zeros(envs)
        self.tracked = np.zeros(envs)

    def reset(self, runtime, envs: np.ndarray) -> None:
        """New episodes for the envs of the bool mask ``envs``: a command drawn for each (in env
        order), their clocks and tracking zeroed."""
        idx = np.nonzero(envs)[0]
        for e in idx:
            runtime.velocity_command[e] = self.ranges.sample(self.rng)
        self.t_command[idx] = 0.0
        self.running[idx] = 0.0
        self.tracked[idx] = 0.0

    def __call__(self, runtime) -> None:
        """Before a tick: new commands where their period ended."""
        for e in np.nonzero(self.clock - self.t_command >= self.period)[0]:
            runtime.velocity_command[e] = self.ranges.sample(self.rng)
            self.t_command[e] = self.clock[e]

    def track(self, running: np.ndarray, error: np.ndarray) -> None:
        """Account a tick: ``running`` (envs,) bool RUNNING, ``error`` (envs,) (m/s)^2, the
        squared planar velocity error."""
        self.running += running
        self.tracked += running & (np.sqrt(error) <= TRACKING_TOLERANCE)

    def success(self, env: int | None = None) -> float | None:
        """Tracking success this episode: RUNNING ticks tracked / RUNNING ticks (at least 1)."""
        tracked = self.tracked.sum() if env is None else self.tracked[env]
        running = self.running.sum() if env is None else self.running[env]
        return float(tracked / max(running, 1.0))

    def parts(self) -> dict:
        """``commands``: ``t_command`` s, ``running``, ``tracked`` ticks; the generator is the
        trainer's."""
        names = ("t_command", "running", "tracked")
        return {"commands": _Arrays(lambda: {k: getattr(self, k) for k in names})}

    def state_dict(self, env: int | None = None) -> dict:
        return parts_state_dict(self.parts(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        load_parts(self.parts(), state, env)
