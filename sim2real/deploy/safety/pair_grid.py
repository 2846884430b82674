"""Grids of the joints that move a collision pair: which pairs never touch
(:func:`pairs_kept_apart`) and, for the others, a table of lower bounds of their distance over
boxes of those joints (:class:`PairTables`, looked up by :func:`table_bound`).

A pair's distance depends only on the joints its approach bound moves (``pair_weights[p] > 0``,
:func:`sim2real.robots.chain_bounds.collision_pair_weights`). With few of them, their range box is gridded;
every configuration of a grid cell lies within half a grid step ``s_j / 2`` of one of the cell's
corners, so the distance anywhere in the cell stays above the least distance at its corners minus
``sum_j w_pj s_j / 2``. A configuration past the grid is within ``|q_j - clip(q_j)|`` of one in
it, which costs ``sum_j w_pj |q_j - clip(q_j)|`` more. Cells are pooled by twos into coarser
levels, so that a lookup reads at most ``LOOKUP_CELLS`` cells per joint
(:mod:`sim2real.deploy.safety.envelope_kernel`). The motion envelope looks a box up here (the numpy
reference) and in its compiled screen (:func:`sim2real.deploy.safety.envelope_kernel.table_bound`): the
same arithmetic in the same order.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from sim2real.deploy.safety.envelope_kernel import INDEX_SLACK, LOOKUP_CELLS
from sim2real.robots import Robot

#: Most joints between the two links of a pair for :func:`pairs_kept_apart` to try a proof (a
#: grid of every joint between them: ``GRID_POINTS[-1] ** MAX_PROOF_JOINTS`` queries at most).
MAX_PROOF_JOINTS = 2
#: Points per joint of the successive grids of :func:`pairs_kept_apart` (each refines the last).
GRID_POINTS = (33, 65, 129, 257)
#: Joints a table spans (a pair moved by one joint has one cell across the second).
TABLE_AXES = 2
#: Fewest points per joint of a table's grid: a pair a grid finds in contact is gridded once more
#: with the first of :data:`GRID_POINTS` that has as many (our choice: a fraction of a degree per
#: cell at a cost of ``TABLE_POINTS ** 2`` queries).
TABLE_POINTS = 129
#: Robots' grids kept in memory (:func:`pair_grids`).
CACHED_ROBOTS = 8


@dataclass(frozen=True)
class PairTables:
    """Lower-bound tables of the pairs' distances, as the compiled screen reads them.

    Attributes:
        joint: (pairs, TABLE_AXES) int64, the joint of each axis (-1: none).
        grid: (pairs, TABLE_AXES, 3) float64, rad: each axis' first and last grid point and step.
        cells: (pairs, TABLE_AXES) int64, cells along each axis at the finest level (1 on an
            unused axis).
        offset: (pairs, levels) int64, where each level's cells start in ``values`` (row-major,
            ``ceil(cells / 2**level)`` per axis); -1: no table (or no such level).
        values: (total,) float64, m, each cell's lower bound of the pair's distance.
    """

    joint: np.ndarray
    grid: np.ndarray
    cells: np.ndarray
    offset: np.ndarray
    values: np.ndarray

    @classmethod
    def empty(cls, pairs: int) -> PairTables:
        """No table for any of ``pairs`` pairs."""
        return cls(
            np.full((pairs, TABLE_AXES), -1, dtype=np.int64),
            np.ones((pairs, TABLE_AXES, 3)),
            np.ones((pairs, TABLE_AXES), dtype=np.int64),
            np.full((pairs, 1), -1, dtype=np.int64),
            np.zeros(0),
        )

    def arrays(self) -> tuple[np.ndarray, ...]:
        """``(joint, grid, cells, offset, values)``, the order of
        :func:`sim2real.deploy.safety.envelope_kernel.envelope_screen`."""
        return self.joint, self.grid, self.cells, self.offset, self.values


def _grid_distances(robot, geometry, p: int, joints: np.ndarray, points: int) -> np.ndarray:
    """(points,) * len(joints) m, pair ``p``'s distance on the grid of ``joints`` over their
    position range (the other joints at home)."""
    geom_model, geom_data = geometry
    model = robot.fixed_base_model
    data = model.createData()
    lower, upper = np.asarray(robot.position_lower), np.asarray(robot.position_upper)
    axes = [np.linspace(lower[j], upper[j], points) for j in joints]
    q = np.asarray(robot.home, dtype=np.float64).copy()
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(joints))
    out = np.empty(len(grid))
    for k, values in enumerate(grid):
        q[joints] = values
        pin.updateGeometryPlacements(model, data, geom_model, geom_data, q)
        out[k] = pin.computeDistance(geom_model, geom_data, p).min_distance
    return out.reshape((points,) * len(joints))


def _levels(cell: np.ndarray) -> list[np.ndarray]:
    """The cells' lower bounds (2-D) pooled by twos (min; an odd last cell alone, an axis of one
    cell kept) level after level until one cell is left."""
    levels = [cell]
    while max(levels[-1].shape) > 1:
        a = levels[-1]
        for axis in range(a.ndim):
            if a.shape[axis] > 1:
                a = np.moveaxis(a, axis, 0)
                if a.shape[0] % 2:
                    a = np.concatenate([a, np.full_like(a[:1], np.inf)])
                a = np.moveaxis(np.minimum(a[0::2], a[1::2]), 0, axis)
        levels.append(a)
    return levels


def _tables(robot, built: dict, pair_weights: np.ndarray) -> PairTables:
    """:class:`PairTables` of the grids ``built`` (pair -> (joints, points, distances))."""
    pairs = len(pair_weights)
    lower, upper = np.asarray(robot.position_lower), np.asarray(robot.position_upper)
    per_pair = {}
    for p, (joints, points, dist) in built.items():
        step = (upper[joints] - lower[joints]) / (points - 1)
        d = dist.reshape(dist.shape + (1,) * (TABLE_AXES - dist.ndim))
        corner = d
        for axis in range(dist.ndim):  # the least distance at each cell's corners
            a, b = np.swapaxes(corner, 0, axis)[:-1], np.swapaxes(corner, 0, axis)[1:]
            corner = np.swapaxes(np.minimum(a, b), 0, axis)
        per_pair[p] = (joints, step, _levels(corner - pair_weights[p][joints] @ (0.5 * step)))
    depth = max([len(v[2]) for v in per_pair.values()], default=1)
    t = PairTables.empty(pairs)
    offset = np.full((pairs, depth), -1, dtype=np.int64)
    chunks, start = [], 0
    for p, (joints, step, levels) in per_pair.items():
        for k, j in enumerate(joints):
            t.joint[p, k] = j
            t.grid[p, k] = lower[j], upper[j], step[k]
        t.cells[p] = levels[0].shape
        for level, cells in enumerate(levels):
            offset[p, level] = start
            chunks.append(cells.ravel())
            start += cells.size
    values = np.concatenate(chunks) if chunks else np.zeros(0)
    return PairTables(t.joint, t.grid, t.cells, offset, values)


_CACHE: OrderedDict = OrderedDict()


def pair_grids(robot: Robot, geometry, pair_weights: np.ndarray) -> tuple[np.ndarray, PairTables]:
    """Which listed collision pairs the joints between their two links cannot bring into contact
    anywhere within the position limits (MoveIt's "never in collision" pairs, here proved rather
    than sampled), and lower-bound tables of the others (:class:`PairTables`), from one pass of
    grids.

    A pair moved by at most :data:`MAX_PROOF_JOINTS` joints is gridded (:data:`GRID_POINTS` per
    joint, finer until decided) and kept apart when the grid's least distance minus ``sum_j w_pj
    s_j / 2`` is above zero; a grid that finds it in contact ends the proof. A pair not kept
    apart and moved by at most :data:`TABLE_AXES` joints gets a table of its last grid (for a
    pair found in contact, the grid of :data:`TABLE_POINTS` the contact skips to). Kept in memory
    per robot description hash, limits, home and ``pair_weights`` (the last
    :data:`CACHED_ROBOTS`).

    Args:
        robot: The robot (position limits, home pose).
        geometry: ``(geom_model, geom_data)`` of
            :func:`sim2real.deploy.safety.collision.collision_model` (its data is used).
        pair_weights: (pairs, n) m/rad, :func:`sim2real.robots.chain_bounds.collision_pair_weights`.

    Returns:
        ``(apart, tables)``: (pairs,) bool (a copy) and :class:`PairTables` (read-only).
    """
    weights_all = np.asarray(pair_weights, dtype=np.float64)
    key = (
        robot.description_hash,
        *(np.asarray(a, dtype=np.float64).tobytes()
          for a in (robot.position_lower, robot.position_upper, robot.home, weights_all)),
    )  # fmt: skip
    if key in _CACHE:
        _CACHE.move_to_end(key)
        apart, tables = _CACHE[key]
        return apart.copy(), tables
    lower, upper = np.asarray(robot.position_lower), np.asarray(robot.position_upper)
    apart = np.zeros(len(weights_all), dtype=bool)
    built = {}
    for p, weights in enumerate(weights_all):
        joints = np.flatnonzero(weights > 0.0)
        if not 0 < len(joints) <= max(MAX_PROOF_JOINTS, TABLE_AXES):
            continue
        touched = len(joints) > MAX_PROOF_JOINTS  # no proof tried: only the table
        for points in GRID_POINTS:
            if touched and points < TABLE_POINTS:
                continue
            dist = _grid_distances(robot, geometry, p, joints, points)
            least = dist.min()
            touched = touched or bool(least <= 0.0)
            step = (upper[joints] - lower[joints]) / (points - 1)
            if not touched and least - weights[joints] @ (0.5 * step) > 0.0:
                apart[p] = True
                break
            if touched and points >= TABLE_POINTS:
                break
        if not apart[p] and len(joints) <= TABLE_AXES:
            built[p] = (joints, points, dist)
    tables = _tables(robot, built, weights_all)
    for a in (tables.joint, tables.grid, tables.cells, tables.offset, tables.values):
        a.flags.writeable = False
    _CACHE[key] = (apart, tables)
    while len(_CACHE) > CACHED_ROBOTS:
        _CACHE.popitem(last=False)
    return apart.copy(), tables


def pairs_kept_apart(robot: Robot, geometry, pair_weights: np.ndarray) -> np.ndarray:
    """(pairs,) bool, the pairs :func:`pair_grids` proves never touch within the position
    limits (same arguments)."""
    return pair_grids(robot, geometry, pair_weights)[0]


def table_bound(
    tables: PairTables, p: int, centre: np.ndarray, half: np.ndarray, weights: np.ndarray
) -> float:
    """m, a lower bound of pair ``p``'s distance over the box ``centre +- half`` (n,) rad from
    its table (``-inf`` without one, or for a NaN box): the least cell bound the box covers (at
    the finest level that reads at most ``LOOKUP_CELLS`` cells per joint), minus ``weights @
    overshoot`` (``weights`` (n,) m/rad, the pair's approach bound) where the box reaches past
    the grid. The numpy reference of :func:`sim2real.deploy.safety.envelope_kernel.table_bound`."""
    if tables.offset[p, 0] < 0:
        return -math.inf
    first = [0] * TABLE_AXES
    last = [0] * TABLE_AXES
    overshoot = 0.0
    for k in range(TABLE_AXES):
        j = tables.joint[p, k]
        if j < 0:
            continue
        lo, hi = centre[j] - half[j], centre[j] + half[j]
        if not lo <= hi:
            return -math.inf
        g_lo, g_hi, step = tables.grid[p, k]
        overshoot += weights[j] * max(g_lo - lo, hi - g_hi, 0.0)
        lo, hi = min(max(lo, g_lo), g_hi), min(max(hi, g_lo), g_hi)
        first[k] = min(
            max(math.floor((lo - g_lo) / step - INDEX_SLACK), 0), int(tables.cells[p, k]) - 1
        )
        last[k] = min(math.floor((hi - g_lo) / step + INDEX_SLACK), int(tables.cells[p, k]) - 1)
    level = 0
    while any((last[k] >> level) - (first[k] >> level) + 1 > LOOKUP_CELLS
              for k in range(TABLE_AXES)):  # fmt: skip
        level += 1
    size = [-(-int(tables.cells[p, k]) // (1 << level)) for k in range(TABLE_AXES)]
    start = tables.offset[p, level]
    cells = tables.values[start : start + size[0] * size[1]].reshape(size)
    box = cells[
        first[0] >> level : (last[0] >> level) + 1, first[1] >> level : (last[1] >> level) + 1
    ]
    return float(box.min()) - overshoot
