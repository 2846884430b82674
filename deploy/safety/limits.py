"""The guard's position-limit checks: ``soft_limit`` and ``hard_limit``.

``soft_limit``: a target position beyond the soft limit (``soft_limit_fraction`` of the range,
90 % by default) is clamped to it; in velocity and torque mode the estimate inside the soft band
is counted (a warning). ``hard_limit``: the target, the estimate or (velocity mode) the predicted
position beyond the hard limit: :attr:`SafetyGuard.hard_violation
<deploy.safety.guard.SafetyGuard.hard_violation>` is set and the runtime makes a safe stop. A
floating-base robot's *target* past a hard limit is clamped to the soft limit instead: its
low-gain PD's targets act as torques (``kp (target - q)``), and legged policies command past the
joint range by design (legged_gym trains without any bound on the targets); its estimate past a
hard limit still stops.

Each is a :class:`deploy.safety.check.GuardCheck`: its numpy reference and its compiled per-env
function do the same operations in the same order. Units: rad.
"""

from __future__ import annotations

import numba
import numpy as np

from deploy.kernels import np_max, np_min
from deploy.safety.check import (
    CLAMP,
    FIRED,
    INSPECT,
    LOWER,
    POSITION,
    PREDICTED,
    SOFT_LOWER,
    SOFT_UPPER,
    UPPER,
    VELOCITY,
    GuardCheck,
)

#: Rows of the hard-limit check's constants: the bounds of a position target (hard limits
#: widened by the guard's target tolerance; infinite for a floating base).
TARGET_LOWER, TARGET_UPPER = 0, 1


@numba.njit(cache=True, nogil=True)
def soft_limit_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`SoftLimit`'s compiled share (signature of :class:`GuardCheck`)."""
    n = out.shape[1]
    lim = g.lim
    soft = False
    if stage == INSPECT:
        if g.mode == POSITION:
            for j in range(n):
                t = out[e, j]
                if t < lim[SOFT_LOWER, j] or t > lim[SOFT_UPPER, j]:
                    soft = True
        else:
            for j in range(n):
                if q[e, j] > lim[SOFT_UPPER, j] or q[e, j] < lim[SOFT_LOWER, j]:
                    soft = True
    elif stage == CLAMP and g.mode == POSITION:
        for j in range(n):
            out[e, j] = np_min(np_max(out[e, j], lim[SOFT_LOWER, j]), lim[SOFT_UPPER, j])
    return FIRED if soft else 0


class SoftLimit(GuardCheck):
    """Position mode: a target past the soft limit is clamped to it. Velocity and torque mode:
    the estimate inside the soft band (a warning; nothing changed)."""

    name = "soft_limit"
    what = "a position target clamped into the soft joint limits"
    kernel = soft_limit_kernel

    def reference(self, stage, g, out, q, dq, commanded):
        mask = g._mask
        if stage == INSPECT:
            if g.mode == "position":
                np.logical_or(out < g.soft_lower, out > g.soft_upper, out=mask)
            else:
                np.logical_or(q > g.soft_upper, q < g.soft_lower, out=mask)
            return mask.any(axis=1), None
        if stage == CLAMP and g.mode == "position":
            np.minimum(np.maximum(out, g.soft_lower, out=out), g.soft_upper, out=out)
        return None, None


@numba.njit(cache=True, nogil=True)
def hard_limit_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`HardLimit`'s compiled share (signature of :class:`GuardCheck`)."""
    n = out.shape[1]
    lim = g.lim
    crossed = False
    if stage == INSPECT:
        for j in range(n):
            if q[e, j] < lim[LOWER, j] or q[e, j] > lim[UPPER, j]:
                crossed = True
        if g.mode == POSITION:
            for j in range(n):
                t = out[e, j]
                if t < own[TARGET_LOWER, j] or t > own[TARGET_UPPER, j]:
                    crossed = True
    elif stage == PREDICTED and g.mode == VELOCITY:
        for j in range(n):
            p = g.pred[e, j]
            if p < lim[LOWER, j] or p > lim[UPPER, j]:
                crossed = True
    return FIRED if crossed else 0


class HardLimit(GuardCheck):
    """The estimate past a hard limit, a position target past it (a floating base's targets are
    clamped instead: their bounds are infinite) or, in velocity mode, the predicted position:
    a hard violation (the runtime's safe stop)."""

    name = "hard_limit"
    what = "the estimate or a target past a hard limit (a safe stop)"
    stops = True
    kernel = hard_limit_kernel

    def constants(self, guard) -> np.ndarray:
        return np.array([guard._target_lower, guard._target_upper], dtype=np.float64)

    def reference(self, stage, g, out, q, dq, commanded):
        mask = g._mask
        if stage == INSPECT:
            np.logical_or(q < g.lower, q > g.upper, out=mask)
            crossed = mask.any(axis=1)
            if g.mode == "position":
                np.logical_or(out < g._target_lower, out > g._target_upper, out=mask)
                crossed |= mask.any(axis=1)
            return crossed, None
        if stage == PREDICTED and g.mode == "velocity":
            np.logical_or(g._pred < g.lower, g._pred > g.upper, out=mask)
            return mask.any(axis=1), None
        return None, None
