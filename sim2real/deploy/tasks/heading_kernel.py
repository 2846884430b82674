"""The compiled arithmetic of :meth:`sim2real.deploy.tasks.heading.HeadingHold.__call__` and of
the heading commands of :class:`sim2real.deploy.tasks.commands.CommandSchedule` (:func:`yaw_args`,
:func:`target_args` in place of :func:`hold_args`, :func:`command`).

A tick of the hold is :func:`yaw_args` (the arc tangent's arguments of the estimate's heading),
``np.arctan2``, :func:`hold_args` (which envs hold, the reference where a hold begins, the sine
and cosine of the heading error), ``np.arctan2`` and :func:`command` (the clipped yaw-rate
command); numpy's arctan2 is not the C library's, so the two arc tangents stay numpy's. Each
expression is numpy's in numpy's order: ``yaw_of``'s, ``np.angle(np.exp(1j * d))`` as
``arctan2(sin d, cos d)`` (as :mod:`sim2real.deploy.tasks.locomotion_kernel` computes it), and
``np.clip``'s maximum then minimum, a NaN kept.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: ``sim2real.deploy.core.modes.RUNNING``
_RUNNING = 2


@numba.njit(cache=True, nogil=True)
def yaw_args(orientation, args):
    """``args`` (2, envs): the arc tangent's arguments of the yaw of ``orientation`` (envs, 4)
    (``attitude.yaw_of``)."""
    for e in range(orientation.shape[0]):
        w, x, y, z = orientation[e, 0], orientation[e, 1], orientation[e, 2], orientation[e, 3]
        args[0, e] = 2.0 * (w * z + x * y)
        args[1, e] = 1.0 - 2.0 * (y * y + z * z)


@numba.njit(cache=True, nogil=True)
def hold_args(mode, asked, yaw, holding, reference, hold, sin_cos):
    """``hold`` (envs,) bool: RUNNING with a zero yaw-rate command ``asked[:, 2]``; the
    ``reference`` (envs,) rad takes ``yaw`` where a hold begins; ``holding`` becomes ``hold``;
    ``sin_cos`` (2, envs): the sine and cosine of ``reference - yaw``."""
    for e in range(mode.shape[0]):
        h = mode[e] == _RUNNING and asked[e, 2] == 0.0
        if h and not holding[e]:
            reference[e] = yaw[e]
        holding[e] = h
        hold[e] = h
        d = reference[e] - yaw[e]
        sin_cos[0, e] = math.sin(d)
        sin_cos[1, e] = math.cos(d)


@numba.njit(cache=True, nogil=True)
def target_args(mode, target, yaw, hold, sin_cos):
    """``hold`` (envs,) bool: RUNNING with a heading ``target`` (envs,) rad (NaN: none);
    ``sin_cos`` (2, envs): the sine and cosine of ``target - yaw`` (a heading command's error,
    :func:`hold_args`' with the drawn heading for the held one)."""
    for e in range(mode.shape[0]):
        hold[e] = mode[e] == _RUNNING and math.isfinite(target[e])
        d = target[e] - yaw[e]
        sin_cos[0, e] = math.sin(d)
        sin_cos[1, e] = math.cos(d)


@numba.njit(cache=True, nogil=True)
def command(hold, error, gain, max_rate, asked, velocity_command):
    """``velocity_command[:, 2]``: ``clip(gain * error, -max_rate, max_rate)`` where ``hold``,
    else ``asked[:, 2]``."""
    for e in range(hold.shape[0]):
        if hold[e]:
            r = gain * error[e]
            r = r if (np.isnan(r) or r > -max_rate) else -max_rate
            r = r if (np.isnan(r) or r < max_rate) else max_rate
            velocity_command[e, 2] = r
        else:
            velocity_command[e, 2] = asked[e, 2]


def load() -> None:
    """Compile (or load from numba's cache) the kernels' specializations for the runtime's
    arrays' types (float64, an int8 mode, bool flags): done when a hold is built."""
    from sim2real.deploy.kernels.calls import bind

    f1, b, two = np.zeros(1), np.zeros(1, dtype=np.bool_), np.zeros((2, 1))
    bind(yaw_args, np.zeros((1, 4)), two)
    bind(hold_args, np.zeros(1, dtype=np.int8), np.zeros((1, 3)), f1, b, f1, b, two)
    bind(command, b, f1, 1.0, 1.0, np.zeros((1, 3)), np.zeros((1, 3)))
    bind(target_args, np.zeros(1, dtype=np.int8), f1, f1, b, two)
