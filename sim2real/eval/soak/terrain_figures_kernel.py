"""The compiled arithmetic of :meth:`sim2real.eval.soak.terrain_figures.TerrainFigures.step`: one
tick of every env's terrain figures in one call (numpy's dozens of small operations cost many
times more: docs/measurements.md).

The place of a point is :func:`sim2real.eval.world.tile_parts.place`'s: its nearest sample
(``rint``, half to even, as numpy's), the tile by floor division, the platform by the env's mask.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def account(
    truth, running, falls, platform, origins, spacing, n, rows, cols, dt, sums, crossings,
    falls_on, falls_seen, anchor_tile, anchor_platform, fell_tile, fell_part,
):  # fmt: skip
    """One tick (module docstring). ``truth`` (envs, >= 9): the true base's world x, y (m) at
    columns 0, 1 and its world planar velocity (m/s) at 7, 8; ``running`` (envs,) bool;
    ``falls`` (envs,) int64 the tracker's counts; ``platform`` (envs, n, n) bool; ``origins``
    (envs, 2) m, each env's first tile's first sample; ``rows x cols`` tiles; ``sums``
    (envs, 4): s on the platform, the feature, off the tiles, and m on the feature;
    ``crossings`` (envs, 2) int64 out, in; ``falls_on`` (envs, 3) int64 by part;
    ``falls_seen``, ``anchor_tile`` (envs,) int64; ``anchor_platform`` (envs,) bool; ``fell_tile``,
    ``fell_part`` (envs,) int64 written for the envs that fell this tick (``fell_part`` -1 for
    the others). Returns whether any env fell."""
    side0, side1 = rows * n, cols * n
    any_fell = False
    for e in range(truth.shape[0]):
        u0 = int(np.rint((truth[e, 0] - origins[e, 0]) / spacing))
        u1 = int(np.rint((truth[e, 1] - origins[e, 1]) / spacing))
        tile = -1
        on = False
        if 0 <= u0 < side0 and 0 <= u1 < side1:
            t0, t1 = u0 // n, u1 // n
            tile = t0 * cols + t1
            on = platform[e, u0 - t0 * n, u1 - t1 * n]
        part = 2 if tile < 0 else (0 if on else 1)
        walking = running[e]
        if walking:
            sums[e, part] += dt
            if part == 1:
                v0, v1 = truth[e, 7], truth[e, 8]
                sums[e, 3] += math.sqrt(v0 * v0 + v1 * v1) * dt
        if tile != anchor_tile[e]:  # the anchor's tile left, over its rim
            if anchor_platform[e] and walking:
                crossings[e, 0] += 1
            anchor_tile[e] = tile
            anchor_platform[e] = False
        if on and not anchor_platform[e]:
            if walking:
                crossings[e, 1] += 1
            anchor_platform[e] = True
        fell_part[e] = -1
        if falls[e] > falls_seen[e]:
            falls_on[e, part] += falls[e] - falls_seen[e]
            falls_seen[e] = falls[e]
            fell_tile[e], fell_part[e] = tile, part
            any_fell = True
    return any_fell
