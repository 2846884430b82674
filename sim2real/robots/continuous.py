"""Continuous joints (a wheel): hinges without a position limit.

robot.toml says ``continuous = true`` in place of ``position_limit``; the Robot's
``position_lower``/``position_upper`` (and soft limits) of such a joint are ``-inf``/``+inf``, so
every comparison with a limit (the guard's, the violation monitor's, the fall check's) leaves its
angle alone while its speed and torque stay checked. Code that draws poses inside the limits
(the loader's MuJoCo/Pinocchio agreement check, the importer's inertia and gravity samples) draws
a continuous joint's angle from one turn instead: :func:`sampling_bounds`.
"""

from __future__ import annotations

import numpy as np

#: Half of one turn, rad: a continuous joint's angle is drawn from [-pi, pi] where poses are sampled.
TURN_HALF = np.pi


def sampling_bounds(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` (rad, arrays shaped as given) with each infinite bound replaced by
    -/+ :data:`TURN_HALF`: the range to draw a pose's joint angles from."""
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    return (
        np.where(np.isfinite(lower), lower, -TURN_HALF),
        np.where(np.isfinite(upper), upper, TURN_HALF),
    )


def continuous_mask(lower, upper) -> np.ndarray:
    """Bool per joint: no position limit (either bound infinite)."""
    return ~(np.isfinite(np.asarray(lower)) & np.isfinite(np.asarray(upper)))
