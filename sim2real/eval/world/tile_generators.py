"""The terrain tiles the soak builds, by kind (:data:`TILE_GENERATORS`): each a
:class:`TileGenerator` registered under its name with its builder, its platform, its feature's
noun and how a size is stated on a command line.

The ground (:func:`sim2real.eval.world.terrain.ground_map`) asks :func:`make_tile` for each tile of
a session's kind, the tiles' parts (:class:`sim2real.eval.world.tile_parts.TileLayout`) ask
:func:`platform_mask`, and ``--terrain KIND:SIZE`` (:func:`sim2real.eval.world.terrain.
parse_terrain`) asks the kind's ``difficulty``; no room names a kind. The built-in kinds are
legged_gym's (:mod:`sim2real.eval.world.terrain_tiles`: the geometry), which a ranges file's
``terrain_proportions`` draw by legged_gym's own rule
(:data:`sim2real.eval.world.terrain_tiles.KINDS`); a kind registered beside them is built when
stated (``--terrain KIND:SIZE`` or ``KIND@LEVEL``, a ``TerrainDraw`` of it).

To add a terrain kind: one module that calls :func:`register_tile_generator` with every part
(registration refuses one missing); ``tests/test_tile_generators.py`` builds a made-up one.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from sim2real.deploy.core.registry import Registry
from sim2real.eval.world import terrain_tiles as tiles


@dataclass(frozen=True)
class TileGenerator:
    """One kind of terrain tile (module docstring).

    Attributes:
        name: ``KIND`` of ``--terrain KIND:SIZE`` and of reports (``stairs_up@5``).
        build: ``build(hf, difficulty, hs, vs, rng)``: add the tile's relief to ``hf``
            ((n, n) int16 height units of ``vs`` m on ``hs`` m spacing; zero on entry) at
            ``difficulty`` in [0, 1), random parts from ``rng`` (in a fixed order: seeded tiles
            repeat).
        platform: ``platform(n, hs)``: (n, n) bool, the flat platform at the tile's centre where
            the robot starts; the rest is its feature.
        feature: The feature's noun, for the report (``steps``, ``slope``, ``obstacles``).
        size: ``size(difficulty)``: the text after ``KIND:`` that states a tile of it (its
            label, ``stairs_up:0.104``).
        difficulty: ``difficulty(text)``: the difficulty of ``KIND:text``. Raises ValueError for
            a malformed text.
        stepped: Its faces are vertical: a ``trimesh`` terrain lays it as boxes
            (:func:`sim2real.eval.world.terrain.add_ground`), a height field otherwise.
    """

    name: str
    build: Callable[..., None]
    platform: Callable[[int, float], np.ndarray]
    feature: str
    size: Callable[[float], str]
    difficulty: Callable[[str], float]
    stepped: bool = False


#: The tile kinds, by name (the built-in ones registered below).
TILE_GENERATORS: Registry[TileGenerator] = Registry("terrain kind")
#: The parts a generator must have (all but the flags).
PARTS = tuple(f.name for f in fields(TileGenerator) if f.name != "stepped")


def register_tile_generator(generator: TileGenerator) -> TileGenerator:
    """Register ``generator`` under its name; returns it.

    Raises:
        ValueError: a part missing (None or empty: named), or the name taken.
    """
    missing = [p for p in PARTS if not getattr(generator, p)]
    if missing:
        raise ValueError(
            f"terrain kind {generator.name!r}: expected every part of a tile generator, "
            f"missing {missing}"
        )
    return TILE_GENERATORS.register(generator.name, generator)


def tile_kinds() -> tuple[str, ...]:
    """The names of the kinds the soak builds, in registration order."""
    return TILE_GENERATORS.names()


def tile_generator(kind: str) -> TileGenerator:
    """The generator of ``kind``.

    Raises:
        ValueError: a kind the soak does not build (named, with the kinds it builds).
    """
    if kind not in TILE_GENERATORS.names():
        raise ValueError(
            f"terrain kind '{kind}' is not one the soak builds; expected one of {list(tile_kinds())}"
        )
    return TILE_GENERATORS.get(kind)


def make_tile(
    kind: str, difficulty: float, pixels: int, hs: float, vs: float, rng: np.random.Generator
) -> np.ndarray:
    """One ``(pixels, pixels)`` int16 tile of ``kind`` at ``difficulty``, random parts from
    ``rng`` (its generator's ``build``).

    Raises:
        ValueError: a kind the soak does not build (named, with the kinds it builds).
    """
    build = tile_generator(kind).build
    hf = np.zeros((pixels, pixels), dtype=np.int16)
    build(hf, difficulty, hs, vs, rng)
    return hf


def platform_mask(kind: str, pixels: int, hs: float) -> np.ndarray:
    """(pixels, pixels) bool: the samples of a ``kind`` tile's flat platform at its centre, where
    the robot starts; the rest is its feature (its generator's ``platform``).

    Raises:
        ValueError: a kind the soak does not build.
    """
    return tile_generator(kind).platform(pixels, hs)


def _step_size(difficulty: float) -> str:
    return f"{tiles.difficulty_terms(difficulty)['step_height']:.3g}"


def _slope_size(difficulty: float) -> str:
    return f"{math.degrees(math.atan(tiles.difficulty_terms(difficulty)['slope'])):.3g}deg"


def _step_difficulty(text: str) -> float:
    return (float(text) - 0.05) / 0.18


def _slope_difficulty(text: str) -> float:
    """A slope by its angle (``15deg``) or gradient (``0.27``)."""
    g = math.tan(math.radians(float(text[:-3]))) if text.endswith("deg") else float(text)
    return g / 0.4


def _obstacle_difficulty(text: str) -> float:
    return (float(text) - 0.05) / 0.1


for _generator in (
    TileGenerator(
        "slope_up", tiles.slope_tile(-1.0), tiles.slope_platform, "slope", _slope_size,
        _slope_difficulty
    ),
    TileGenerator(
        "slope_down", tiles.slope_tile(1.0), tiles.slope_platform, "slope", _slope_size,
        _slope_difficulty
    ),
    TileGenerator(
        "rough_slope", tiles.slope_tile(1.0, rough=True), tiles.slope_platform, "rough slope",
        _slope_size, _slope_difficulty
    ),
    TileGenerator(
        "stairs_up", tiles.stairs_tile(-1.0), tiles.stairs_platform, "steps", _step_size,
        _step_difficulty, stepped=True
    ),
    TileGenerator(
        "stairs_down", tiles.stairs_tile(1.0), tiles.stairs_platform, "steps", _step_size,
        _step_difficulty, stepped=True
    ),
    TileGenerator(
        "discrete", tiles.discrete_tile, tiles.square_platform, "obstacles",
        lambda d: f"{d:.3g}", _obstacle_difficulty, stepped=True
    ),
):  # fmt: skip
    register_tile_generator(_generator)
