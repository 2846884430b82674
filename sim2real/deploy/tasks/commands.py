"""Velocity commands of a legged robot: ``--command`` parsed (:func:`parse_command`), the
ranges a schedule draws from (:class:`CommandRanges`) and the schedule itself
(:class:`CommandSchedule`: a new command every ``period`` s of RUNNING time from a seeded stream
per env, written into ``runtime.velocity_command``; its state kept for the soak's checkpoints,
:mod:`sim2real.deploy.core.stateful`). :mod:`sim2real.deploy.tasks.locomotion` measures how
well the robot follows them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim2real.deploy.core.stateful import (
    check,
    env_list,
    put,
    read_streams,
    set_streams,
    streams_json,
    take,
)


def parse_command(text: str) -> np.ndarray:
    """``"VX,VY,WZ"`` (m/s, m/s, rad/s, base frame) -> (3,) float array.

    Raises:
        ValueError: not three finite numbers (the message quotes ``text``).
    """
    try:
        command = np.array([float(x) for x in text.split(",")])
    except ValueError:
        command = np.array([])
    if command.shape != (3,) or not np.isfinite(command).all():
        raise ValueError(f"--command {text!r}: expected VX,VY,WZ (m/s, m/s, rad/s)")
    return command


def check_period(period, name: str) -> tuple[float, float]:
    """``period`` (s: a number or ``(low, high)``) as ``(low, high)`` with ``0 < low <= high``,
    both finite.

    Raises:
        ValueError: anything else (the message starts with ``name``).
    """
    pair = (period, period) if isinstance(period, (int, float)) else tuple(period)
    ok = len(pair) == 2 and all(isinstance(p, (int, float)) and math.isfinite(p) for p in pair)
    if not (ok and 0 < pair[0] <= pair[1]):
        raise ValueError(
            f"{name}: expected s > 0 (a number, or a range [low, high] with 0 < low <= high), "
            f"got {period!r}"
        )
    return float(pair[0]), float(pair[1])


@dataclass(frozen=True)
class CommandRanges:
    """What :class:`CommandSchedule` draws a command from (our choice unless noted).

    Attributes:
        vx: Forward speed, m/s, uniform. Our choice: 0-0.5 m/s, the walking range the shipped
            trot generator was tuned for (``sim2real/policies/gait.py``: ``deploy-run --command
            0.5,0,0``); legged_gym's go2 task samples [-1, 1] m/s (unitree_rl_gym
            go2_config.py ``commands.ranges.lin_vel_x``), beyond what it was tuned for.
        vy: Lateral speed, m/s, uniform. Our choice: 0 (the trot generator does not side-step).
        yaw_rate: rad/s, uniform. Our choice: +-0.5 rad/s (legged_gym: +-1 rad/s).
        zero_fraction: Probability that a period's command is zero (standing still; our
            choice: 0.2, as legged_gym zeroes small commands so the policy learns to stand;
            Isaac Lab's and mjlab's ``rel_standing_envs``).
        period: s between new commands, ``(low, high)``: each command lasts ``U(low, high)``
            s (Isaac Lab's and mjlab's ``resampling_time_range``; legged_gym's
            ``resampling_time`` is ``(t, t)``); a number ``t`` is ``(t, t)``. None (default):
            the schedule's own period (``soak-test --goal-period``).
        heading_command: legged_gym's ``commands.heading_command``: the training drew a
            heading, not a yaw rate (a training domain's ``[commands]``; recorded, not yet run
            by the schedule).
        heading: ``(low, high)`` rad, the headings drawn (``commands.ranges.heading``).
        heading_stiffness: 1/s, the yaw rate per rad of heading error (legged_gym's
            ``legged_robot.py``: ``0.5 * wrap_to_pi(heading - yaw)``).
        max_yaw_rate: rad/s, the clip of that yaw rate (HIMLoco's ``legged_robot.py`` 2,
            upstream legged_gym's 1).
    """

    vx: tuple[float, float] = (0.0, 0.5)
    vy: tuple[float, float] = (0.0, 0.0)
    yaw_rate: tuple[float, float] = (-0.5, 0.5)
    zero_fraction: float = 0.2
    period: float | tuple[float, float] | None = None
    heading_command: bool = False
    heading: tuple[float, float] | None = None
    heading_stiffness: float | None = None
    max_yaw_rate: float | None = None

    def __post_init__(self):
        for name in ("vx", "vy", "yaw_rate"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"CommandRanges.{name}: expected (low, high), got {(lo, hi)}")
        if self.period is not None:
            period = check_period(self.period, "CommandRanges.period")
            object.__setattr__(self, "period", period)
        if not 0.0 <= self.zero_fraction <= 1.0:
            raise ValueError(
                f"CommandRanges.zero_fraction: expected a probability, got {self.zero_fraction}"
            )

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """One command (3,): (vx, vy m/s, yaw rate rad/s); four draws from ``rng`` always."""
        zero = rng.random() < self.zero_fraction
        command = np.array(
            [rng.uniform(*self.vx), rng.uniform(*self.vy), rng.uniform(*self.yaw_rate)]
        )
        return np.zeros(3) if zero else command


class CommandSchedule:
    """A new velocity command every ``period`` s for each of ``envs`` legged robots, written into
    ``runtime.velocity_command[e]`` (the legged counterpart of :class:`sim2real.deploy.tasks.goals.
    GoalScheduler`).

    Only RUNNING time counts, as for goals: an env that is not running has its command clock
    held, and gets its first command when it first runs. Each env draws from its own generator
    (``rng``: one per env), so that a session's commands do not depend on its neighbours.

    Args:
        envs: Batch size.
        period: s of RUNNING time between new commands (> 0), or ``(low, high)``: each
            command then lasts ``U(low, high)`` s, drawn from the env's stream after the
            command (a fixed period draws nothing more: its streams are the command draws
            alone).
        rng: ``envs`` numpy generators, one command stream per env.
        ranges: What the commands are drawn from (:class:`CommandRanges`; its ``period`` is
            the caller's to pass here).

    Attributes:
        t_command: (envs,) s, when each env's command was issued, moved on by the time it was
            not running (its clock held: ``t - t_command`` is the RUNNING time since the draw).
            issued: (envs,) int64, commands issued (draws from the env's stream). command:
            (envs, 3), the current command (zeros before the first).
        t_seen: (envs,) s, the runtime's time at the previous call (NaN before the first): a
            stopped env's ``t_command`` moves on by the time since.
        wait: (envs,) s, how long the current command lasts (the period's low end before the
            first).
    """

    def __init__(self, envs: int, period: float, rng, ranges: CommandRanges | None = None):
        self.streams = list(rng)
        if len(self.streams) != envs:
            raise ValueError(f"rng: expected {envs} generators (one per env), got {len(rng)}")
        self.envs, self.period = envs, check_period(period, "period")
        self.ranges = CommandRanges() if ranges is None else ranges
        self.t_command = np.zeros(envs)
        self.issued = np.zeros(envs, dtype=np.int64)
        self.command = np.zeros((envs, 3))
        self.t_seen = np.full(envs, np.nan)
        self.wait = np.full(envs, self.period[0])

    def _fields(self) -> dict[str, np.ndarray]:
        return {"t_command": self.t_command, "issued": self.issued, "command": self.command}

    def state_dict(self, env: int | None = None) -> dict:
        """``t_command`` (s), ``issued`` (int64), ``command`` (envs, 3), ``t_seen``, ``wait`` (s); ``rng``:
        JSON of the streams' ``bit_generator.state`` (a list over the envs)."""
        out: dict = take(self._fields(), env)
        out["t_seen"] = take({"t_seen": self.t_seen}, env)["t_seen"]
        out["wait"] = take({"wait": self.wait}, env)["wait"]
        out["rng"] = streams_json(self.streams, env_list(self.envs, env))
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        A state without ``t_seen`` (a checkpoint written before it) leaves it NaN: the first
        call after it moves no stopped clock on; one without ``wait`` leaves the period's low
        end.

        Raises:
            StateDictError: a missing field, a shape or a stream count that differs; nothing is
                changed.
        """
        check(self._fields(), state, env)
        envs = env_list(self.envs, env)
        rng = read_streams(state, "rng", len(envs))
        optional = {"t_seen": self.t_seen, "wait": self.wait}
        for key, array in optional.items():
            if key in state:
                check({key: array}, {key: state[key]}, env)
        put(self._fields(), state, env)
        self.t_seen[envs], self.wait[envs] = np.nan, self.period[0]
        for key, array in optional.items():
            if key in state:
                put({key: array}, {key: state[key]}, env)
        set_streams(self.streams, envs, rng, "rng")

    def __call__(self, runtime) -> None:
        """After a tick of ``runtime``: hold the clocks of stopped envs (their draw time moves on
        by the time since the previous call, so a stop neither advances nor restarts the
        period), issue due commands."""
        running = runtime.mode == 2  # RUNNING
        t = runtime.time
        if not running.all():
            stopped = ~running & np.isfinite(self.t_seen)
            self.t_command[stopped] += t - self.t_seen[stopped]
            self.t_seen[:] = t
            if not running.any():
                return
        else:
            self.t_seen[:] = t
        due = running & ((self.issued == 0) | (t - self.t_command >= self.wait))
        low, high = self.period
        for e in np.flatnonzero(due):
            self.command[e] = self.ranges.sample(self.streams[e])
            if high > low:
                self.wait[e] = self.streams[e].uniform(low, high)
            runtime.velocity_command[e] = self.command[e]
            self.t_command[e] = t
            self.issued[e] += 1
