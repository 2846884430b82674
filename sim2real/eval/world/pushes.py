"""A floating-base robot's pushes of its training domain, run by the soak as a disturbance of the
world, apart from the fault schedule (:mod:`sim2real.eval.world.fault_schedule`, whose ``push`` faults are
forces). Two conventions, both as their stacks write them:

- legged_gym's ``push_robots`` (``mode = "set"``, the default): every ``push_interval_s`` the
  base's horizontal velocity is SET to a random value of up to ``max_push_vel_xy`` m/s per axis.
- mjlab's ``push_by_setting_velocity`` event (``mode = "add"``, unitree_rl_mjlab
  ``mjlab/tasks/velocity/velocity_env_cfg.py`` ``push_robot``): after a random interval drawn
  from ``interval_range_s`` (1-3 s), U(range) is ADDED to the root's world velocity per axis:
  ``x``, ``y``, ``z`` (m/s) and ``roll``, ``pitch``, ``yaw`` (rad/s, world frame).

When: legged_gym's pushes keep its global schedule (``common_step_counter % push_interval``:
every env at once, whatever its episode's age), so the soak pushes at ticks ``k * interval``.
Random intervals count per env from its reset (Isaac Lab's ``EventManager.reset`` redraws an
``interval`` term's wait with ``is_global_time=False``; holosoma's ``randomize_push_schedule``
zeroes the env's counter): the soak redraws the wait at each return to RUNNING, so no push lands
sooner than ``interval_range[0]`` after a stand-up (mjlab's function terms keep their wait across
a reset; the soak does not tell the two apart).

How a push acts (``apply``): ``"force"`` (the default): the wrench that gives the robot the
training push's velocity change over ``window`` s (:data:`PUSH_WINDOW`; ``SimDisturbances.
push_wrench``), spread over its bodies so that the whole robot takes that change, its joints'
speeds untouched, as under the training's push (``SimDisturbances.set_push_wrench``; a force on
the base alone swings the legs), felt by the accelerometer and gyro as a real shove is. Or the
velocity set between two physics steps as the training stacks do (``"velocity_hidden_from_imu"``),
which the estimator never sees. Each push's velocity and interval is a pure function of the
session seed and the push's index, so a resumed session pushes as an uninterrupted one
(:meth:`DomainPushes.state_dict`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: The ``numpy.random.default_rng([seed, PUSH_STREAM, k])`` stream of push ``k`` of a session
#: (apart from :data:`sim2real.eval.world.session_draw.STREAMS`); its interval's is ``[seed,
#: PUSH_STREAM, k, INTERVAL_STREAM]``.
PUSH_STREAM = 101
INTERVAL_STREAM = 1
#: The axes a push may move, in the order of a free joint's twist: linear x, y, z (m/s, world),
#: angular roll, pitch, yaw (rad/s, world).
AXES = ("x", "y", "z", "roll", "pitch", "yaw")
MODES = ("set", "add")
#: How a push acts (module docstring): a force over ``window`` s, or the velocity set at once.
APPLY = ("force", "velocity_hidden_from_imu")
#: s, the default window of a push's force (our choice): a real shove is a force over tens of
#: milliseconds (a hand's push lasts about 0.1 s); five control ticks at 50 Hz.
PUSH_WINDOW = 0.1


@dataclass(frozen=True)
class PushRanges:
    """The pushes of a training domain.

    Attributes:
        interval: s between pushes: a number (legged_gym's ``push_interval_s``; its default 15,
            unitree_rl_gym's G1, H1, H1-2 5) or a range ``(low, high)`` each interval is drawn
            from, uniform (mjlab's ``interval_range_s``, 1-3 s for the G1).
        max_velocity: legged_gym's ``max_push_vel_xy``, m/s: ``x`` and ``y`` uniform in
            ``[-max_velocity, max_velocity]`` (default 1.0 when no axis is given; unitree_rl_gym's
            humanoids 1.5). Not with the per-axis ranges.
        mode: ``"set"``: the drawn velocity replaces the base's on the axes drawn (legged_gym);
            ``"add"``: it is added to the base's present velocity (mjlab).
        x, y, z: Linear velocity ranges ``(low, high)``, m/s, world frame; None: 0 (a ranges
            file's ``[pushes] velocity = {x = [low, high], ...}``; mjlab's G1: x, y +-0.5,
            z +-0.25).
        roll, pitch, yaw: Angular velocity ranges about the world axes, rad/s; None: 0 (a ranges
            file's ``[pushes] angular_velocity = {roll = [low, high], ...}``; mjlab's G1: roll,
            pitch +-0.52, yaw +-0.78).
        apply: How a push acts, one of :data:`APPLY` (module docstring): ``"force"`` (default)
            or ``"velocity_hidden_from_imu"`` (the training stacks' way, which the IMU never
            feels).
        window: s, how long a push's force acts (``apply = "force"``; default
            :data:`PUSH_WINDOW`), rounded to whole control ticks (at least one); the force is
            the velocity change times the robot's mass over the rounded window.

    Raises:
        ValueError: a non-positive or inverted interval, a negative ``max_velocity``, an
            inverted axis range, an unknown mode or ``apply``, a window that is not a number
            > 0 s, ``max_velocity`` with axis ranges, or angular or vertical ranges with
            ``mode = "set"`` (legged_gym sets the horizontal velocity only).
    """

    interval: float | tuple[float, float] = 15.0
    max_velocity: float | None = None
    mode: str = "set"
    x: tuple[float, float] | None = None
    y: tuple[float, float] | None = None
    z: tuple[float, float] | None = None
    roll: tuple[float, float] | None = None
    pitch: tuple[float, float] | None = None
    yaw: tuple[float, float] | None = None
    apply: str = "force"
    window: float = PUSH_WINDOW

    def __post_init__(self):
        low, high = self.interval_range
        if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high):
            raise ValueError(
                f"PushRanges.interval: expected a number > 0 s or a range 0 < low <= high, got "
                f"{self.interval}"
            )
        if self.max_velocity is not None and not (
            math.isfinite(self.max_velocity) and self.max_velocity >= 0
        ):
            raise ValueError(f"PushRanges.max_velocity: expected >= 0 m/s, got {self.max_velocity}")
        if self.mode not in MODES:
            raise ValueError(f"PushRanges.mode: expected one of {list(MODES)}, got {self.mode!r}")
        if self.apply not in APPLY:
            raise ValueError(f"PushRanges.apply: expected one of {list(APPLY)}, got {self.apply!r}")
        if not (math.isfinite(self.window) and self.window > 0):
            raise ValueError(f"PushRanges.window: expected a number > 0 s, got {self.window}")
        given = [a for a in AXES if getattr(self, a) is not None]
        if given and self.max_velocity is not None:
            raise ValueError(
                f"PushRanges.max_velocity: expected it (legged_gym) or the axis ranges {given} "
                "(mjlab), not both"
            )
        for a in given:
            lo, hi = getattr(self, a)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"PushRanges.{a}: expected a range low <= high, got {(lo, hi)}")
        if self.mode == "set" and any(a in given for a in AXES[2:]):
            raise ValueError(
                f"PushRanges.mode: 'set' replaces the horizontal velocity only; the ranges "
                f'{[a for a in given if a in AXES[2:]]} expect mode = "add"'
            )

    def describe(self) -> str:
        """One line saying which pushes these are and how they act (the soak prints it: a
        ranges file without ``apply`` means forces, where it once meant the training stacks'
        velocity set at once)."""
        low, high = self.interval_range
        every = f"every {low:g} s" if low == high else f"every U({low:g}, {high:g}) s"
        if self.max_velocity is not None or not any(getattr(self, a) for a in AXES):
            size = f"the horizontal velocity {self.mode} to up to {self.max_velocity or 1.0:g} m/s"
        else:
            axes = ", ".join(f"{a} {list(getattr(self, a))}" for a in AXES if getattr(self, a))
            size = f"{'added' if self.mode == 'add' else 'set'}: {axes}"
        if self.apply == "force":
            how = (
                f"as forces over {self.window:g} s spread over the robot's bodies (the IMU feels "
                'them; apply = "velocity_hidden_from_imu" sets the velocity as training does)'
            )
        else:
            how = "the velocity changed at once between physics steps, unseen by the IMU"
        return f"{every}, {size}, {how}"

    @property
    def interval_range(self) -> tuple[float, float]:
        """``(low, high)`` s between pushes (``(interval, interval)`` for a fixed one)."""
        if isinstance(self.interval, tuple):
            return float(self.interval[0]), float(self.interval[1])
        return float(self.interval), float(self.interval)

    @property
    def legacy(self) -> bool:
        """legged_gym's pushes exactly: a fixed interval, the horizontal velocity set."""
        fixed = self.interval_range[0] == self.interval_range[1]
        return fixed and self.mode == "set" and all(getattr(self, a) is None for a in AXES)

    def ranges(self) -> np.ndarray:
        """(6, 2) the ``(low, high)`` of each axis of :data:`AXES` (unset: 0)."""
        if all(getattr(self, a) is None for a in AXES):  # legged_gym's: x and y
            v = 1.0 if self.max_velocity is None else self.max_velocity
            out = np.zeros((6, 2))
            out[:2] = (-v, v)
            return out
        return np.array([getattr(self, a) or (0.0, 0.0) for a in AXES], dtype=float)


def push_velocity(seed: int, index: int, max_velocity: float) -> np.ndarray:
    """(2,) m/s, the base velocity legged_gym push ``index`` of session ``seed`` sets (uniform
    per axis)."""
    rng = np.random.default_rng([int(seed), PUSH_STREAM, int(index)])
    return rng.uniform(-max_velocity, max_velocity, 2)


def push_twist(seed: int, index: int, ranges: np.ndarray) -> np.ndarray:
    """(6,) push ``index`` of session ``seed``: each axis of :data:`AXES` uniform in its range
    (``ranges`` (6, 2))."""
    rng = np.random.default_rng([int(seed), PUSH_STREAM, int(index)])
    return rng.uniform(ranges[:, 0], ranges[:, 1])


def push_interval(seed: int, index: int, low: float, high: float) -> float:
    """s from push ``index - 1`` (or the session's start) to push ``index``, uniform."""
    if low == high:
        return low
    rng = np.random.default_rng([int(seed), PUSH_STREAM, int(index), INTERVAL_STREAM])
    return float(rng.uniform(low, high))


class DomainPushes:
    """The pushes of a batch of sessions (one env each), on the session clock.

    Args:
        seeds: The sessions' seeds, one per env.
        ranges: The pushes (:class:`PushRanges`).
        control_period: s per tick.

    Attributes:
        times: Per env, the session times of the pushes applied so far (s), for the report and
            the attribution of falls.
        index: (envs,) int64, the index of each env's next push (random intervals only).
        next_tick: (envs,) int64, the tick of each env's next push (random intervals only).
        force_ticks: control ticks a push's force acts (``ranges.window`` rounded, >= 1).
        wrench: (envs, 6) the force (N) and torque (N m, world frame) on the base's body of each
            env's push in force now (its share of the push spread over the robot's bodies;
            zeros: none); its rows' force is what a fault's forces add to
            (:class:`sim2real.eval.soak.faults.SessionFaults`' ``base_forces``).
        until: (envs,) int64, the tick at which each env's push force ends (0: none).
        last_tick: (envs,) int64, the tick of each env's last push (-1: none yet).
        running: (envs,) bool, each env RUNNING at the previous call (random intervals: the
            wait is drawn again where an env enters RUNNING, module docstring).
    """

    def __init__(self, seeds: list[int], ranges: PushRanges, control_period: float):
        self.seeds = [int(s) for s in seeds]
        self.ranges = ranges
        self.dt = control_period
        self.every = max(1, round(ranges.interval_range[0] / control_period))
        self.times: list[list[float]] = [[] for _ in self.seeds]
        self._axes = ranges.ranges()
        self.index = np.ones(len(self.seeds), dtype=np.int64)
        self.next_tick = np.array([self._due(s, 1, 0) for s in self.seeds], dtype=np.int64)
        self.force_ticks = max(1, round(ranges.window / control_period))
        envs = len(self.seeds)
        self.wrench = np.zeros((envs, 6))
        self.until = np.zeros(envs, dtype=np.int64)
        self.last_tick = np.full(envs, -1, dtype=np.int64)
        self.running = np.zeros(envs, dtype=bool)

    def _push(self, rt, backend, e: int, twist: np.ndarray, add: bool) -> None:
        """Push env ``e`` by ``twist`` (:meth:`SimDisturbances.push_base
        <sim2real.deploy.backends.sim.disturbances.SimDisturbances.push_base>`'s meaning) as
        ``ranges.apply`` says, and note it."""
        if self.ranges.apply == "force":
            duration = self.force_ticks * self.dt
            total = backend.push_wrench(e, twist, add, duration)
            self.wrench[e] = backend.set_push_wrench(e, total)
            self.until[e] = rt.ticks + self.force_ticks
        elif add:
            backend.push_base(e, twist, add=True)
        else:
            backend.set_base_velocity(e, twist[:2])
        self.times[e].append(rt.ticks * self.dt)
        self.last_tick[e] = rt.ticks

    def _end_forces(self, rt, backend) -> None:
        """Remove the push forces whose window has ended."""
        for e in np.flatnonzero((self.until > 0) & (self.until <= rt.ticks)):
            self.wrench[e] = backend.set_push_wrench(e, np.zeros(6))
            self.until[e] = 0

    def _due(self, seed: int, index: int, after: int) -> int:
        """The tick of push ``index`` of session ``seed``, the previous one at tick ``after``."""
        return after + max(
            1, round(push_interval(seed, index, *self.ranges.interval_range) / self.dt)
        )

    def __call__(self, rt, backend) -> None:
        """Push every env whose robot is RUNNING when its push is due; end the push forces
        whose window is over. Random intervals: an env entering RUNNING (its reset) waits a new
        interval from there (module docstring)."""
        from sim2real.deploy.core.modes import RUNNING

        if self.until.any():
            self._end_forces(rt, backend)
        if self.ranges.legacy:  # legged_gym: tick k * every, the same for every env
            if rt.ticks % self.every:
                return
            index = rt.ticks // self.every
            for e, seed in enumerate(self.seeds):
                if rt.mode[e] == RUNNING:
                    v = push_velocity(seed, index, self._axes[0, 1])
                    self._push(rt, backend, e, np.array([*v, 0.0, 0.0, 0.0, 0.0]), False)
            return
        running = rt.mode == RUNNING
        for e in np.flatnonzero(running & ~self.running):  # reset: the wait starts again
            self.next_tick[e] = self._due(self.seeds[e], int(self.index[e]), rt.ticks)
        self.running[:] = running
        for e in np.flatnonzero(self.next_tick <= rt.ticks):
            seed, k = self.seeds[e], int(self.index[e])
            if rt.mode[e] == RUNNING:
                twist = push_twist(seed, k, self._axes)
                self._push(rt, backend, e, twist, self.ranges.mode == "add")
            self.index[e] = k + 1
            self.next_tick[e] = self._due(seed, k + 1, rt.ticks)

    def state_dict(self, env: int | None = None) -> dict:
        """``times`` (JSON lists), ``index`` and ``next_tick`` (int64), ``wrench`` (N, N m),
        ``until`` and ``last_tick`` (int64), ``running`` (bool) of env ``env`` (every env's
        without ``env``; the force itself is in the plant's state, MuJoCo's ``xfrc_applied``)."""
        rows = list(range(len(self.seeds))) if env is None else [env]
        return {
            "times": [list(self.times[e]) for e in rows],
            "index": self.index[rows].copy(),
            "next_tick": self.next_tick[rows].copy(),
            "wrench": self.wrench[rows].copy(),
            "until": self.until[rows].copy(),
            "last_tick": self.last_tick[rows].copy(),
            "running": self.running[rows].copy(),
        }

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (a state without ``index``, from a checkpoint of
        legged_gym's pushes, keeps the schedule: it is the tick's; one without ``wrench`` has
        no push in force; one without ``running``, from before the wait restarted at a
        reset, has every env taken as RUNNING: a stopped one restarts its wait at its next
        RUNNING)."""
        rows = list(range(len(self.seeds))) if env is None else [env]
        times = [list(map(float, t)) for t in state["times"]]
        for r, e in enumerate(rows):
            self.times[e] = times[r]
        if "index" in state:
            self.index[rows] = np.asarray(state["index"], dtype=np.int64)
            self.next_tick[rows] = np.asarray(state["next_tick"], dtype=np.int64)
        if "wrench" in state:  # a push in force (a checkpoint before pushes were forces: none)
            self.wrench[rows] = np.asarray(state["wrench"], dtype=float)
            self.until[rows] = np.asarray(state["until"], dtype=np.int64)
            self.last_tick[rows] = np.asarray(state["last_tick"], dtype=np.int64)
        self.running[rows] = np.asarray(state.get("running", [True] * len(rows)), dtype=bool)
