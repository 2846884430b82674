"""Kernel of :meth:`deploy.safety.guard.SafetyGuard.filter`: everything but the Pinocchio calls.

Phase 0 checks the hard and soft limits, clamps (position mode: to the soft limits; velocity mode:
into the velocity band), computes the predicted next state, the torque governor's excess speeds
and the screens of the per-env geometric and effort checks. It returns a code (``NEEDS_*`` bits)
when Python must call Pinocchio: the torque governor (gravity per env) or a screen that says a
check could fire; otherwise it goes on with phase 1. Phase 1 keeps the last accepted target
(position mode) and clamps torques to the derated effort limit (torque mode).

Arrays: ``lim`` (``ROWS``, n) float64 per-joint constants; ``counts`` the guard's
``count_matrix`` (rows: :mod:`deploy.safety.checks`); ``checks`` (3, envs) bool, rows workspace,
self-collision, effort (which envs' Pinocchio checks must run).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from deploy.kernels import np_max, np_min, pairs_may_touch, row_sum
from deploy.safety.checks import row

#: Rows of ``lim``.
LOWER, UPPER, TARGET_LOWER, TARGET_UPPER, SOFT_LOWER, SOFT_UPPER = 0, 1, 2, 3, 4, 5
VEL, ACC, SPEED_B, EIGHT_A, EFFORT, GRAVITY_BOUND = 6, 7, 8, 9, 10, 11
EE_LEVER = 12  # m per rad: bound of the end effector's displacement per radian of each joint
ROWS = 13
#: Modes.
POSITION, VELOCITY, TORQUE = 0, 1, 2
#: Rows of the count matrix (deploy.safety.checks).
SOFT_LIMIT, HARD_LIMIT, VELOCITY_CHECK = row("soft_limit"), row("hard_limit"), row("velocity")
EFFORT_CHECK = row("effort")
#: Return bits.
NEEDS_GOVERNOR, NEEDS_SCREENS = 1, 2


@numba.njit(cache=True, nogil=True, inline="always")
def _stopping_speed(d: float, b: float, eight_a: float, vel: float) -> float:
    """``min(stopping_speed(d, a, j, dt), vel)`` with ``b = a^2 / j + 2 a dt``,
    ``eight_a = 8 a`` (the reference's order)."""
    s = 0.5 * (math.sqrt(b * b + eight_a * np_max(d, 0.0)) - b)
    return np_min(s, vel)


@numba.njit(cache=True, nogil=True)
def guard_filter(
    phase: int,
    mode: int,
    out: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    commanded: np.ndarray,
    has_commanded: bool,
    lim: np.ndarray,
    scalars: np.ndarray,
    effort_scale: np.ndarray,
    counts: np.ndarray,
    hard_violation: np.ndarray,
    pred: np.ndarray,
    tmp: np.ndarray,
    screen: np.ndarray,
    workspace_margin: np.ndarray,
    over: np.ndarray,
    under: np.ndarray,
    checks: np.ndarray,
    held: np.ndarray,
    last_valid: np.ndarray,
    pair_clearance: np.ndarray,
    pair_weights: np.ndarray,
) -> int:
    """One :meth:`~deploy.safety.guard.SafetyGuard.filter` from ``phase`` on (module docstring).

    Shapes: ``out`` (the target, clamped in place), ``q``, ``dq``, ``commanded``,
    ``effort_scale``, ``pred``, ``tmp``, ``over``, ``under``, ``last_valid`` (envs, n);
    ``screen`` (2, envs, n) rows workspace_q, collision_q; ``workspace_margin`` (envs,) m;
    ``scalars``: dt (s), screen margin (m),
    has_pairs (1.0 or 0.0); ``pair_clearance`` (envs, pairs) m, each collision pair's distance at
    the collision screen's configuration; ``pair_weights`` (pairs, n) m/rad
    (:func:`robots.chain_bounds.collision_pair_weights`). Units as in the guard.
    """
    envs, n = out.shape
    if phase == 0:
        dt, margin = scalars[0], scalars[1]
        has_pairs = scalars[2] != 0.0
        any_governor = False
        any_screen = False
        for e in range(envs):
            hard_violation[e] = False
            held[e] = False
            crossed = False
            for j in range(n):
                if q[e, j] < lim[LOWER, j] or q[e, j] > lim[UPPER, j]:
                    crossed = True
            soft = False
            if mode == POSITION:
                for j in range(n):
                    t = out[e, j]
                    if t < lim[TARGET_LOWER, j] or t > lim[TARGET_UPPER, j]:
                        crossed = True
                    if t < lim[SOFT_LOWER, j] or t > lim[SOFT_UPPER, j]:
                        soft = True
                    t = np_min(np_max(t, lim[SOFT_LOWER, j]), lim[SOFT_UPPER, j])
                    out[e, j] = t
                    pred[e, j] = t
            elif mode == VELOCITY:
                clamped = False
                for j in range(n):
                    upper, lower = q[e, j], q[e, j]
                    if has_commanded:
                        upper = np_max(q[e, j], commanded[e, j])
                        lower = np_min(q[e, j], commanded[e, j])
                    d_up = np_max(lim[SOFT_UPPER, j] - upper, 0.0)
                    d_down = np_max(lower - lim[SOFT_LOWER, j], 0.0)
                    b, ea, vel = lim[SPEED_B, j], lim[EIGHT_A, j], lim[VEL, j]
                    v_up = _stopping_speed(d_up, b, ea, vel)
                    v_down = -_stopping_speed(d_down, b, ea, vel)
                    t = out[e, j]
                    if t > v_up or t < v_down:
                        clamped = True
                    t = np_min(np_max(t, v_down), v_up)
                    out[e, j] = t
                    if q[e, j] > lim[SOFT_UPPER, j] or q[e, j] < lim[SOFT_LOWER, j]:
                        soft = True
                    p = t * dt
                    p = p + q[e, j]
                    pred[e, j] = p
                    if p < lim[LOWER, j] or p > lim[UPPER, j]:
                        crossed = True
                if clamped:
                    counts[VELOCITY_CHECK, e] += 1
            else:
                fast = False
                for j in range(n):
                    p = dq[e, j] * dt
                    pred[e, j] = p + q[e, j]
                    if q[e, j] > lim[SOFT_UPPER, j] or q[e, j] < lim[SOFT_LOWER, j]:
                        soft = True
                    d_up = np_max(lim[SOFT_UPPER, j] - q[e, j], 0.0)
                    d_down = np_max(q[e, j] - lim[SOFT_LOWER, j], 0.0)
                    acc = lim[ACC, j] * effort_scale[e, j]
                    v_up = np_min(math.sqrt(2.0 * acc * d_up), lim[VEL, j])
                    v_down = np_min(math.sqrt(2.0 * acc * d_down), lim[VEL, j])
                    o = np_max(dq[e, j] - v_up, 0.0)
                    u = np_max(-v_down - dq[e, j], 0.0)
                    over[e, j] = o
                    under[e, j] = u
                    if o > 0 or u > 0:
                        fast = True
                if fast:
                    counts[VELOCITY_CHECK, e] += 1
                    any_governor = True
            if soft:
                counts[SOFT_LIMIT, e] += 1
            if crossed:
                counts[HARD_LIMIT, e] += 1
                hard_violation[e] = True
        # screens of the per-env checks at the predicted state
        for e in range(envs):
            for j in range(n):
                tmp[e, j] = abs(pred[e, j] - screen[0, e, j]) * lim[EE_LEVER, j]
            move = row_sum(tmp, e)
            ws = workspace_margin[e] <= move + margin
            col = has_pairs and pairs_may_touch(
                pred, e, screen[1], pair_clearance, pair_weights, margin, tmp
            )
            eff = False
            for j in range(n):
                if lim[GRAVITY_BOUND, j] > lim[EFFORT, j] * effort_scale[e, j]:
                    eff = True
            checks[0, e] = ws
            checks[1, e] = col
            checks[2, e] = eff
            if ws or col or eff:
                any_screen = True
        code = (NEEDS_GOVERNOR if any_governor else 0) | (NEEDS_SCREENS if any_screen else 0)
        if code:
            return code
    if mode == POSITION:
        for e in range(envs):
            if not held[e]:
                for j in range(n):
                    last_valid[e, j] = out[e, j]
    elif mode == TORQUE:
        for e in range(envs):
            clamped = False
            for j in range(n):
                limit = lim[EFFORT, j] * effort_scale[e, j]
                t = out[e, j]
                if t > limit or t < -limit:
                    clamped = True
                out[e, j] = np_min(np_max(t, -limit), limit)
            if clamped:
                counts[EFFORT_CHECK, e] += 1
    return 0
