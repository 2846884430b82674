"""Kernel of :meth:`sim2real.deploy.safety.guard.SafetyGuard.filter`: everything but the Pinocchio calls.

Phase 0 notes the count rows the motion envelope shares (``g.counted``), then runs, env by env,
the stages of :mod:`sim2real.deploy.safety.check` through every registered check
(:data:`sim2real.deploy.safety.checks.KERNELS`, unrolled in count-row order) and the prediction of
the next state between them, then counts each check that fired. It returns :data:`NEEDS_PYTHON` when
some check asked for its Pinocchio part (``g.needs``); otherwise it goes on with phase 1, which
keeps the last accepted target (position mode) and runs the :data:`FINAL` stage.

numba's cache of :func:`guard_filter` is keyed on its sources, the checks' modules among them
(:mod:`sim2real.numba_cache`) and on the number of checks (the length of ``g.own``): an edit to a
check's compiled function recompiles the kernel that inlines it.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
from numba import literal_unroll

from sim2real.deploy.kernels.calls import SLOT, view1, view2, view3
from sim2real.deploy.safety.check import (
    CLAMP,
    FINAL,
    FIRED,
    INSPECT,
    NEEDS_PYTHON,
    POSITION,
    PREDICTED,
    VELOCITY,
)
from sim2real.deploy.safety.checks import KERNELS
from sim2real.deploy.safety.predicted import DT


class GuardArrays(NamedTuple):
    """The guard's arrays the kernel and the checks' compiled functions read and write (made
    once, updated in place). Shapes: ``envs``, ``n``, ``K`` checks, ``pairs`` collision pairs."""

    mode: int  # sim2real.deploy.safety.check.POSITION, VELOCITY or TORQUE
    lim: np.ndarray  # (LIM_ROWS, n) the robot's limits (rows of sim2real.deploy.safety.check)
    scalars: np.ndarray  # dt (s), the screens' margin (m), has pairs (1.0 or 0.0)
    effort_scale: np.ndarray  # (envs, n) thermal derating of the effort limits
    counts: np.ndarray  # (K, envs) int64, the guard's count_matrix
    hard_violation: np.ndarray  # (envs,) bool
    beyond_ticks: np.ndarray  # (envs,) int64, consecutive ticks of an estimate past a hard limit
    far_ticks: np.ndarray  # (envs,) int64, consecutive ticks of one farther than its tolerance
    pred: np.ndarray  # (envs, n) the predicted next position, rad
    tmp: np.ndarray  # (envs, n) work
    screen: np.ndarray  # (2, envs, n) rad: configurations of the workspace, collision screens
    workspace_margin: np.ndarray  # (envs,) m inside the workspace box at screen[0]
    over: np.ndarray  # (envs, n) rad/s above the torque governor's band
    under: np.ndarray  # (envs, n) rad/s below it
    held: np.ndarray  # (envs,) bool, held by a check's Python part
    last_valid: np.ndarray  # (envs, n) the hold target of position mode
    pair_clearance: np.ndarray  # (envs, pairs) m, each pair's distance at screen[1]
    pair_weights: np.ndarray  # (pairs, n) m/rad
    fired: np.ndarray  # (K, envs) bool: work
    needs: np.ndarray  # (K, envs) bool: which checks' Python part must run for which env
    stops: np.ndarray  # (K,) bool: the check's firing is a hard violation
    geometric: np.ndarray  # (3,) int64: the count rows the motion envelope also counts in
    counted: np.ndarray  # (3, envs) int64: those rows when phase 0 began
    own: tuple  # K arrays (rows, n) float64: each check's constants


@numba.njit(cache=True, nogil=True, _nrt=False)
def _stage(stage, e, out, q, dq, commanded, has_commanded, g) -> bool:
    """Run ``stage`` of env ``e`` through every check; record ``fired`` and ``needs``; return
    whether a check needs its Python part."""
    python = False
    k = 0
    for check in literal_unroll(KERNELS):
        code = check(stage, e, out, q, dq, commanded, has_commanded, g, g.own[k])
        if code & FIRED:
            g.fired[k, e] = True
        if code & NEEDS_PYTHON:
            g.needs[k, e] = True
            python = True
        k += 1
    return python


@numba.njit(cache=True, nogil=True, _nrt=False)
def guard_filter(phase, out, q, dq, commanded, has_commanded, g) -> int:
    """One :meth:`~sim2real.deploy.safety.guard.SafetyGuard.filter` from ``phase`` on (module docstring).

    ``out`` (envs, n) the target, clamped in place; ``q``, ``dq`` the estimate; ``commanded``
    velocity mode's integrated command (``q`` when ``has_commanded`` is False); ``g`` the
    guard's :class:`GuardArrays`. Returns :data:`NEEDS_PYTHON` or 0 (done).
    """
    envs, n = out.shape
    checks = g.fired.shape[0]
    mode = g.mode
    # the stages as int64 values: a module constant passed as is types as a literal, and numba
    # then compiles _stage once per stage (four times the kernel's compile, the same machine code
    # but for the branches the literal folds away)
    _inspect, _clamp = np.int64(INSPECT), np.int64(CLAMP)
    _predicted, _final = np.int64(PREDICTED), np.int64(FINAL)
    if phase == 0:
        dt = g.scalars[DT]
        python = False
        for k in range(g.geometric.shape[0]):
            r = g.geometric[k]
            for e in range(envs):
                g.counted[k, e] = g.counts[r, e]
        for e in range(envs):
            g.hard_violation[e] = False
            g.held[e] = False
            for k in range(checks):
                g.fired[k, e] = False
                g.needs[k, e] = False
            _stage(_inspect, e, out, q, dq, commanded, has_commanded, g)
            _stage(_clamp, e, out, q, dq, commanded, has_commanded, g)
            for j in range(n):  # the predicted next state
                if mode == POSITION:
                    g.pred[e, j] = out[e, j]
                elif mode == VELOCITY:
                    p = out[e, j] * dt
                    p = p + q[e, j]
                    g.pred[e, j] = p
                else:
                    p = dq[e, j] * dt
                    g.pred[e, j] = p + q[e, j]
            if _stage(_predicted, e, out, q, dq, commanded, has_commanded, g):
                python = True
            for k in range(checks):
                if g.fired[k, e]:
                    g.counts[k, e] += 1
                    if g.stops[k]:
                        g.hard_violation[e] = True
        if python:
            return NEEDS_PYTHON
    for e in range(envs):
        if mode == POSITION and not g.held[e]:
            for j in range(n):
                g.last_valid[e, j] = out[e, j]
        for k in range(checks):
            g.fired[k, e] = False
        _stage(_final, e, out, q, dq, commanded, has_commanded, g)
        for k in range(checks):
            if g.fired[k, e]:
                g.counts[k, e] += 1
    return 0


#: The table of :func:`guard_table`: ``mode`` in the header, then the slots
#: (:func:`~sim2real.deploy.kernels.calls.put_slot`) of the target, the estimate and the
#: commanded position, and of :class:`GuardArrays`' arrays (its fields from ``lim`` to
#: ``counted``, in order): each name's dtype and dimensions.
TABLE_SLOTS = (
    ("out", "f8", 2), ("q", "f8", 2), ("dq", "f8", 2), ("commanded", "f8", 2), ("lim", "f8", 2),
    ("scalars", "f8", 1), ("effort_scale", "f8", 2), ("counts", "i8", 2),
    ("hard_violation", "b1", 1), ("beyond_ticks", "i8", 1), ("far_ticks", "i8", 1),
    ("pred", "f8", 2), ("tmp", "f8", 2), ("screen", "f8", 3), ("workspace_margin", "f8", 1),
    ("over", "f8", 2), ("under", "f8", 2), ("held", "b1", 1), ("last_valid", "f8", 2),
    ("pair_clearance", "f8", 2), ("pair_weights", "f8", 2), ("fired", "b1", 2),
    ("needs", "b1", 2), ("stops", "b1", 1), ("geometric", "i8", 1), ("counted", "i8", 2),
)  # fmt: skip
TABLE_HEADER = 1


@numba.njit(cache=True, nogil=True)
def guard_table(phase, table, has_commanded, own) -> int:
    """:func:`guard_filter` on the arrays of ``table`` (:data:`TABLE_SLOTS`) and the checks'
    constants ``own``: two arrays to unbox a call, not thirty-three."""
    f8, i8, b1 = np.float64, np.int64, np.bool_
    s = TABLE_HEADER
    g = GuardArrays(
        table[0], view2(table, s + 4 * SLOT, f8), view1(table, s + 5 * SLOT, f8),
        view2(table, s + 6 * SLOT, f8), view2(table, s + 7 * SLOT, i8),
        view1(table, s + 8 * SLOT, b1), view1(table, s + 9 * SLOT, i8),
        view1(table, s + 10 * SLOT, i8), view2(table, s + 11 * SLOT, f8),
        view2(table, s + 12 * SLOT, f8), view3(table, s + 13 * SLOT, f8),
        view1(table, s + 14 * SLOT, f8), view2(table, s + 15 * SLOT, f8),
        view2(table, s + 16 * SLOT, f8), view1(table, s + 17 * SLOT, b1),
        view2(table, s + 18 * SLOT, f8), view2(table, s + 19 * SLOT, f8),
        view2(table, s + 20 * SLOT, f8), view2(table, s + 21 * SLOT, b1),
        view2(table, s + 22 * SLOT, b1), view1(table, s + 23 * SLOT, b1),
        view1(table, s + 24 * SLOT, i8), view2(table, s + 25 * SLOT, i8), own,
    )  # fmt: skip
    out, q, dq = view2(table, s, f8), view2(table, s + SLOT, f8), view2(table, s + 2 * SLOT, f8)
    return guard_filter(phase, out, q, dq, view2(table, s + 3 * SLOT, f8), has_commanded, g)
