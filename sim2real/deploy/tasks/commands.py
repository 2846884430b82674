"""Velocity commands of a legged robot: ``--command`` parsed (:func:`parse_command`), the
ranges a schedule draws from (:class:`CommandRanges`) and the schedule itself
(:class:`CommandSchedule`: a new command every ``period`` s of RUNNING time from a seeded stream
per env, written into ``runtime.velocity_command``; its state kept for the soak's checkpoints,
:mod:`sim2real.deploy.core.stateful`). :mod:`sim2real.deploy.tasks.locomotion` measures how
well the robot follows them.

Heading commands (``CommandRanges.heading_command``) are legged_gym's command manager's: a
heading is drawn in place of the yaw rate, and every tick the policy is given
``clip(heading_stiffness * wrap(heading - yaw), -max_yaw_rate, max_yaw_rate)``, as
legged_gym's ``_post_physics_step_callback`` computes it (``legged_robot.py``:
``torch.clip(0.5*wrap_to_pi(self.commands[:, 3] - heading), -1., 1.)``; HIMLoco's fork clips
to +-2; Isaac Lab's ``UniformVelocityCommand`` with ``heading_control_stiffness``, clipped to
its ``ang_vel_z`` range). ``yaw`` is the runtime's base estimate's, the one thing on a robot
that knows its heading (as :class:`sim2real.deploy.tasks.heading.HeadingHold`, whose compiled
kernels compute it); the heading is absolute in the estimate's world frame, as legged_gym's is
in the simulator's."""

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

