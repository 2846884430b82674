"""A floating-base robot's pushes of its training domain: legged_gym's ``push_robots`` (every
``push_interval_s`` the base's horizontal velocity is set to a random value of up to
``max_push_vel_xy`` m/s per axis), run by the soak as a disturbance of the world, apart from the
fault schedule (:mod:`eval.world.fault_schedule`, whose ``push`` faults are forces).

:class:`PushRanges` is what a ranges file's ``[pushes]`` table sets (``interval`` s,
``max_velocity`` m/s); :class:`DomainPushes` applies them to a batch of sessions. Each push's
velocity is a pure function of the session seed and the push's index, so a resumed session pushes
exactly as an uninterrupted one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: The ``numpy.random.default_rng([seed, PUSH_STREAM, k])`` stream of push ``k`` of a session
#: (apart from :data:`eval.world.session_draw.STREAMS`).
PUSH_STREAM = 101


@dataclass(frozen=True)
class PushRanges:
    """legged_gym's pushes (``domain_rand.push_robots``).

    Attributes:
        interval: s between pushes (``push_interval_s``; legged_gym's default 15, unitree_rl_gym's
            G1, H1, H1-2 5).
        max_velocity: Largest horizontal base velocity a push sets, per axis, m/s
            (``max_push_vel_xy``; default 1.0, unitree_rl_gym's humanoids 1.5): each of x and y
            uniform in ``[-max_velocity, max_velocity]``.
    """

    interval: float = 15.0
    max_velocity: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.interval) and self.interval > 0):
            raise ValueError(f"PushRanges.interval: expected > 0 s, got {self.interval}")
        if not (math.isfinite(self.max_velocity) and self.max_velocity >= 0):
            raise ValueError(f"PushRanges.max_velocity: expected >= 0 m/s, got {self.max_velocity}")


def push_velocity(seed: int, index: int, max_velocity: float) -> np.ndarray:
    """(2,) m/s, the base velocity push ``index`` of session ``seed`` sets (uniform per axis)."""
    rng = np.random.default_rng([int(seed), PUSH_STREAM, int(index)])
    return rng.uniform(-max_velocity, max_velocity, 2)


class DomainPushes:
    """The pushes of a batch of sessions (one env each), on the session clock.

    Args:
        seeds: The sessions' seeds, one per env.
        ranges: The pushes (:class:`PushRanges`).
        control_period: s per tick.

    Attributes:
        times: Per env, the session times of the pushes applied so far (s), for the report and
            the attribution of falls.
    """

    def __init__(self, seeds: list[int], ranges: PushRanges, control_period: float):
        self.seeds = [int(s) for s in seeds]
        self.ranges = ranges
        self.every = max(1, round(ranges.interval / control_period))
        self.dt = control_period
        self.times: list[list[float]] = [[] for _ in self.seeds]

    def __call__(self, rt, backend) -> None:
        """Push every env whose robot is RUNNING when a push is due (tick ``k * every``)."""
        if rt.ticks % self.every:
            return
        from deploy.runtime import RUNNING

        index = rt.ticks // self.every
        for e, seed in enumerate(self.seeds):
            if rt.mode[e] == RUNNING:
                backend.set_base_velocity(e, push_velocity(seed, index, self.ranges.max_velocity))
                self.times[e].append(rt.ticks * self.dt)

    def state_dict(self, env: int | None = None) -> dict:
        """``times`` of env ``env`` (JSON list; every env's without ``env``)."""
        rows = self.times if env is None else [self.times[env]]
        return {"times": [list(t) for t in rows]}

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`."""
        rows = [list(map(float, t)) for t in state["times"]]
        if env is None:
            self.times = rows
        else:
            self.times[env] = rows[0]
