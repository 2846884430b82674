"""legged_gym's terrain tiles as height grids, in numpy (no simulator): what its ``Terrain.make_terrain``
(legged_gym ``legged_gym/utils/terrain.py``, OpenRobotLab/HIMLoco's copy) draws for one tile of a kind
at a difficulty, through Isaac Gym's ``terrain_utils`` generators (pyramid slopes, random uniform
roughness, pyramid stairs, discrete obstacles), rewritten from their documented behaviour.

A tile is an ``(length, width)`` int16 grid of height units (``vertical_scale`` m each) on
``horizontal_scale`` m spacing; index 0 runs along world x, index 1 along y (Isaac Gym's layout).
By difficulty ``d`` in [0, 1) (legged_gym: row ``i`` of ``num_rows`` has ``d = i / num_rows``):
``slope = 0.4 d`` (rise over run), roughness amplitude ``0.01 + 0.07 d`` m, ``step_height = 0.05 +
0.18 d`` m (steps 0.30 m deep around a 3 m platform), discrete obstacles ``0.05 + 0.1 d`` m high.
The robot starts on the tile's central platform: ``stairs_up`` and ``slope_up`` are legged_gym's
pits (its negative step height and slope: the robot climbs out), ``stairs_down``, ``slope_down``
and ``rough_slope`` its pyramids (the robot walks down).

A length is turned into grid units as legged_gym does (``int(x / scale)``), after adding
``UNIT_EPSILON`` so that a height stated in metres (0.10 m at 0.005 m) is not one unit short by
floating-point rounding.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RegularGridInterpolator

#: The built-in tile kinds, each with the index of its share in legged_gym's
#: ``terrain_proportions`` ([smooth slope, rough slope, stairs up, stairs down, discrete]);
#: ``slope_up`` and ``slope_down`` split the smooth slopes' share in halves, as legged_gym does.
#: Each is registered with its builder (:mod:`sim2real.eval.world.tile_generators`).
KINDS = {
    "slope_up": 0, "slope_down": 0, "rough_slope": 1, "stairs_up": 2, "stairs_down": 3,
    "discrete": 4,
}  # fmt: skip
#: legged_gym's kinds past the fifth share of ``terrain_proportions``, which the soak does not
#: build (refused by name when their share is not 0).
UNBUILT_KINDS = ("stepping_stones", "gaps", "pits")
#: Added to a length over a scale before truncating it to grid units (module docstring).
UNIT_EPSILON = 1e-6
#: legged_gym ``make_terrain``'s constants: platform side (m), stair depth (m), roughness step
#: and its grid (m), the obstacles' count and sides (m).
PLATFORM = 3.0
STEP_WIDTH = 0.30
ROUGH_STEP, ROUGH_GRID = 0.005, 0.2
OBSTACLES, OBSTACLE_SIZES = 20, (1.0, 2.0)


def _units(x: float, scale: float) -> int:
    return int(x / scale + (UNIT_EPSILON if x >= 0 else -UNIT_EPSILON))


def difficulty_terms(difficulty: float) -> dict[str, float]:
    """legged_gym ``make_terrain``'s sizes at ``difficulty``: ``slope`` (rise over run),
    ``amplitude`` (m), ``step_height`` (m), ``obstacle_height`` (m)."""
    d = float(difficulty)
    return {
        "slope": 0.4 * d,
        "amplitude": 0.01 + 0.07 * d,
        "step_height": 0.05 + 0.18 * d,
        "obstacle_height": 0.05 + 0.1 * d,
    }


def pyramid_slope(hf: np.ndarray, slope: float, hs: float, vs: float) -> None:
    """Add a pyramid of gradient ``slope`` (negative: a pit) rising to a flat 3-m platform."""
    n0, n1 = hf.shape
    x, y = _pyramid(hf.shape)
    top = int(slope * (hs / vs) * (n0 / 2))
    hf += (top * x[:, None] * y[None, :]).astype(hf.dtype)
    half = int(PLATFORM / hs / 2)
    corner = hf[n0 // 2 - half, n1 // 2 - half]
    np.clip(hf, min(corner, 0), max(corner, 0), out=hf)


def random_uniform(hf: np.ndarray, amplitude: float, hs: float, vs: float, rng) -> None:
    """Add heights drawn uniformly from ``[-amplitude, amplitude]`` on ``ROUGH_STEP`` m steps
    at ``ROUGH_GRID`` m spacing, interpolated linearly onto the tile and rounded to units."""
    low, high, step = _units(-amplitude, vs), _units(amplitude, vs), _units(ROUGH_STEP, vs)
    values = np.arange(low, high + step, step)
    n0, n1 = hf.shape
    coarse = rng.choice(values, (int(n0 * hs / ROUGH_GRID), int(n1 * hs / ROUGH_GRID)))
    x = np.linspace(0, n0 * hs, coarse.shape[0])
    y = np.linspace(0, n1 * hs, coarse.shape[1])
    f = RegularGridInterpolator((x, y), coarse.astype(float))
    fx, fy = np.meshgrid(np.linspace(0, n0 * hs, n0), np.linspace(0, n1 * hs, n1), indexing="ij")
    hf += np.rint(f(np.stack([fx, fy], -1))).astype(hf.dtype)


def _stair_rings(shape: tuple[int, int], hs: float):
    """The inner squares ``(a0, b0, a1, b1)`` (grid units) of legged_gym's stair rings, outside
    in: each ``STEP_WIDTH`` m inside the last, until one is no larger than the platform (the
    last: the platform)."""
    width, platform = _units(STEP_WIDTH, hs), _units(PLATFORM, hs)
    (a0, b0), (a1, b1) = (0, shape[0]), (0, shape[1])
    while b0 - a0 > platform and b1 - a1 > platform:
        a0, b0, a1, b1 = a0 + width, b0 - width, a1 + width, b1 - width
        yield a0, b0, a1, b1


def pyramid_stairs(hf: np.ndarray, step_height: float, hs: float, vs: float) -> None:
    """Set rings of ``STEP_WIDTH`` m, each ``step_height`` higher (negative: lower) than the
    one outside it, until the inner square is no larger than the platform."""
    h, height = 0, _units(step_height, vs)
    for a0, b0, a1, b1 in _stair_rings(hf.shape, hs):
        h += height
        hf[a0:b0, a1:b1] = h


def _pyramid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """legged_gym's pyramid factors along each axis: 1 at the centre, 0 at the edges."""
    n0, n1 = shape
    c0, c1 = n0 // 2, n1 // 2
    return (c0 - np.abs(c0 - np.arange(n0))) / c0, (c1 - np.abs(c1 - np.arange(n1))) / c1