#: Proportional gain of a heading's yaw-rate command, 1/s: legged_gym's
#: ``0.5 * wrap_to_pi(heading - yaw)`` (legged_gym/envs/base/legged_robot.py,
#: ``_post_physics_step_callback``, ``commands.heading_command``); the heading hold's too
#: (:mod:`sim2real.deploy.tasks.heading`).
HEADING_GAIN = 0.5
#: rad/s, the largest yaw-rate command of a heading (legged_gym clips the same expression to
#: [-1, 1]; HIMLoco's fork to [-2, 2]).
HEADING_MAX_RATE = 1.0


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
        heading_command: Draw a heading, not a yaw rate (legged_gym's
            ``commands.heading_command``; module docstring): the policy is given the yaw rate
            of the heading's error every tick. Default False (our choice: the contract's
            ranges are raw yaw rates).
        heading: rad, the heading's range, uniform (legged_gym's ``ranges.heading``,
            [-3.14, 3.14] in ``legged_robot_config.py``; default [-pi, pi]).
        heading_stiffness: 1/s, yaw-rate command per rad of heading error (legged_gym's
            ``0.5``, Isaac Lab's ``heading_control_stiffness``; > 0).
        max_yaw_rate: rad/s, the clip of a heading command's yaw rate (legged_gym's 1, HIMLoco's
            2, Isaac Lab's ``ang_vel_z`` range; > 0).
        heading_fraction: Probability that a command is a heading command while
            ``heading_command`` is on (Isaac Lab's ``rel_heading_envs``; legged_gym: 1); the
            others draw ``yaw_rate``. A standing command (``zero_fraction``) has no heading.

    Raises:
        ValueError: a range inverted or not finite, a probability outside [0, 1], a stiffness
            or clip not a finite number > 0 (the message names ``CommandRanges.<field>``).
    """

    vx: tuple[float, float] = (0.0, 0.5)
    vy: tuple[float, float] = (0.0, 0.0)
    yaw_rate: tuple[float, float] = (-0.5, 0.5)
    zero_fraction: float = 0.2
    period: float | tuple[float, float] | None = None
    heading_command: bool = False
    heading: tuple[float, float] = (-math.pi, math.pi)
    heading_stiffness: float = HEADING_GAIN
    max_yaw_rate: float = HEADING_MAX_RATE
    heading_fraction: float = 1.0

    def __post_init__(self):
        for name in ("vx", "vy", "yaw_rate", "heading"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"CommandRanges.{name}: expected (low, high), got {(lo, hi)}")
        if self.period is not None:
            period = check_period(self.period, "CommandRanges.period")
            object.__setattr__(self, "period", period)
        for name in ("zero_fraction", "heading_fraction"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"CommandRanges.{name}: expected a probability, got {value}")
        for name in ("heading_stiffness", "max_yaw_rate"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"CommandRanges.{name}: expected a number > 0, got {value}")
        if not isinstance(self.heading_command, bool):
            raise ValueError(
                f"CommandRanges.heading_command: expected true or false, got {self.heading_command!r}"
            )

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """One command (3,): (vx, vy m/s, yaw rate rad/s); four draws from ``rng`` always.

        Raises:
            ValueError: heading commands on (their yaw rate is the schedule's, :meth:`draw`).
        """
        if self.heading_command:
            raise ValueError(
                "CommandRanges.heading_command: a heading's yaw rate is computed every tick by "
                "the soak's CommandSchedule; sample() draws raw yaw rates only"
            )
        return self.draw(rng)[0]

    def draw(self, rng: np.random.Generator) -> tuple[np.ndarray, float]:
        """One command (3,) (vx, vy m/s, yaw rate rad/s) and its heading, rad (NaN: a yaw-rate
        command, or a standing one). Draws from ``rng``, in order: standing or not, vx, vy;
        then, without heading commands, the yaw rate (four draws, :meth:`sample`'s); with them,
        whether it is a heading command when ``heading_fraction`` < 1, then the heading (its
        yaw rate 0 here: the schedule computes it) or the yaw rate."""
        zero = rng.random() < self.zero_fraction
        vx, vy = rng.uniform(*self.vx), rng.uniform(*self.vy)
        heading = math.nan
        if self.heading_command and (
            self.heading_fraction >= 1.0 or rng.random() < self.heading_fraction
        ):
            heading, wz = rng.uniform(*self.heading), 0.0
        else:
            wz = rng.uniform(*self.yaw_rate)
        if zero:
            return np.zeros(3), math.nan
        return np.array([vx, vy, wz]), heading


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
        heading: (envs,) rad, the current command's heading (NaN: a yaw-rate or standing
            command; ``ranges.heading_command``): while RUNNING the env's yaw-rate command is
            ``clip(heading_stiffness * wrap(heading - yaw), -max_yaw_rate, max_yaw_rate)``, yaw
            the base estimate's, every tick (module docstring).
        heading_ended: (envs,) int64, heading commands that ended RUNNING (a new command drawn);
            heading_error: (envs,) rad, the sum of their ``|wrap(heading - yaw)|`` at that moment
            (how near the robot came to each heading in its period).
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
        self.heading = np.full(envs, np.nan)
        self.heading_ended = np.zeros(envs, dtype=np.int64)
        self.heading_error = np.zeros(envs)
        self._yaw_args, self._yaw = np.zeros((2, envs)), np.zeros(envs)
        self._sin_cos, self._error = np.zeros((2, envs)), np.zeros(envs)
        self._hold = np.zeros(envs, dtype=bool)
        if self.ranges.heading_command:
            from sim2real.deploy.tasks.heading_kernel import load

            load()  # the kernels ready before the first tick

    #: Fields a checkpoint written before heading commands lacks, and what they are then.
    _HEADING = {"heading": np.nan, "heading_ended": 0, "heading_error": 0.0}

    def _fields(self) -> dict[str, np.ndarray]:
        return {"t_command": self.t_command, "issued": self.issued, "command": self.command}

    def _optional(self) -> dict[str, np.ndarray]:
        """Fields a checkpoint may lack (older ones): ``t_seen``, ``wait`` and the heading's."""
        heading = {"heading": self.heading, "heading_ended": self.heading_ended}
        return (
            {"t_seen": self.t_seen, "wait": self.wait}
            | heading
            | {"heading_error": self.heading_error}
        )

    def state_dict(self, env: int | None = None) -> dict:
        """``t_command`` (s), ``issued`` (int64), ``command`` (envs, 3), ``t_seen``, ``wait`` (s),
        ``heading`` (rad, NaN: none), ``heading_ended`` (int64), ``heading_error`` (rad); ``rng``:
        JSON of the streams' ``bit_generator.state`` (a list over the envs)."""
        out: dict = take(self._fields(), env)
        out |= take(self._optional(), env)
        out["rng"] = streams_json(self.streams, env_list(self.envs, env))
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        A state without ``t_seen`` (a checkpoint written before it) leaves it NaN: the first
        call after it moves no stopped clock on; one without ``wait`` leaves the period's low
        end; one without the heading's fields (written before heading commands, which it then
        could not run) leaves no heading and no heading figures.

        Raises:
            StateDictError: a missing field, a shape or a stream count that differs; nothing is
                changed.
        """
        check(self._fields(), state, env)
        envs = env_list(self.envs, env)
        rng = read_streams(state, "rng", len(envs))
        optional = self._optional()
        for key, array in optional.items():
            if key in state:
                check({key: array}, {key: state[key]}, env)
        put(self._fields(), state, env)
        self.t_seen[envs], self.wait[envs] = np.nan, self.period[0]
        for key, value in self._HEADING.items():
            optional[key][envs] = value
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
        headings = self.ranges.heading_command
        if headings:  # the estimate's heading now (the ending commands' and this tick's)
            from sim2real.deploy.tasks import heading_kernel as hk

            hk.yaw_args(runtime.state.base.orientation, self._yaw_args)
            np.arctan2(self._yaw_args[0], self._yaw_args[1], out=self._yaw)
        low, high = self.period
        for e in np.flatnonzero(due):
            if np.isfinite(self.heading[e]):  # a heading command ends: how near it came
                self.heading_ended[e] += 1
                self.heading_error[e] += abs(_wrap(self.heading[e] - self._yaw[e]))
            self.command[e], self.heading[e] = self.ranges.draw(self.streams[e])
            if high > low:
                self.wait[e] = self.streams[e].uniform(low, high)
            runtime.velocity_command[e] = self.command[e]
            self.t_command[e] = t
            self.issued[e] += 1
        if headings:
            self._steer(runtime)

    def resample(self, envs: np.ndarray) -> None:
        """Draw a new command for the envs of ``envs`` (bool mask (envs,)) at their next RUNNING
        tick, whatever their period's clock (legged_gym's ``_resample_commands`` in
        ``reset_idx``: a respawned robot's new episode begins with a new command)."""
        self.t_command[np.asarray(envs, dtype=bool)] = -np.inf

    def _steer(self, runtime) -> None:
        """The yaw-rate command of the RUNNING envs with a heading (``self._yaw``: this tick's
        estimate), by :mod:`sim2real.deploy.tasks.heading_kernel`'s kernels: theirs with the
        heading hold's arithmetic and numpy's arc tangent."""
        from sim2real.deploy.tasks import heading_kernel as hk

        command, r = runtime.velocity_command, self.ranges
        hk.target_args(runtime.mode, self.heading, self._yaw, self._hold, self._sin_cos)
        np.arctan2(self._sin_cos[0], self._sin_cos[1], out=self._error)
        hk.command(self._hold, self._error, r.heading_stiffness, r.max_yaw_rate, command, command)

    def heading_figures(self, env: int | None = None) -> dict | None:
        """``{"heading_commands_ended": n, "mean_heading_error_deg": deg or None}`` of env
        ``env`` (all envs by default): the heading commands that ended RUNNING and their mean
        ``|wrap(heading - yaw)|`` at their end (the estimate's yaw); None without heading
        commands."""
        if not self.ranges.heading_command:
            return None
        n = int(self.heading_ended.sum() if env is None else self.heading_ended[env])
        error = float(self.heading_error.sum() if env is None else self.heading_error[env])
        return {
            "heading_commands_ended": n,
            "mean_heading_error_deg": math.degrees(error / n) if n else None,
        }


def _wrap(angle: float) -> float:
    """``angle`` rad wrapped to (-pi, pi] (numpy's ``np.angle(np.exp(1j * angle))``)."""
    return math.atan2(math.sin(angle), math.cos(angle))
