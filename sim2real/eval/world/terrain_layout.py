"""Where a session's terrain tiles lie (:mod:`sim2real.eval.world.terrain`): a tile's side in
samples, the session's rows and columns of tiles, the tile the robot starts on and each row's
difficulty, for a ``grid`` walk (``tiles x tiles`` tiles of one kind and level) and a
``curriculum`` walk (its kind's column of legged_gym's map, one tile per level along x:
:mod:`sim2real.eval.soak.curriculum_walk`). Shared by the ground's builder
(:func:`~sim2real.eval.world.terrain.ground_map`) and the tiles' parts
(:mod:`sim2real.eval.world.tile_parts`). ``ranges`` is a
:class:`~sim2real.eval.world.terrain.TerrainRanges`, ``draw`` a
:class:`~sim2real.eval.world.terrain.TerrainDraw` (not imported: terrain imports this module).
"""

from __future__ import annotations


def tile_grid(ranges) -> tuple[int, int, int]:
    """``(n, border, start)`` in samples of ``horizontal_scale``: a tile's side (legged_gym's
    ``int(terrain_width / horizontal_scale)``), the flat border's width, and the start's index
    (the middle tile's centre) along either axis of a ``grid`` walk's ground
    (:class:`~sim2real.eval.world.terrain.GroundMap`; along y of a curriculum walk's)."""
    n = int(ranges.terrain_width / ranges.horizontal_scale)
    border = int(ranges.border_size / ranges.horizontal_scale)
    return n, border, border + (ranges.tiles // 2) * n + n // 2


def tile_counts(ranges) -> tuple[int, int]:
    """``(rows, cols)``: the session's tiles along x and y (``tiles x tiles``; a curriculum
    walk's column: ``num_rows x tiles``, row ``i`` level ``i``)."""
    return (ranges.num_rows if ranges.walk == "curriculum" else ranges.tiles), ranges.tiles


def start_tile(draw) -> tuple[int, int]:
    """``(row, col)``: the tile the session's robot starts on (the world origin at its centre):
    the middle one, or on a curriculum walk its level's (legged_gym's ``env_origins[level,
    type]``, ``_get_env_origins``) in the middle column."""
    r = draw.ranges
    if r.walk == "curriculum":
        return int(draw.level), r.tiles // 2
    return r.tiles // 2, r.tiles // 2


def tile_difficulty(draw, row: int) -> float:
    """The difficulty of row ``row``'s tiles: the draw's, or on a curriculum walk legged_gym's
    ``i / num_rows`` (``Terrain.curiculum``)."""
    r = draw.ranges
    return row / r.num_rows if r.walk == "curriculum" else draw.difficulty
