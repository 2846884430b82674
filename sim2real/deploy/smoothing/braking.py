"""The stopping math of a jerk-limited joint: how far it needs to stop from a speed
(:func:`stopping_distance`) and the largest speed from which it stops within a distance
(:func:`stopping_speed`).

The smoother's velocity-mode stopping guards (:mod:`sim2real.deploy.smoothing.reference`,
:mod:`sim2real.deploy.smoothing.kernel`) and the safety guard's stopping bounds
(:mod:`sim2real.deploy.safety.guard`) are
built on them.
"""

from __future__ import annotations

import numpy as np


def stopping_distance(velocity, acceleration_limit, jerk_limit):
    """Distance, rad, a joint moving at ``velocity`` (rad/s, with zero acceleration) needs to stop
    under the acceleration limit (rad/s^2) and jerk limit (rad/s^3):
    ``v^2 / (2 a) + |v| a / (2 j)``.

    Exact for a jerk-limited brake that reaches the acceleration limit (``|v| >= a^2 / j``: jerk
    ramp, constant deceleration, jerk ramp, symmetric in time, average speed ``|v| / 2`` over
    ``|v| / a + a / j``); an upper bound below (the distance is then ``|v|^1.5 / sqrt(j)``).
    Arrays broadcast.
    """
    v = np.abs(velocity)
    return v * v / (2.0 * acceleration_limit) + v * acceleration_limit / (2.0 * jerk_limit)


def stopping_speed(distance, acceleration_limit, jerk_limit, latency=0.0):
    """Largest speed, rad/s, from which a joint stops within ``distance`` (rad, >= 0) when the
    brake begins ``latency`` s (>= 0) later: the inverse of ``v latency + stopping_distance(v)``,
    ``(sqrt(b^2 + 8 a d) - b) / 2`` with ``b = a^2 / j + 2 a latency``. Arrays broadcast."""
    b = acceleration_limit**2 / jerk_limit + 2.0 * acceleration_limit * latency
    return 0.5 * (np.sqrt(b * b + 8.0 * acceleration_limit * np.maximum(distance, 0.0)) - b)
