"""Where on its tiles a session's robot is: the tile and the part of it (platform, feature, off).

legged_gym's tiles (:mod:`sim2real.eval.world.terrain_tiles`) put the robot on a flat platform at the
centre of a tile; the tile's feature surrounds it out to the tile's rim: the steps of a stairs
tile, the slope of a smooth or rough slope, the obstacle field of a discrete one. A
:class:`TileLayout` answers, for world points ``(x, y)`` (m), which of the session's
``tiles x tiles`` tiles they are on (its index ``i * tiles + j``; -1 off the tiles, on the flat
border around them) and whether on its platform (:func:`~sim2real.eval.world.terrain_tiles.
platform_mask`, the generator's own region) or its feature. A point belongs to its nearest
sample of the ground's grid (a stepped ground's box top about it; a height field's vertex).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.eval.world.terrain import TerrainDraw, tile_grid
from sim2real.eval.world.terrain_tiles import platform_mask

#: The parts of a tile a point can be on: its central platform, its feature, or off the tiles.
PARTS = ("platform", "feature", "off")
#: What the feature of each kind is, for the report's words.
FEATURE_NOUNS = {
    "stairs_up": "steps", "stairs_down": "steps", "slope_up": "slope", "slope_down": "slope",
    "rough_slope": "rough slope", "discrete": "obstacles",
}  # fmt: skip


@dataclass(frozen=True, eq=False)
class TileLayout:
    """The tiles of a session's ground (module docstring).

    Attributes:
        kind: The tiles' kind (:data:`~sim2real.eval.world.terrain_tiles.KINDS`).
        origin: m, the world x (and y) of the first tile's first sample.
        spacing: m between samples (``horizontal_scale``).
        n: Samples along a tile's side. tiles: The grid is ``tiles x tiles``.
        platform: (n, n) bool, the platform's samples of a tile (all tiles alike).
    """

    kind: str
    origin: float
    spacing: float
    n: int
    tiles: int
    platform: np.ndarray

    @classmethod
    def of(cls, draw: TerrainDraw) -> TileLayout:
        """The layout of ``draw``'s ground (:func:`sim2real.eval.world.terrain.ground_map`'s: the
        start, the world origin, at the middle tile's centre)."""
        r = draw.ranges
        n, border, start = tile_grid(r)
        hs = r.horizontal_scale
        return cls(
            draw.kind, (border - start) * hs, hs, n, r.tiles, platform_mask(draw.kind, n, hs)
        )

    @property
    def start_tile(self) -> int:
        """The index of the middle tile, the robot's start."""
        return (self.tiles // 2) * self.tiles + self.tiles // 2

    @property
    def feature(self) -> str:
        """The feature's noun (``steps``, ``slope``, ...: :data:`FEATURE_NOUNS`)."""
        return FEATURE_NOUNS[self.kind]

    def samples(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) int64, the nearest sample of world points ``xy`` (..., 2) m, counted from
        the first tile's first."""
        return np.rint((np.asarray(xy, float) - self.origin) / self.spacing).astype(np.int64)

    def locate(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(tile, on_platform)`` of world points ``xy`` (..., 2) m: the tile's index
        (``i * tiles + j``, i along x; -1 off the tiles) and whether on its platform
        (:func:`place`)."""
        xy = np.asarray(xy, float)
        mask = self.platform[None]
        return place(xy, self, mask, np.zeros(xy.shape[:-1], dtype=np.int64))

    def offset(self, tile: int) -> list[int] | None:
        """``[di, dj]``: tile ``tile``'s place from the start tile (along x, along y); None off
        the tiles."""
        if tile < 0:
            return None
        mid = self.tiles // 2
        return [tile // self.tiles - mid, tile % self.tiles - mid]


def place(
    xy: np.ndarray, grid: TileLayout, platforms: np.ndarray, which: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``(tile, on_platform)`` of world points ``xy`` (..., 2) m on ``grid``'s tiles (its
    ``origin``, ``spacing``, ``n``, ``tiles``), point ``p`` judged by platform mask
    ``platforms[which[p]]`` (``platforms`` (m, n, n) bool: a batch's envs, each its own kind)."""
    u = np.rint((xy - grid.origin) / grid.spacing).astype(np.int64)
    inside = ((u >= 0) & (u < grid.tiles * grid.n)).all(axis=-1)
    t = u // grid.n
    local = np.clip(u - t * grid.n, 0, grid.n - 1)
    tile = np.where(inside, t[..., 0] * grid.tiles + t[..., 1], -1)
    return tile, inside & platforms[which, local[..., 0], local[..., 1]]
