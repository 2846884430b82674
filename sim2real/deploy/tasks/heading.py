"""Heading hold: a zero yaw-rate command holds the heading the robot had when it was given.

A velocity policy turns a little on a straight command: its yaw-rate tracking has an offset (the
shipped Go2 policy turns about -4 deg/s at ``--command 0.5,0,0``), and nothing in a fixed
command corrects it. legged_gym (and unitree_rl_gym, which trains on it) closes this loop in the
command itself: with ``commands.heading_command = True`` (its default) the policy's yaw-rate
command is ``clip(0.5 * wrap(heading - yaw), -1, 1)`` (``legged_robot.py``,
``_post_physics_step_callback``), so the policies trained there were trained with it.
:class:`HeadingHold` does the same at deployment: while an env is RUNNING with a command whose
yaw rate is zero, its ``runtime.velocity_command[:, 2]`` becomes ``gain * wrap(reference - yaw)``
clipped to ``max_rate``, where ``yaw`` is the base estimate's (on hardware nothing else knows
it: the yaw of the filter's world frame, which drifts with the gyro's unobservable yaw bias)
and ``reference`` is the yaw when the hold began. A command with a yaw rate is passed through
unchanged, and the hold lets go at every stop.

A tick runs as the compiled kernels of :mod:`sim2real.deploy.tasks.heading_kernel` around
numpy's two arc tangents, bound to the runtime's arrays (the same numbers); the numpy path
(:meth:`HeadingHold.reference_call`) is their reference.
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.core.stateful import put, take
from sim2real.deploy.kernels.calls import bind, fits
from sim2real.deploy.tasks.commands import HEADING_GAIN, HEADING_MAX_RATE


class HeadingHold:
    """The heading hold of ``envs`` legged robots (module docstring).

    Args:
        envs: Batch size.
        gain: 1/s, yaw-rate command per rad of heading error (> 0; ``HEADING_GAIN``).
        max_rate: rad/s, the clip of the yaw-rate command (> 0; ``HEADING_MAX_RATE``).

    Attributes:
        reference: (envs,) rad, the held heading (the base estimate's yaw when the hold began).
        holding: (envs,) bool, the hold is on (RUNNING with a zero yaw-rate command).

    Raises:
        ValueError: ``gain`` or ``max_rate`` not a finite number > 0.
    """

    def __init__(self, envs: int, gain: float = HEADING_GAIN, max_rate: float = HEADING_MAX_RATE):
        for name, value in (("gain", gain), ("max_rate", max_rate)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"heading hold {name}: expected a number > 0, got {value}")
        self.gain, self.max_rate = float(gain), float(max_rate)
        self.reference = np.zeros(envs)
        self.holding = np.zeros(envs, dtype=bool)
        self.envs = envs
        #: False: numpy's path only (the reference of the kernels)
        self.compiled = True
        self._key = self._calls = None  # the arrays the kernels' calls are bound to, the calls
        self._args, self._yaw = np.zeros((2, envs)), np.zeros(envs)
        self._sin_cos, self._error = np.zeros((2, envs)), np.zeros(envs)
        self._hold = np.zeros(envs, dtype=bool)
        from sim2real.deploy.tasks.heading_kernel import load

        load()  # the kernels ready before the first tick

    def __call__(self, runtime, asked: np.ndarray) -> None:
        """Write the yaw-rate command of the next tick into ``runtime.velocity_command``.

        Args:
            runtime: A floating-base :class:`~sim2real.deploy.runtime.Runtime` after its tick.
            asked: (envs, 3) the command the operator gave (m/s, m/s, rad/s).
        """
        calls = self._bound(runtime, asked) if self.compiled else None
        if calls is None:
            self.reference_call(runtime, asked)
            return
        yaw_args, hold_args, command = calls
        yaw_args()
        np.arctan2(self._args[0], self._args[1], out=self._yaw)
        hold_args()
        np.arctan2(self._sin_cos[0], self._sin_cos[1], out=self._error)
        command()

    def _bound(self, runtime, asked: np.ndarray):
        """The kernels' three calls bound to ``runtime``'s arrays and ``asked`` (made when they
        change), or None where an array does not fit them (numpy's path)."""
        key = (runtime.state.base.orientation, runtime.mode, asked, runtime.velocity_command)
        if self._key is not None and all(a is b for a, b in zip(self._key, key, strict=True)):
            return self._calls
        from sim2real.deploy.tasks import heading_kernel as k

        orientation, mode, _, command = key
        envs = self.envs
        ok = (
            fits(orientation, np.float64, (envs, 4))
            and fits(mode, np.int8, (envs,))
            and fits(asked, np.float64, (envs, 3))
            and fits(command, np.float64, (envs, 3))
        )
        self._key = key
        self._calls = None
        if ok:
            self._calls = (
                bind(k.yaw_args, orientation, self._args),
                bind(
                    k.hold_args,
                    mode,
                    asked,
                    self._yaw,
                    self.holding,
                    self.reference,
                    self._hold,
                    self._sin_cos,
                ),
                bind(k.command, self._hold, self._error, self.gain, self.max_rate, asked, command),
            )
        return self._calls

    def reference_call(self, runtime, asked: np.ndarray) -> None:
        """:meth:`__call__` by numpy (the kernels' reference)."""
        from sim2real.deploy.core.attitude import yaw_of  # numba's module: not at the CLI's parse
        from sim2real.deploy.core.modes import RUNNING

        yaw = yaw_of(runtime.state.base.orientation)
        hold = (runtime.mode == RUNNING) & (asked[:, 2] == 0.0)
        begin = hold & ~self.holding
        self.reference[begin] = yaw[begin]
        self.holding[:] = hold
        error = np.angle(np.exp(1j * (self.reference - yaw)))  # wrapped to (-pi, pi]
        rate = np.clip(self.gain * error, -self.max_rate, self.max_rate)
        runtime.velocity_command[:, 2] = np.where(hold, rate, asked[:, 2])

    def _fields(self) -> dict[str, np.ndarray]:
        return {"reference": self.reference, "holding": self.holding}

    def state_dict(self, env: int | None = None) -> dict:
        """``reference`` (envs,) rad and ``holding`` (envs,) bool."""
        return take(self._fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`.

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        put(self._fields(), state, env)
