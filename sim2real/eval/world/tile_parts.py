"""Where on its tiles a session's robot is: the tile and the part of it (platform, feature, off).

legged_gym's tiles (:mod:`sim2real.eval.world.terrain_tiles`) put the robot on a flat platform at the
centre of a tile; the tile's feature surrounds it out to the tile's rim: the steps of a stairs
tile, the slope of a smooth or rough slope, the obstacle field of a discrete one. A
:class:`TileLayout` answers, for world points ``(x, y)`` (m), which of the session's
``rows x cols`` tiles they are on (its index ``i * cols + j``; -1 off the tiles, on the flat
border around them) and whether on its platform (:func:`~sim2real.eval.world.tile_generators.
platform_mask`, the generator's own region) or its feature. A point belongs to its nearest
sample of the ground's grid (a stepped ground's box top about it; a height field's vertex).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.eval.world.terrain import TerrainDraw
from sim2real.eval.world.terrain_layout import start_tile, tile_counts, tile_grid
from sim2real.eval.world.tile_generators import platform_mask, tile_generator

#: The parts of a tile a point can be on: its central platform, its feature, or off the tiles.
PARTS = ("platform", "feature", "off")


@dataclass(frozen=True, eq=False)
class TileLayout:
    """The tiles of a session's ground (module docstring).

    Attributes:
        kind: The tiles' kind (:data:`~sim2real.eval.world.tile_generators.TILE_GENERATORS`).
        origin: m, the world ``(x, y)`` of the first tile's first sample.
        spacing: m between samples (``horizontal_scale``).
        n: Samples along a tile's side.
        rows, cols: The grid is ``rows x cols`` tiles (rows along x; a curriculum walk's rows
            are its levels).
        start: ``(row, col)`` of the tile the robot starts on.
        platform: (n, n) bool, the platform's samples of a tile (all tiles alike).
    """

    kind: str
    origin: tuple[float, float]
    spacing: float
    n: int
    rows: int
    cols: int
    start: tuple[int, int]
    platform: np.ndarray

    @classmethod
    def of(cls, draw: TerrainDraw) -> TileLayout:
        """The layout of ``draw``'s ground (:func:`sim2real.eval.world.terrain.ground_map`'s: the
        start, the world origin, at its start tile's centre)."""
        r = draw.ranges
        n, border, _ = tile_grid(r)
        hs = r.horizontal_scale
        rows, cols = tile_counts(r)
        i0, j0 = start_tile(draw)
        origin = (-(i0 * n + n // 2) * hs, -(j0 * n + n // 2) * hs)
        return cls(draw.kind, origin, hs, n, rows, cols, (i0, j0), platform_mask(draw.kind, n, hs))

    @property
    def grid(self) -> tuple[float, int, int, int]:
        """``(spacing, n, rows, cols)``: what layouts of one batch share."""
        return self.spacing, self.n, self.rows, self.cols

    @property
    def start_tile(self) -> int:
        """The index of the start tile (``row * cols + col``)."""
        return self.start[0] * self.cols + self.start[1]

    @property
    def feature(self) -> str:
        """The feature's noun (``steps``, ``slope``, ...: its generator's ``feature``)."""
        return tile_generator(self.kind).feature

    def centre(self, row: int, col: int) -> np.ndarray:
        """(2,) m, the world ``(x, y)`` of tile ``(row, col)``'s centre sample (legged_gym's
        ``env_origins[row, col]``: the tile's centre)."""
        return np.array(self.origin) + self.spacing * (np.array([row, col]) * self.n + self.n // 2)

    def samples(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) int64, the nearest sample of world points ``xy`` (..., 2) m, counted from
        the first tile's first."""
        return np.rint((np.asarray(xy, float) - self.origin) / self.spacing).astype(np.int64)

    def locate(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(tile, on_platform)`` of world points ``xy`` (..., 2) m: the tile's index
        (``row * cols + col``, rows along x; -1 off the tiles) and whether on its platform
        (:func:`place`)."""
        xy = np.asarray(xy, float)
        which = np.zeros(xy.shape[:-1], dtype=np.int64)
        return place(xy, self, self.platform[None], which, np.array([self.origin]))

    def offset(self, tile: int) -> list[int] | None:
        """``[di, dj]``: tile ``tile``'s place from the start tile (along x, along y); None off
        the tiles."""
        if tile < 0:
            return None
        return [tile // self.cols - self.start[0], tile % self.cols - self.start[1]]


def place(
    xy: np.ndarray,
    grid: TileLayout,
    platforms: np.ndarray,
    which: np.ndarray,
    origins: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``(tile, on_platform)`` of world points ``xy`` (..., 2) m on tiles of ``grid``'s
    ``spacing``, ``n``, ``rows`` and ``cols``, point ``p`` judged on env ``which[p]``'s tiles:
    their first sample at ``origins[which[p]]`` ((m, 2) m), platform mask
    ``platforms[which[p]]`` (``platforms`` (m, n, n) bool: a batch's envs, each its own kind)."""
    u = np.rint((xy - origins[which]) / grid.spacing).astype(np.int64)
    size = np.array([grid.rows, grid.cols]) * grid.n
    inside = ((u >= 0) & (u < size)).all(axis=-1)
    t = u // grid.n
    local = np.clip(u - t * grid.n, 0, grid.n - 1)
    tile = np.where(inside, t[..., 0] * grid.cols + t[..., 1], -1)
    return tile, inside & platforms[which, local[..., 0], local[..., 1]]
