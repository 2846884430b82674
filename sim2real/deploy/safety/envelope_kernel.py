"""Kernel of :class:`sim2real.deploy.safety.envelope.MotionEnvelope`: the joint box of each env's motion
envelope
and the screen that says where Pinocchio must look (:func:`envelope_screen`), with the lookup of
a pair's lower-bound table (:func:`table_bound`, of :mod:`sim2real.deploy.safety.pair_grid`) and a pair's
local approach bound (:func:`pair_reach`, of :mod:`sim2real.deploy.safety.local_reach`).

The box of env ``e``, joint ``i`` spans the estimated position, the smoother's position before
and after the step, and the point where the joint comes to rest if the smoother brakes from its
new state (:func:`brake_reach`, with a derated drive's deceleration, :func:`brake_headroom`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from sim2real.deploy.safety import drive_kernel as dk

#: Rows of ``need``.
COLLISION, WORKSPACE = 0, 1
#: Bits of :func:`certify`'s code: some env needs an exact query; a velocity drive may run past
#: its limit (``beyond``).
UNCERTAIN, BEYOND = 1, 2
#: Most cells per joint a pair table's lookup reads (our choice): a wider box reads a coarser
#: level (:mod:`sim2real.deploy.safety.pair_grid`). Here, not there: numba's cache of this module's kernels
#: is keyed on this file.
LOOKUP_CELLS = 8
#: Cells of slack on each side of a lookup's index range: round-off in ``(x - lower) / step``
#: never puts a box's edge in the wrong cell.
INDEX_SLACK = 1e-9


@numba.njit(cache=True, nogil=True, inline="always")
def brake_reach(v: float, a: float, amax: float, jmax: float) -> tuple[float, float]:
    """``(forward, back)`` rad: how far a joint at speed ``v`` (rad/s) and acceleration ``a``
    (rad/s^2) can still move along (``forward``) and against (``back``) its direction of motion
    while a jerk-limited brake (``amax``, ``jmax``) brings it to rest.

    Forward: the acceleration toward the motion is ramped down first (time ``a / j``, the speed
    rising by ``a^2 / 2j`` to ``v_eff``), then the brake from ``v_eff`` at zero acceleration,
    ``v_eff^2 / 2a + v_eff a / 2j`` (:func:`sim2real.deploy.smoothing.braking.stopping_distance`). Back: an
    acceleration against the motion cannot be released at once and may carry the joint past rest
    by at most ``a^3 / (2 j^2)``. Direction: that of ``v``, or of ``a`` at rest.
    """
    s = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else (1.0 if a >= 0.0 else -1.0))
    speed = abs(v)
    toward = max(a * s, 0.0)
    against = max(-a * s, 0.0)
    v_eff = speed + toward * toward / (2.0 * jmax)
    forward = v_eff * toward / jmax + v_eff * v_eff / (2.0 * amax) + v_eff * amax / (2.0 * jmax)
    back = against * against * against / (2.0 * jmax * jmax)
    return s * forward, -s * back


@numba.njit(cache=True, nogil=True, inline="always")
def brake_headroom(scale: float, gravity_share: float, floor: float) -> float:
    """Fraction of the full deceleration a drive derated to ``scale`` (of its effort limit) still
    has: the torque left above the worst gravity load, ``(scale - g) / (1 - g)`` with ``g`` the
    gravity bound's share of the effort limit (the share of the limit the acceleration limits
    were sized from), clipped to ``[floor, 1]``."""
    if gravity_share >= 1.0:
        return max(min(scale, 1.0), floor)
    return max(min((scale - gravity_share) / (1.0 - gravity_share), 1.0), floor)


@numba.njit(cache=True, nogil=True, _nrt=False)
def table_bound(
    p: int,
    centre: np.ndarray,
    half: np.ndarray,
    weights: np.ndarray,
    joint: np.ndarray,
    grid: np.ndarray,
    cells: np.ndarray,
    offset: np.ndarray,
    values: np.ndarray,
) -> float:
    """m, a lower bound of pair ``p``'s distance over the box ``centre +- half`` (n,) rad from its
    table (the arrays of :class:`sim2real.deploy.safety.pair_grid.PairTables`; ``weights`` (n,) m/rad the
    pair's approach bound); ``-inf`` without a table or for a NaN box. Compiled
    :func:`sim2real.deploy.safety.pair_grid.table_bound` (two axes), the same arithmetic in the same
    order."""
    if offset[p, 0] < 0:
        return -math.inf
    f0 = f1 = l0 = l1 = 0
    overshoot = 0.0
    for k in range(2):
        j = joint[p, k]
        if j < 0:
            continue
        lo, hi = centre[j] - half[j], centre[j] + half[j]
        if not lo <= hi:
            return -math.inf
        g_lo, g_hi, step = grid[p, k, 0], grid[p, k, 1], grid[p, k, 2]
        overshoot += weights[j] * max(g_lo - lo, hi - g_hi, 0.0)
        lo, hi = min(max(lo, g_lo), g_hi), min(max(hi, g_lo), g_hi)
        first = min(max(math.floor((lo - g_lo) / step - INDEX_SLACK), 0), cells[p, k] - 1)
        last = min(math.floor((hi - g_lo) / step + INDEX_SLACK), cells[p, k] - 1)
        if k == 0:
            f0, l0 = first, last
        else:
            f1, l1 = first, last
    level = 0
    while (l0 >> level) - (f0 >> level) + 1 > LOOKUP_CELLS or (
        (l1 >> level) - (f1 >> level) + 1 > LOOKUP_CELLS
    ):
        level += 1
    width = -(-cells[p, 1] // (1 << level))
    start = offset[p, level]
    least = math.inf
    for a in range(f0 >> level, (l0 >> level) + 1):
        for b in range(f1 >> level, (l1 >> level) + 1):
            least = min(least, values[start + a * width + b])
    return least - overshoot


@numba.njit(cache=True, nogil=True, _nrt=False)
def pair_reach(
    p: int,
    weights: np.ndarray,
    speeds: np.ndarray,
    spread: np.ndarray,
    order: np.ndarray,
    nest: np.ndarray,
    bound: np.ndarray,
) -> float:
    """m, how far pair ``p``'s distance can shrink over the box ``|q - c| <= spread`` (n,) rad:
    ``weights`` (pairs, n) m/rad the global bound, ``speeds`` (pairs, n) m/rad the speeds of the
    pairs' moved points at ``c``, ``order`` (n,) and ``nest`` (pairs, n, n) the joints' nesting;
    ``bound`` (n,) scratch. Compiled :func:`sim2real.deploy.safety.local_reach.local_reach` for one pair,
    the same arithmetic in the same order."""
    n = spread.shape[0]
    for j in order:
        s = speeds[p, j]
        for k in range(n):
            if nest[p, j, k] == 1:
                s = s + bound[k] * spread[k]
            elif nest[p, j, k] == 2:
                s = s + weights[p, k] * spread[k]
        bound[j] = s if s < weights[p, j] else weights[p, j]
    reach = 0.0
    for j in range(n):
        if weights[p, j] != 0.0:
            reach = reach + bound[j] * spread[j]
    return reach


@numba.njit(cache=True, nogil=True)
def pairs_reach(
    weights: np.ndarray,
    speeds: np.ndarray,
    spread: np.ndarray,
    order: np.ndarray,
    nest: np.ndarray,
    out: np.ndarray,
) -> np.ndarray:
    """:func:`pair_reach` of every pair (arguments as there), written to ``out`` (pairs,) m and
    returned: the numpy path's local bound (the envelope's ``_reach``,
    :mod:`sim2real.deploy.safety.envelope_query`),
    the compiled :func:`sim2real.deploy.safety.local_reach.local_reach`."""
    bound = np.empty(spread.shape[0])
    for p in range(out.shape[0]):
        out[p] = pair_reach(p, weights, speeds, spread, order, nest, bound)
    return out


@numba.njit(cache=True, nogil=True, _nrt=False)
def envelope_screen(
    q: np.ndarray,
    before: np.ndarray,
    after: np.ndarray,
    stopping: np.ndarray,
    limits: np.ndarray,
    effort_scale: np.ndarray,
    cached_q: np.ndarray,
    clearance: np.ndarray,
    weights: np.ndarray,
    margin: float,
    box: np.ndarray,
    need: np.ndarray,
    joint: np.ndarray,
    grid: np.ndarray,
    cells: np.ndarray,
    offset: np.ndarray,
    values: np.ndarray,
    speeds: np.ndarray,
    order: np.ndarray,
    nest: np.ndarray,
    slack: np.ndarray,
    lead: np.ndarray,
    scratch: np.ndarray,
) -> bool:
    """The box of every env not ``stopping`` ((envs,) bool), and whether the cache certifies it
    (``scratch`` (2, n): work; the kernel allocates nothing).

    The box (module docstring): ``q`` (envs, n) estimated positions (rad); ``before`` and
    ``after`` (3, envs, n) the smoother's position, velocity and acceleration before and after
    the step. ``limits`` (4, n): the smoother's acceleration and jerk limits, the worst gravity
    load's share of each effort limit and the smallest brake headroom assumed. The brake
    decelerates at the acceleration limit times :func:`brake_headroom` of ``effort_scale``
    (envs, n), the thermal derating. Writes ``box`` (5, envs, n): centre, half-width, the
    brake's rest point, that headroom and how far the joint may stray from the path: the brake's
    reversal past rest (``back`` of :func:`brake_reach`, as a distance) plus ``slack`` (envs, n)
    rad, the drive's own (0 for a position servo; a velocity drive's sag, friction and command
    period, :meth:`sim2real.deploy.safety.drive.VelocityDrive.motion`), by which the box is widened on each
    side; the box also holds the rest point moved by ``lead`` (envs, n) rad, signed (a velocity
    drive running ahead of its braking integrator, the same method).

    The screen marks ``need[row, e]`` (rows ``COLLISION``, ``WORKSPACE``) where the cache cannot
    certify the box: ``cached_q`` (2, envs, n) rad the configurations of the last exact queries
    (rows as ``need``), ``clearance`` (envs, pairs + 3) m the pair distances there and, last,
    the end effector's margins inside the workspace box along x, y, z (``inf`` without a box),
    ``weights`` (pairs + 3, n) m/rad the pairs' approach bounds and the end effector's levers
    along x, y, z. A quantity can shrink by at most ``weights @ (|centre - cached| + half)``
    anywhere in the box, a pair's distance by at most :func:`pair_reach` of that spread
    (``speeds`` (envs, pairs, n) m/rad the speeds at the cached configuration,
    :meth:`sim2real.deploy.safety.local_reach.LocalReach.speeds`; ``order``, ``nest``
    :func:`sim2real.robots.chain_bounds.collision_pair_nesting`); a pair's distance also stays above its
    table's bound over the box (:func:`table_bound`; ``joint`` to ``values`` the arrays of
    :class:`sim2real.deploy.safety.pair_grid.PairTables`), whichever is higher. Returns whether any env
    needs an exact query.
    """
    envs, n = q.shape
    rows = weights.shape[0]
    pairs = rows - 3
    any_need = False
    spread, bound = scratch[0], scratch[1]
    for e in range(envs):
        need[COLLISION, e] = False
        need[WORKSPACE, e] = False
        if stopping[e]:
            continue
        for i in range(n):
            share = brake_headroom(effort_scale[e, i], limits[2, i], limits[3, i])
            forward, back = brake_reach(
                after[1, e, i], after[2, e, i], limits[0, i] * share, limits[1, i]
            )
            p0, p = before[0, e, i], after[0, e, i]
            box[2, e, i] = p + forward
            box[3, e, i] = share
            box[4, e, i] = abs(back) + slack[e, i] + abs(lead[e, i])
            ahead = p + forward + lead[e, i]
            lo = min(q[e, i], p0, p, p + forward, p + back, ahead) - slack[e, i]
            hi = max(q[e, i], p0, p, p + forward, p + back, ahead) + slack[e, i]
            box[0, e, i] = 0.5 * (lo + hi)
            box[1, e, i] = 0.5 * (hi - lo)
        for r in range(rows):
            row = WORKSPACE if r >= pairs else COLLISION
            if need[row, e]:
                continue
            reach = 0.0
            if r < pairs:
                for i in range(n):
                    spread[i] = abs(box[0, e, i] - cached_q[row, e, i]) + box[1, e, i]
                reach = pair_reach(r, weights, speeds[e], spread, order, nest, bound)
            else:
                for i in range(n):
                    if weights[r, i] != 0.0:
                        d = abs(box[0, e, i] - cached_q[row, e, i]) + box[1, e, i]
                        reach += weights[r, i] * d
            if not (clearance[e, r] - reach > margin):  # NaN-safe: unknown means check
                if (
                    r < pairs
                    and table_bound(
                        r, box[0, e], box[1, e], weights[r], joint, grid, cells, offset, values
                    )
                    > margin
                ):
                    continue
                need[row, e] = True
                any_need = True
    return any_need


class ScreenArrays(NamedTuple):
    """The motion envelope's arrays of :func:`envelope_screen`, its arguments from ``limits`` on
    (shapes and units there), made once and updated in place."""

    limits: np.ndarray
    cached_q: np.ndarray
    clearance: np.ndarray
    weights: np.ndarray
    margin: float
    box: np.ndarray
    need: np.ndarray
    joint: np.ndarray
    grid: np.ndarray
    cells: np.ndarray
    offset: np.ndarray
    values: np.ndarray
    speeds: np.ndarray
    order: np.ndarray
    nest: np.ndarray
    slack: np.ndarray
    lead: np.ndarray
    scratch: np.ndarray


class DriveArrays(NamedTuple):
    """A velocity drive's arrays of :func:`sim2real.deploy.safety.drive_kernel.velocity_drive_motion`
    and :func:`~sim2real.deploy.safety.drive_kernel.integrate` (shapes and units there), and
    ``path`` (2, 3, envs, n): the smoother's state before and after its step with the drives'
    equilibrium as the position (:meth:`sim2real.deploy.safety.envelope.MotionEnvelope.check`)."""

    setpoint: np.ndarray
    gravity: np.ndarray
    mass: np.ndarray
    joint: np.ndarray
    variance: np.ndarray
    uncertainty: np.ndarray
    dt: float
    lower: np.ndarray
    upper: np.ndarray
    path: np.ndarray
    beyond: np.ndarray


@numba.njit(cache=True, nogil=True, _nrt=False)
def certify(q, dq, before, after, stopping, effort_scale, command, s, d) -> int:
    """One tick of :meth:`sim2real.deploy.safety.envelope.MotionEnvelope.certify` in one call: with
    a velocity drive (``d`` its :class:`DriveArrays`, gravity and mass matrix at ``q`` already
    computed; None for a position servo, a specialization without the drive's code) the drive's
    motion (``d.path``, ``s.slack``, ``s.lead``, ``d.beyond``), then :func:`envelope_screen`
    (``s`` its :class:`ScreenArrays`) of that motion or, without a drive, of the smoother's
    ``before`` and ``after`` (3, envs, n). Returns
    the bits :data:`UNCERTAIN` and :data:`BEYOND`; when neither is set the motion is certified
    and the drive's integrators take ``command`` (envs, n) rad/s (the envelope's commit).
    ``q``, ``dq`` (envs, n) the estimate; ``stopping`` (envs,) bool; ``effort_scale`` (envs, n).

    It calls the kernels of :mod:`sim2real.deploy.safety.drive_kernel`; an edit to those
    recompiles it (:mod:`sim2real.numba_cache`)."""
    code = 0
    start, end = before, after
    if d is not None:  # numba prunes the branch for d None
        path = d.path
        for r in range(3):
            for e in range(q.shape[0]):
                for i in range(q.shape[1]):
                    path[0, r, e, i] = before[r, e, i]
                    path[1, r, e, i] = after[r, e, i]
        if dk.velocity_drive_motion(
            d.setpoint, q, dq, after[1], after[2], d.gravity, d.mass, effort_scale, d.joint,
            s.limits, d.variance, d.uncertainty, d.dt, path[0, 0], path[1, 0], s.slack, s.lead,
            d.beyond, stopping,
        ):  # fmt: skip
            code |= BEYOND
        start, end = path[0], path[1]
    if envelope_screen(
        q, start, end, stopping, s.limits, effort_scale, s.cached_q, s.clearance, s.weights,
        s.margin, s.box, s.need, s.joint, s.grid, s.cells, s.offset, s.values, s.speeds,
        s.order, s.nest, s.slack, s.lead, s.scratch,
    ):  # fmt: skip
        code |= UNCERTAIN
    if d is not None and code == 0:
        dk.integrate(d.setpoint, command, d.dt, d.lower, d.upper)
    return code


def warm_up() -> None:
    """Compile (or load numba's cache of) the kernel on small arrays, outside any tick."""
    z = np.zeros((1, 2))
    z3 = np.zeros((3, 1, 2))
    tables = (  # read-only, as the envelope's tables are (a specialization of their own)
        np.full((1, 2), -1, dtype=np.int64), np.ones((1, 2, 3)), np.ones((1, 2), dtype=np.int64),
        np.full((1, 1), -1, dtype=np.int64), np.zeros(0),  # no pair table
    )  # fmt: skip
    for table in tables:
        table.flags.writeable = False
    envelope_screen(
        z, z3, z3, np.zeros(1, dtype=bool), np.ones((4, 2)), np.ones((1, 2)),
        np.zeros((2, 1, 2)), np.full((1, 4), math.inf), np.zeros((4, 2)), 0.0,
        np.zeros((5, 1, 2)), np.zeros((2, 1), dtype=bool), *tables,
        np.zeros((1, 1, 2)), np.arange(2), np.zeros((1, 2, 2), dtype=np.int8), np.zeros((1, 2)),
        np.zeros((1, 2)), np.zeros((2, 2)),
    )  # fmt: skip
    pairs_reach(np.zeros((1, 2)), np.zeros((1, 2)), np.zeros(2), np.arange(2),
                np.zeros((1, 2, 2), dtype=np.int8), np.zeros(1))  # fmt: skip