def stairs_platform(pixels: int, hs: float) -> np.ndarray:
    """(pixels, pixels) bool: a stairs tile's flat platform, the last ring's square (legged_gym's
    ``pyramid_stairs_terrain`` loop: 2.6 m at 0.1 m, nine 0.30 m steps)."""
    out = np.zeros((pixels, pixels), dtype=bool)
    a0, b0, a1, b1 = (0, pixels, 0, pixels)
    for a0, b0, a1, b1 in _stair_rings((pixels, pixels), hs):  # noqa: B007 - the last ring's
        pass
    out[a0:b0, a1:b1] = True
    return out


def slope_platform(pixels: int, hs: float) -> np.ndarray:
    """(pixels, pixels) bool: a slope tile's (smooth or rough) flat platform, where the pyramid
    ``x * y`` reaches its clip at the 3-m platform's corner (``pyramid_sloped_terrain``: a
    square's corners at 1.5 m, along the axes 2.4 m: the clip is a level of ``x * y``), whatever
    the gradient (at difficulty 0 the same region, flat throughout)."""
    x, y = _pyramid((pixels, pixels))
    half = int(PLATFORM / hs / 2)
    corner = x[pixels // 2 - half] * y[pixels // 2 - half]
    return x[:, None] * y[None, :] >= corner - 1e-12


def square_platform(pixels: int, hs: float) -> np.ndarray:
    """(pixels, pixels) bool: the 3-m square at the centre a ``discrete`` tile zeroes
    (``discrete_obstacles_terrain``)."""
    out = np.zeros((pixels, pixels), dtype=bool)
    p = _units(PLATFORM, hs)
    out[(pixels - p) // 2 : (pixels + p) // 2, (pixels - p) // 2 : (pixels + p) // 2] = True
    return out


def discrete_obstacles(hf: np.ndarray, height: float, hs: float, vs: float, rng) -> None:
    """Set ``OBSTACLES`` rectangles of sides from ``OBSTACLE_SIZES`` to one of +-height and
    +-height / 2 (grid units, on a 4-unit lattice), then a flat platform at the centre."""
    top = _units(height, vs)
    heights = [-top, -top // 2, top // 2, top]
    low, high = _units(OBSTACLE_SIZES[0], hs), _units(OBSTACLE_SIZES[1], hs)
    n0, n1 = hf.shape
    for _ in range(OBSTACLES):
        w, ln = rng.choice(range(low, high, 4)), rng.choice(range(low, high, 4))
        i, j = rng.choice(range(0, n0 - w, 4)), rng.choice(range(0, n1 - ln, 4))
        hf[i : i + w, j : j + ln] = rng.choice(heights)
    p = _units(PLATFORM, hs)
    hf[(n0 - p) // 2 : (n0 + p) // 2, (n1 - p) // 2 : (n1 + p) // 2] = 0


def slope_tile(sign: float, rough: bool = False):
    """The builder of a slope tile (:class:`~sim2real.eval.world.tile_generators.TileGenerator`'s
    ``build``): a pyramid of gradient ``sign * slope`` at the difficulty (negative: a pit, the
    robot climbs out), with ``rough``: roughness on it (its random parts from ``rng``)."""

    def build(hf: np.ndarray, difficulty: float, hs: float, vs: float, rng) -> None:
        t = difficulty_terms(difficulty)
        pyramid_slope(hf, sign * t["slope"], hs, vs)
        if rough:
            random_uniform(hf, t["amplitude"], hs, vs, rng)

    return build


def stairs_tile(sign: float):
    """The builder of a stairs tile: steps of ``sign * step_height`` at the difficulty (negative:
    down into a pit, the robot climbs out)."""

    def build(hf: np.ndarray, difficulty: float, hs: float, vs: float, rng) -> None:
        pyramid_stairs(hf, sign * difficulty_terms(difficulty)["step_height"], hs, vs)

    return build


def discrete_tile(hf: np.ndarray, difficulty: float, hs: float, vs: float, rng) -> None:
    """The builder of a ``discrete`` tile: obstacles of the difficulty's height (random parts
    from ``rng``)."""
    discrete_obstacles(hf, difficulty_terms(difficulty)["obstacle_height"], hs, vs, rng)
