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

from collections import namedtuple

import numba
import numpy as np
from numba import literal_unroll

from sim2real.deploy.kernels.tables import Table
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

#: The guard's table: the target, the estimate, the commanded position and the guard's arrays
#: the kernel and the checks' compiled functions read and write (made once, updated in place),
#: each declared once. Shapes: ``envs``, ``n``, ``K`` checks, ``pairs`` collision pairs.
GUARD = Table(
    "sim2real.deploy.safety.kernel:GUARD",
    mode="i8",  # sim2real.deploy.safety.check.POSITION, VELOCITY or TORQUE
    out="f8[envs,n]",  # the target, clamped in place
    q="f8[envs,n]",  # the estimate, rad
    dq="f8[envs,n]",  # rad/s
    commanded="f8[envs,n]",  # velocity mode's integrated command (q without one)
    lim="f8[*,n]",  # (LIM_ROWS, n) the robot's limits (rows of sim2real.deploy.safety.check)
    scalars="f8[*]",  # dt (s), the screens' margin (m), has pairs (1.0 or 0.0)
    effort_scale="f8[envs,n]",  # thermal derating of the effort limits
    counts="i8[K,envs]",  # the guard's count_matrix
    hard_violation="b1[envs]",
    beyond_ticks="i8[envs]",  # consecutive ticks of an estimate past a hard limit
    far_ticks="i8[envs]",  # consecutive ticks of one farther than its tolerance
    pred="f8[envs,n]",  # the predicted next position, rad
    tmp="f8[envs,n]",  # work
    screen="f8[2,envs,n]",  # rad: configurations of the workspace, collision screens
    workspace_margin="f8[envs]",  # m inside the workspace box at screen[0]
    over="f8[envs,n]",  # rad/s above the torque governor's band
    under="f8[envs,n]",  # rad/s below it
    held="b1[envs]",  # held by a check's Python part
    last_valid="f8[envs,n]",  # the hold target of position mode
    pair_clearance="f8[envs,*]",  # (envs, pairs) m, each pair's distance at screen[1]
    pair_weights="f8[*,n]",  # (pairs, n) m/rad
    fired="b1[K,envs]",  # work
    needs="b1[K,envs]",  # which checks' Python part must run for which env
    stops="b1[K]",  # the check's firing is a hard violation
    geometric="i8[3]",  # the count rows the motion envelope also counts in
    counted="i8[3,envs]",  # those rows when phase 0 began
)
#: :data:`GUARD`'s fields but the target, estimate and command, and ``own``: K arrays (rows, n)
#: float64, each check's constants; what the kernel reads when the table is not used.
GuardArrays = namedtuple(
    "GuardArrays",
    [*(f.name for f in GUARD if f.name not in ("out", "q", "dq", "commanded")), "own"],
)


@numba.njit(cache=True, nogil=True, _nrt=False)
def _stage(stage, e, out, q, dq, commanded, has_commanded, g, own) -> bool:
    """Run ``stage`` of env ``e`` through every check; record ``fired`` and ``needs``; return
    whether a check needs its Python part."""
    python = False
    k = 0
    for check in literal_unroll(KERNELS):
        code = check(stage, e, out, q, dq, commanded, has_commanded, g, own[k])
        if code & FIRED:
            g.fired[k, e] = True
        if code & NEEDS_PYTHON:
            g.needs[k, e] = True
            python = True
        k += 1
    return python


@numba.njit(cache=True, nogil=True, _nrt=False)
def guard_filter(phase, out, q, dq, commanded, has_commanded, g, own) -> int:
    """One :meth:`~sim2real.deploy.safety.guard.SafetyGuard.filter` from ``phase`` on (module docstring).

    ``out`` (envs, n) the target, clamped in place; ``q``, ``dq`` the estimate; ``commanded``
    velocity mode's integrated command (``q`` when ``has_commanded`` is False); ``g`` the
    guard's arrays by name (its :class:`GuardArrays` or packed :data:`GUARD`), ``own`` the
    checks' constants. Returns :data:`NEEDS_PYTHON` or 0 (done).
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
            _stage(_inspect, e, out, q, dq, commanded, has_commanded, g, own)
            _stage(_clamp, e, out, q, dq, commanded, has_commanded, g, own)
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
            if _stage(_predicted, e, out, q, dq, commanded, has_commanded, g, own):
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
        _stage(_final, e, out, q, dq, commanded, has_commanded, g, own)
        for k in range(checks):
            if g.fired[k, e]:
                g.counts[k, e] += 1
    return 0


@numba.njit(cache=True, nogil=True)
def guard_table(phase, t, has_commanded, own) -> int:
    """:func:`guard_filter` on the packed table ``t`` (:data:`GUARD`) and the checks' constants
    ``own``: two arrays to unbox a call, not thirty-three."""
    return guard_filter(phase, t.out, t.q, t.dq, t.commanded, has_commanded, t, own)
