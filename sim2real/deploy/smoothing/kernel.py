"""Kernels of :meth:`sim2real.deploy.smoothing.CommandSmoother.step`: everything around the Ruckig call.

:func:`before_ruckig` takes the new targets (non-finite ones replaced by the held target and
counted), clamps them to the limits of the mode and counts the clamps; in velocity mode it also
applies both stopping guards near the soft limits (the smooth one, ``|v| <= stopping_speed(room)``,
and the exact brake trigger) and counts what they cut. In torque mode it does the whole step
(clamp and rate limit; there is no Ruckig). :func:`after_ruckig` takes Ruckig's new state
(written into the work rows by the caller), screens the DoFs whose new trajectory could leave the
limits (position mode, on a new calculation; Python reads their extrema), clips the position
command and updates the commanded position and the mean acceleration.

Arrays are flat over the DoFs (``e * n + j``): ``w`` (``W_ROWS``, dofs) float64 state and work
rows, ``c`` (``C_ROWS``, dofs) constants, ``counts`` (4, dofs) int64 per-joint counters
(non-finite targets, target clamps, extrema violations, stopping-distance clamps).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim2real.deploy.kernels import np_max, np_min

#: Rows of ``w``; ``BEFORE`` and the two after it: ``POS``, ``VEL``, ``ACC`` before the step.
RAW, HELD, GOAL, CMD, POS, VEL, ACC, MEAN_ACC, CMD_POSITION, BEFORE = range(10)
W_ROWS = 12
#: Rows of ``c``.
LO, HI, VMAX, AMAX, EMAX, RATE, SCREEN_LO, SCREEN_HI, C, C2, EIGHT_A = range(11)
JDT, JDT2_2, JDT3_6, INV_J, INV_2J, INV_2A, A_2J = range(11, 18)
C_ROWS = 18
#: Rows of ``counts``.
NON_FINITE, TARGET_CLAMPS, EXTREMA, STOPPING = range(4)
#: Modes.
POSITION, VELOCITY, TORQUE = 0, 1, 2


@numba.njit(cache=True, nogil=True, inline="always")
def _speed(d: float, c: np.ndarray, i: int) -> float:
    """:func:`sim2real.deploy.smoothing.stopping_speed` as the smoother evaluates it in place."""
    d = np_max(d, 0.0)
    d = d * c[EIGHT_A, i]
    d = d + c[C2, i]
    d = math.sqrt(d)
    d = d - c[C, i]
    return d * 0.5


@numba.njit(cache=True, nogil=True, _nrt=False)
def _near(w: np.ndarray, c: np.ndarray, i: int) -> bool:
    p = w[POS, i]
    return p > c[SCREEN_HI, i] or p < c[SCREEN_LO, i] or abs(w[VEL, i]) > c[VMAX, i]


@numba.njit(cache=True, nogil=True, _nrt=False)
def _brake_bound(u: float, b: float, room: float, c: np.ndarray, i: int, dt: float) -> bool:
    """Whether the joint, after one more period of the worst acceleration, could no longer stop
    within ``room`` (``ReferenceSmoother._brake_needed`` for one row and DoF)."""
    t1 = u * dt
    t2 = b * (0.5 * dt * dt)
    t1 = t1 + t2
    t1 = t1 + c[JDT3_6, i]
    room = room - t1
    t2 = b * dt
    t2 = t2 + u
    t2 = t2 + c[JDT2_2, i]
    t2 = np_max(t2, 0.0)
    t3 = b + c[JDT, i]
    t3 = np_min(np_max(t3, 0.0), c[AMAX, i])
    t1 = t3 * c[INV_J, i]
    b = t2 * t1
    t1 = t1 * t1
    t1 = t1 * t3
    t1 = t1 * (1.0 / 3.0)
    b = b + t1
    t1 = t3 * t3
    t1 = t1 * c[INV_2J, i]
    t1 = t1 + t2
    t2 = t1 * c[INV_2A, i]
    t2 = t2 + c[A_2J, i]
    t2 = t2 * t1
    b = b + t2
    return b > room


@numba.njit(cache=True, nogil=True, _nrt=False)
def before_ruckig(
    mode: int,
    target: np.ndarray,
    has_target: bool,
    w: np.ndarray,
    c: np.ndarray,
    counts: np.ndarray,
    stop_dof: np.ndarray,
    dt: float,
    out: np.ndarray,
) -> None:
    """Ruckig's state (``w[POS:ACC + 1]``) noted in ``w[BEFORE:BEFORE + 3]``; targets in,
    Ruckig's next target in ``w[GOAL]`` out (torque mode: the command in ``w[CMD]`` and in
    ``out`` (envs, n)). ``target`` (envs, n) in the units of the mode, read when
    ``has_target``; ``stop_dof`` (dofs,) bool, the DoFs in safe stop; ``dt`` the control
    period, s."""
    dofs = w.shape[1]
    for r in range(3):
        for i in range(dofs):
            w[BEFORE + r, i] = w[POS + r, i]
    if has_target:
        n = target.shape[1]
        for i in range(dofs):
            w[RAW, i] = target[i // n, i % n]
        for i in range(dofs):
            if not math.isfinite(w[RAW, i]):
                if not stop_dof[i]:
                    counts[NON_FINITE, i] += 1
                w[RAW, i] = w[HELD, i]
        for i in range(dofs):
            w[HELD, i] = w[RAW, i]
    else:
        for i in range(dofs):
            w[RAW, i] = w[HELD, i]
    if mode == TORQUE:
        for i in range(dofs):
            r = w[RAW, i]
            g = np_min(np_max(r, -c[EMAX, i]), c[EMAX, i])
            w[GOAL, i] = g
            if r != g and not stop_dof[i]:
                counts[TARGET_CLAMPS, i] += 1
            d = np_min(np_max(g - w[CMD, i], -c[RATE, i]), c[RATE, i])
            w[CMD, i] = w[CMD, i] + d
        _command_out(w, out)
        return
    for i in range(dofs):
        w[MEAN_ACC, i] = w[VEL, i]  # Ruckig's velocity before the step
    if mode == POSITION:
        for i in range(dofs):
            r = w[RAW, i]
            g = np_min(np_max(r, c[LO, i]), c[HI, i])
            w[GOAL, i] = g
            if r != g and not stop_dof[i]:
                counts[TARGET_CLAMPS, i] += 1
        return
    near = False
    for i in range(dofs):
        r = w[RAW, i]
        g = np_min(np_max(r, -c[VMAX, i]), c[VMAX, i])
        if r != g and not stop_dof[i]:
            counts[TARGET_CLAMPS, i] += 1
        if stop_dof[i]:
            g = 0.0
        w[GOAL, i] = g
        w[RAW, i] = g
        near = near or _near(w, c, i)
    if near:
        for i in range(dofs):
            g = w[GOAL, i]
            g = np_min(g, _speed(c[HI, i] - w[POS, i], c, i))
            g = np_max(g, -_speed(w[POS, i] - c[LO, i], c, i))
            vel, acc, pos = w[VEL, i], w[ACC, i], w[POS, i]
            if _brake_bound(vel, acc, (c[HI, i] - pos) * 1.0, c, i, dt):
                g = np_min(g, 0.0)
            if _brake_bound(-vel, -acc, (c[LO, i] - pos) * -1.0, c, i, dt):
                g = np_max(g, 0.0)
            w[GOAL, i] = g
    for i in range(dofs):
        if w[RAW, i] != w[GOAL, i] and not stop_dof[i]:
            counts[STOPPING, i] += 1


@numba.njit(cache=True, nogil=True, _nrt=False)
def _command_out(w: np.ndarray, out: np.ndarray) -> None:
    """``w[CMD]`` into ``out`` (envs, n)."""
    n = out.shape[1]
    for i in range(w.shape[1]):
        out[i // n, i % n] = w[CMD, i]


@numba.njit(cache=True, nogil=True, _nrt=False)
def after_ruckig(
    mode: int,
    new_calculation: bool,
    w: np.ndarray,
    c: np.ndarray,
    inv_dt: float,
    near: np.ndarray,
    out: np.ndarray,
) -> bool:
    """After Ruckig's update.

    Ruckig's new state is in ``w[CMD]`` (position mode: the new position, copied to ``w[POS]``
    here; velocity mode: the new velocity, copied to ``w[VEL]`` here), ``w[VEL]`` (position mode),
    ``w[POS]`` (velocity mode) and ``w[ACC]``. Position mode: ``near`` (dofs,) bool marks the DoFs
    whose trajectory extrema Python must check (only on a ``new_calculation``); returns whether
    any. Then the command is clipped (position mode), the commanded position and the mean
    acceleration over the step (rad/s^2) written, and the command copied to ``out`` (envs, n)."""
    dofs = w.shape[1]
    any_near = False
    if mode == POSITION:
        for i in range(dofs):
            w[POS, i] = w[CMD, i]
        if new_calculation:
            for i in range(dofs):
                f = _near(w, c, i)
                near[i] = f
                any_near = any_near or f
        for i in range(dofs):
            p = np_min(np_max(w[CMD, i], c[LO, i]), c[HI, i])
            w[CMD, i] = p
            w[CMD_POSITION, i] = p
    else:
        for i in range(dofs):
            w[VEL, i] = w[CMD, i]
            w[CMD_POSITION, i] = w[POS, i]
    for i in range(dofs):
        w[MEAN_ACC, i] = (w[VEL, i] - w[MEAN_ACC, i]) * inv_dt
    _command_out(w, out)
    return any_near
