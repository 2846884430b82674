"""What a robot is asked to do, as one protocol (:class:`Task`), and the one place that chooses it
for a robot (:func:`task_for`): reach goals (a fixed-base arm, :class:`sim2real.deploy.tasks.goals.GoalTask`),
follow velocity commands (a floating-base robot,
:class:`sim2real.deploy.tasks.velocity.VelocityTask`) or track a reference motion
(:class:`sim2real.deploy.tasks.motion.tracking.TrackingTask`). ``deploy-run``, the soak and training
build their task here; a new kind of task implements :class:`Task` and registers its builder in
:data:`TASKS` (:func:`register_task`), chosen by name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sim2real.deploy.kinds import robot_kind


class Task(Protocol):
    """A task of ``envs`` robots behind one runtime.

    Attributes:
        name: The task's section of a report: ``"goals"`` or ``"locomotion"``.
    """

    name: str

    def reset(self, runtime, envs: np.ndarray) -> None:
        """Episode start for the envs of the boolean mask ``envs``: what is drawn or written
        then (a fixed velocity command); a goal or scheduled command is issued by the ticks."""

    def __call__(self, runtime) -> None:
        """After every tick of ``runtime``: write goals into ``runtime.goal`` or velocity
        commands into ``runtime.velocity_command``, and account the success."""

    def success(self, env: int | None = None) -> float | None:
        """The task's success measure (of env ``env``, or of all envs): the share of goals
        reached, or of RUNNING time tracking the command; None before there is any."""

    def report(self, runtime) -> dict:
        """``deploy-run``'s report entries: ``goals``, ``locomotion`` (one of them None) and
        ``missed_goals``."""

    def curve_start(self) -> dict[str, list]:
        """The task's cumulative curves of a soak session, at their first point."""

    def curve_point(self, curve: dict[str, list], e: int) -> None:
        """Append env ``e``'s counts now to its ``curve`` (of :meth:`curve_start`)."""

    def parts(self) -> dict:
        """The task's stateful parts by checkpoint prefix (``goals``; ``commands``, ``tracker``)."""

    def state_dict(self, env: int | None = None) -> dict:
        """The task's state, each part's fields under its prefix (:mod:`sim2real.deploy.core.stateful`)."""

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`; raises ``StateDictError`` (a field under its prefix)."""


@dataclass(frozen=True)
class TaskEntry:
    """A registered task: ``build(robot, envs, backend, **options) -> Task`` (:func:`task_for`'s
    options); ``episodes(robot, envs, period, rng, clock, ranges, success_radius) -> Task``, its
    episodic form for training (None: none); ``velocity_commands``: it follows the runtime's
    velocity command (``deploy-run --command``, the soak's command schedule and period)."""

    build: object
    episodes: object = None
    velocity_commands: bool = False

    def __call__(self, robot, envs, backend, **options) -> Task:
        """:attr:`build`'s task."""
        return self.build(robot, envs, backend, **options)


#: The tasks by name (:class:`TaskEntry`); ``goals`` and ``locomotion`` are the robot kinds' own
#: (``robot_kind(robot).task``).
TASKS: dict[str, TaskEntry] = {}


def register_task(name: str, builder, episodes=None, velocity_commands: bool = False) -> None:
    """Register ``builder`` under ``name`` (:data:`TASKS`, as a :class:`TaskEntry` with
    ``episodes`` and ``velocity_commands``).

    Raises:
        ValueError: a name already registered.
    """
    if name in TASKS:
        raise ValueError(f"task '{name}': already registered")
    if not isinstance(builder, TaskEntry):
        builder = TaskEntry(builder, episodes, velocity_commands)
    TASKS[name] = builder


def task_entry(robot, task: str | None = None) -> TaskEntry:
    """The registered task ``task``, default ``robot``'s kind's (:data:`TASKS`).

    Raises:
        ValueError: no task of that name."""
    name = task or robot_kind(robot).task
    if name not in TASKS:
        raise ValueError(f"task '{name}': expected one of {sorted(TASKS)}")
    return TASKS[name]


def follows_velocity_commands(robot) -> bool:
    """Whether ``robot``'s task follows velocity commands (a legged robot's: ``deploy-run
    --command``, the soak's command schedule, the terrain it walks on), not goals."""
    return task_entry(robot).velocity_commands


def task_for(
    robot,
    envs: int,
    backend,
    *,
    period: float,
    rng,
    success_time: float = 3.0,
    fixed: np.ndarray | None = None,
    command: str | None = None,
    window: float | None = None,
    interventions=None,
    schedule: bool = True,
    clock: np.ndarray | None = None,
    success_radius: float | None = None,
    ranges=None,
    heading_gain: float = 0.0,
    task: str | None = None,
    motion=None,
    motion_start_after: float = 0.0,
) -> Task:
    """The task of ``robot`` (:func:`sim2real.deploy.robot_kind.robot_kind`): goals for an arm, velocity
    commands for a legged robot.

    Args:
        robot: The robot.
        envs: Batch size.
        backend: The runtime's backend (a simulated plant's truth judges the task).
        period: s of RUNNING time between new goals or scheduled commands.
        rng: One numpy generator for the batch, or ``envs`` of them (one stream per env). A
            legged robot's schedule needs one per env.
        success_time: s within which a goal counts as reached (an arm).
        fixed: Optional fixed goal (3,) m, base frame (an arm).
        command: Optional fixed velocity command ``"VX,VY,WZ"`` (a legged robot; m/s, m/s,
            rad/s, :func:`sim2real.deploy.tasks.commands.parse_command`): written at
            :meth:`Task.reset`, none scheduled. An arm ignores it.
        window: Optional s: account the success per window of session time too.
        interventions: Optional :class:`sim2real.deploy.monitors.interventions.InterventionMonitor` (an
            arm: a missed goal records the interventions during its period).
        schedule: A legged robot without ``command``: draw a new command every ``period`` s
            (the soak); False: the command stays as the runtime holds it (``deploy-run``).
        clock: Training: the episodes' clock, (envs,) s; the task is episodic
            (:mod:`sim2real.deploy.tasks.episodes`): ``period`` is an arm's goal timeout or a legged
            robot's command period in episode time, ``rng`` the episodes' one generator.
        success_radius: Training, an arm: m, a goal is reached within it (default the robot's
            ``task.success_radius``).
        ranges: A legged robot: the :class:`~sim2real.deploy.tasks.commands.CommandRanges` its
            commands are drawn from, in training and in the soak's schedule (default its
            defaults).
        heading_gain: A legged robot with a fixed ``command`` whose yaw rate is zero: hold its
            heading with this gain, 1/s (:class:`sim2real.deploy.tasks.heading.HeadingHold`); 0: off.
        task: A registered task's name in place of the robot kind's (``tracking``).
        motion: ``tracking``: ``(MotionClock, waist joint indices)``. motion_start_after:
            ``tracking``: s of RUNNING before the clip starts (the policy holding its first frame).

    Raises:
        ValueError: a ``command`` that is not three finite numbers (a legged robot).
    """
    entry = task_entry(robot, task)
    if clock is not None:  # training's episodes
        if entry.episodes is None:
            raise ValueError("task_for: a clock given, but the task has no training episodes")
        return entry.episodes(robot, envs, period, rng, clock, ranges, success_radius)
    options = {
        "period": period, "rng": rng, "success_time": success_time, "fixed": fixed,
        "command": command, "window": window, "interventions": interventions,
        "schedule": schedule, "ranges": ranges, "heading_gain": heading_gain, "motion": motion,
        "motion_start_after": motion_start_after,
    }  # fmt: skip
    return entry.build(robot, envs, backend, **options)


def _locomotion(robot, envs, backend, *, period, rng, command, window, schedule, ranges,
                heading_gain, **_) -> Task:  # fmt: skip
    """Velocity commands: fixed, scheduled, or the runtime's (:func:`task_for`)."""
    from sim2real.deploy.tasks.commands import parse_command
    from sim2real.deploy.tasks.velocity import VelocityTask

    if command is not None:
        command = parse_command(command)
    if command is not None or not schedule:
        rng = None  # no schedule
    return VelocityTask(
        envs, robot.control_period, backend, period, rng, command, window, heading_gain, ranges
    )


def _episode_commands(robot, envs, period, rng, clock, ranges, success_radius) -> Task:
    """Training's velocity commands, one per episode (:func:`task_for` with ``clock``)."""
    from sim2real.deploy.tasks.commands import CommandRanges
    from sim2real.deploy.tasks.episodes import EpisodeCommands

    ranges = CommandRanges() if ranges is None else ranges
    return EpisodeCommands(envs, period, ranges, rng, clock)


def _episode_goals(robot, envs, period, rng, clock, ranges, success_radius) -> Task:
    """Training's goals of an arm (:func:`task_for` with ``clock``): reached within
    ``success_radius`` m (default the robot's ``task.success_radius``)."""
    from sim2real.deploy.tasks.episodes import EpisodeGoals

    if success_radius is None:
        success_radius = robot.config.task.success_radius
    return EpisodeGoals(robot, envs, period, rng, clock, success_radius)


def _goals(robot, envs, backend, *, period, rng, success_time, fixed, window, interventions,
           **_) -> Task:  # fmt: skip
    """Reach goals (:func:`task_for`)."""
    from sim2real.deploy.tasks.goals import GoalTask

    return GoalTask(robot, envs, period, fixed, success_time, rng, window, interventions)


def _tracking(
    robot, envs, backend, *, motion, interventions=None, motion_start_after=0.0, **_
) -> Task:
    """Track a reference motion: ``motion`` is ``(MotionClock, waist joint indices)``; the clip
    starts ``motion_start_after`` s into RUNNING."""
    from sim2real.deploy.tasks.motion.tracking import TrackingTask

    if motion is None:
        raise ValueError("task 'tracking': needs a reference motion (deploy-run --motion CLIP)")
    clock, waist = motion
    return TrackingTask(robot, envs, backend, clock, waist, interventions, motion_start_after)


register_task("goals", _goals, episodes=_episode_goals)
register_task("locomotion", _locomotion, episodes=_episode_commands, velocity_commands=True)
register_task("tracking", _tracking)
