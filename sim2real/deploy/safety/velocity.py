"""The guard's ``velocity`` check: velocity limits that shrink to zero at the soft limits.

Velocity mode clamps a target velocity into the band from which each joint still stops before its
soft limit ``d`` away (:func:`velocity_band`): under the acceleration and jerk limits with one
control period of delay, ``v dt + v^2 / (2 a) + v a / (2 j) <= d`` (the smoother also brakes
exactly at the soft limits from Ruckig's own state). Torque mode's governor replaces the torque of
a joint faster than ``sqrt(2 a_max d)`` by gravity compensation plus a brake
(:meth:`Velocity.resolve`, Pinocchio).
Units: rad, rad/s, N m.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pinocchio as pin

from sim2real.deploy.kernels import np_max, np_min
from sim2real.deploy.safety.check import (
    ACC,
    CLAMP,
    FIRED,
    NEEDS_PYTHON,
    PREDICTED,
    SOFT_LOWER,
    SOFT_UPPER,
    TORQUE,
    VEL,
    VELOCITY,
    GuardCheck,
)
from sim2real.deploy.smoothing import stopping_speed

#: Rows of the check's constants: ``b = a^2 / j + 2 a dt`` and ``8 a`` of
#: :func:`sim2real.deploy.smoothing.stopping_speed`, ``a``, ``j`` the acceleration and jerk limits.
SPEED_B, EIGHT_A = 0, 1


@numba.njit(cache=True, nogil=True, inline="always")
def _stopping_speed(d: float, b: float, eight_a: float, vel: float) -> float:
    """``min(stopping_speed(d, a, j, dt), vel)`` with ``b = a^2 / j + 2 a dt``,
    ``eight_a = 8 a`` (the reference's order)."""
    s = 0.5 * (math.sqrt(b * b + eight_a * np_max(d, 0.0)) - b)
    return np_min(s, vel)


@numba.njit(cache=True, nogil=True, _nrt=False)
def velocity_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`Velocity`'s compiled share (signature of :class:`GuardCheck`)."""
    n = out.shape[1]
    lim = g.lim
    if stage == CLAMP and g.mode == VELOCITY:
        clamped = False
        for j in range(n):
            upper, lower = q[e, j], q[e, j]
            if has_commanded:
                upper = np_max(q[e, j], commanded[e, j])
                lower = np_min(q[e, j], commanded[e, j])
            d_up = np_max(lim[SOFT_UPPER, j] - upper, 0.0)
            d_down = np_max(lower - lim[SOFT_LOWER, j], 0.0)
            b, ea, vel = own[SPEED_B, j], own[EIGHT_A, j], lim[VEL, j]
            v_up = _stopping_speed(d_up, b, ea, vel)
            v_down = -_stopping_speed(d_down, b, ea, vel)
            t = out[e, j]
            if t > v_up or t < v_down:
                clamped = True
            out[e, j] = np_min(np_max(t, v_down), v_up)
        return FIRED if clamped else 0
    if stage == PREDICTED and g.mode == TORQUE:
        fast = False
        for j in range(n):
            d_up = np_max(lim[SOFT_UPPER, j] - q[e, j], 0.0)
            d_down = np_max(q[e, j] - lim[SOFT_LOWER, j], 0.0)
            acc = lim[ACC, j] * g.effort_scale[e, j]
            v_up = np_min(math.sqrt(2.0 * acc * d_up), lim[VEL, j])
            v_down = np_min(math.sqrt(2.0 * acc * d_down), lim[VEL, j])
            o = np_max(dq[e, j] - v_up, 0.0)
            u = np_max(-v_down - dq[e, j], 0.0)
            g.over[e, j] = o
            g.under[e, j] = u
            if o > 0 or u > 0:
                fast = True
        return FIRED | NEEDS_PYTHON if fast else 0
    return 0


def velocity_band(g, q: np.ndarray, commanded: np.ndarray | None):
    """(v_up, v_down) >= 0, (envs, n): speeds from which each joint of guard ``g`` still stops
    before its soft limit, capped at the velocity limit. Position and velocity mode: under the
    acceleration and jerk limits of the smoother's trajectories, the brake beginning one
    control period later (:func:`sim2real.deploy.smoothing.stopping_speed`). Torque mode (no Ruckig,
    the torque governor brakes): ``sqrt(2 a d)``, ``a`` scaled by the thermal derating."""
    upper = q if commanded is None else np.maximum(q, commanded)
    lower = q if commanded is None else np.minimum(q, commanded)
    d_up = np.maximum(g.soft_upper - upper, 0.0)
    d_down = np.maximum(lower - g.soft_lower, 0.0)
    if g.mode == "torque":
        # a derated drive brakes with a proportionally smaller torque
        acc = g.acc * g.effort_scale
        v_up = np.minimum(np.sqrt(2.0 * acc * d_up), g.vel)
        v_down = np.minimum(np.sqrt(2.0 * acc * d_down), g.vel)
    else:
        v_up = np.minimum(stopping_speed(d_up, g.acc, g.jerk, g.dt), g.vel)
        v_down = np.minimum(stopping_speed(d_down, g.acc, g.jerk, g.dt), g.vel)
    return v_up, v_down


class Velocity(GuardCheck):
    """A velocity that could not stop before the soft limit: clamped into the band (velocity
    mode), or the torque replaced by the governor's (torque mode)."""

    name = "velocity"
    what = "a speed clamped to what still stops before the soft limit"
    kernel = velocity_kernel

    def constants(self, guard) -> np.ndarray:
        # stopping_speed(d, a, j, dt) = 0.5 (sqrt(b^2 + 8 a d) - b), b as stopping_speed has it
        speed_b = guard.acc**2 / guard.jerk + 2.0 * guard.acc * guard.dt
        return np.array([speed_b, 8.0 * guard.acc], dtype=np.float64)

    def reference(self, stage, g, out, q, dq, commanded):
        mask = g._mask
        if stage == CLAMP and g.mode == "velocity":
            v_up, v_down = velocity_band(g, q, commanded)
            np.logical_or(out > v_up, out < -v_down, out=mask)
            clamped = mask.any(axis=1)
            np.negative(v_down, out=v_down)
            np.minimum(np.maximum(out, v_down, out=out), v_up, out=out)
            return clamped, None
        if stage == PREDICTED and g.mode == "torque":
            v_up, v_down = velocity_band(g, q, None)
            np.maximum(dq - v_up, 0.0, out=g._over)
            np.maximum(-v_down - dq, 0.0, out=g._under)
            np.logical_or(g._over > 0, g._under > 0, out=mask)
            fast = mask.any(axis=1)
            return fast, fast
        return None, None

    def resolve(self, g, k, needs, q, dq, out) -> None:
        """Torque mode's velocity governor: in the envs with a joint faster than its band
        (``g._over``, ``g._under`` > 0, rad/s), cap the torque toward the limit at gravity plus
        the brake (one Pinocchio gravity call per such env)."""
        over, under = g._over, g._under
        for e in np.flatnonzero((over > 0).any(axis=1) | (under > 0).any(axis=1)):
            grav = pin.computeGeneralizedGravity(g.model, g.data, q[e])
            brake = g._brake_gain * (under[e] - over[e])
            out[e] = np.where(over[e] > 0, np.minimum(out[e], grav + brake), out[e])
            out[e] = np.where(under[e] > 0, np.maximum(out[e], grav + brake), out[e])
