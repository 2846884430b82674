"""The ground of a floating-base robot's session: legged_gym's terrain tiles in the plant.

:class:`~sim2real.eval.world.terrain_ranges.TerrainRanges` is legged_gym's ``terrain`` description
as the soak draws from it (:mod:`sim2real.eval.world.terrain_ranges`); :func:`sample_terrain` draws
a session's :class:`TerrainDraw` (a kind of :data:`~sim2real.eval.world.tile_generators.TILE_GENERATORS` and a
difficulty, from ``terrain_proportions`` and the levels); :func:`ground_map` lays out its ``tiles x
tiles`` grid of that kind and difficulty (each tile its own random parts) inside a flat border, the
robot's start (the world origin) at the centre of the middle tile's platform; :func:`add_ground`
puts it into a plant spec as a MuJoCo height field in place of the flat floor plane, with the
floor's contact settings and name, the free-floating base raised by the ground's height at the
start. Without a terrain (``SessionRanges.terrain`` None, the default) the plane stays and nothing
changes.

A ``trimesh`` terrain's stairs and obstacles are boxes (legged_gym's trimesh makes their faces vertical,
``slope_treshold``), its slopes a height field at ``horizontal_scale``; a ``heightfield`` terrain is a
height field throughout (steps as one-cell ramps, as legged_gym's heightfield has them).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import mujoco
import numpy as np

from sim2real.eval.world.floor import BORDER_PREFIX
from sim2real.eval.world.terrain_choice import cumulative_proportions, legged_gym_kind
from sim2real.eval.world.terrain_layout import (  # noqa: F401 - tile_grid is this module's too
    start_tile,
    tile_counts,
    tile_difficulty,
    tile_grid,
)
from sim2real.eval.world.terrain_ranges import (  # noqa: F401 - importable from here too
    FLAT_MESH_TYPES,
    MESH_TYPES,
    RANDOM_DIFFICULTIES,
    WALKS,
    TerrainRanges,
)
from sim2real.eval.world.tile_generators import make_tile, tile_generator, tile_kinds

#: A trimesh terrain lays the kinds whose generator is ``stepped`` as boxes (the stairs and
#: ``discrete``): their faces are steeper than any ``slope_treshold`` (a 0.05 m step over
#: legged_gym's 0.1 m cell: 0.5; its trimesh makes faces above 0.75 vertical). A height field at
#: 0.1 m gives a step a 45-degree ramp; a finer one (we tried 0.025 m) holds a foot sphere in its
#: many prisms' contacts (HIMLoco's Go2 stood still on a flat platform).
#: Depth of the height field's base below its lowest point, m (MuJoCo's ``size[3]``).
BASE_DEPTH = 1.0
#: The flat ground around the height field: four boxes of top 0 reaching this far, m (ours: a
#: session walking off its tiles walks on), named with this prefix (floor geoms,
#: :func:`sim2real.eval.world.floor.floor_geoms`).
BORDER_REACH = 200.0
#: The floor plane's settings its replacement takes (:func:`add_ground`).
FLOOR_SETTINGS = ("name", "contype", "conaffinity", "condim", "friction", "priority", "solref")
FLOOR_SETTINGS += ("solimp", "solmix", "margin", "gap", "material", "rgba", "group")
#: Half side of the square about the start whose highest point the robot is put on, m (ours: a
#: Go2's feet stand within 0.25 m of its base).
SPAWN_HALF_SIDE = 0.3


@dataclass(frozen=True)
class TerrainDraw:
    """A session's ground: its tiles' ``kind`` (a registered one,
    :func:`~sim2real.eval.world.tile_generators.tile_kinds`), ``difficulty`` in [0, 1),
    ``level`` (the row it came from; None for a stated size), the ``ranges`` laid out."""

    kind: str
    difficulty: float
    level: int | None = None
    ranges: TerrainRanges = field(default_factory=TerrainRanges)

    def __post_init__(self):
        tile_generator(self.kind)  # a kind the soak builds, or ValueError naming those it does

    @property
    def label(self) -> str:
        """``kind@level`` or ``kind:size`` (its generator's ``size``: the step height in m, the
        slope in degrees)."""
        if self.level is not None:
            return f"{self.kind}@{self.level}"
        return f"{self.kind}:{tile_generator(self.kind).size(self.difficulty)}"

    def apply(self, spec: mujoco.MjSpec, rng: np.random.Generator) -> GroundMap:
        """Lay this ground into plant ``spec``: :func:`apply_terrain`."""
        return apply_terrain(spec, self, rng)

    def to_dict(self) -> dict:
        """JSON-ready (tuples as lists: a checkpoint's stored draw, read back, equals it)."""
        out = {"kind": self.kind, "difficulty": self.difficulty, "level": self.level}
        ranges = {
            k: list(v) if isinstance(v, tuple) else v
            for k, v in dataclasses.asdict(self.ranges).items()
        }
        return out | {"label": self.label, "ranges": ranges}

    @classmethod
    def from_dict(cls, data: dict) -> TerrainDraw:
        r = {k: tuple(v) if isinstance(v, list) else v for k, v in data["ranges"].items()}
        level = data.get("level")
        level = None if level is None else int(level)
        return cls(str(data["kind"]), float(data["difficulty"]), level, TerrainRanges(**r))


def sample_terrain(rng: np.random.Generator, ranges: TerrainRanges) -> TerrainDraw | None:
    """A session's :class:`TerrainDraw` from ``ranges`` (None for a flat mesh type): the kind
    legged_gym gives a choice (:func:`~sim2real.eval.world.terrain_choice.legged_gym_kind`):
    with ``curriculum`` that of a column drawn uniformly of ``num_cols`` (its ``j / num_cols +
    0.001``), without it a uniform choice in [0, 1) (then the difficulty one of
    ``RANDOM_DIFFICULTIES``); the level uniform over ``levels``."""
    shares = ranges.terrain_proportions
    if ranges.curriculum:  # a column drawn uniformly, its choice legged_gym's
        choice = int(rng.integers(ranges.num_cols)) / ranges.num_cols + 0.001
    else:
        choice = float(rng.uniform(0.0, 1.0))
    kind = legged_gym_kind(choice, shares)
    if kind not in tile_kinds():  # within terrain_choice.ROUNDING past the last share: below
        kind = legged_gym_kind(np.nextafter(cumulative_proportions(shares)[-1], 0.0), shares)
    if not ranges.curriculum:
        return TerrainDraw(kind, float(rng.choice(RANDOM_DIFFICULTIES)), None, ranges)
    low, high = ranges.levels or (0, ranges.num_rows - 1)
    level = int(rng.integers(low, high + 1))
    return TerrainDraw(kind, level / ranges.num_rows, level, ranges)


@dataclass(frozen=True)
class GroundMap:
    """Heights ``heights`` (nx, ny) m on a grid of ``spacing`` m, sample ``(i, j)`` at world
    ``(x0 + i spacing, y0 + j spacing)``; the start (world origin) is on a sample. ``stepped``:
    each sample the flat top of the square of side ``spacing`` about it (boxes), else the
    corners of a height field's cells."""

    heights: np.ndarray
    x0: float
    y0: float
    spacing: float
    stepped: bool = False

    def height_at(self, x, y) -> np.ndarray:
        """The ground's height (m) under world points ``(x, y)`` (arrays alike), bilinear in its
        cell (MuJoCo's two triangles differ inside a cell by at most a quarter of its rise);
        outside the map 0 (the border boxes' top, :func:`add_ground`); a stepped map's
        nearest sample's."""
        h = self.heights
        u = (np.asarray(x, float) - self.x0) / self.spacing
        v = (np.asarray(y, float) - self.y0) / self.spacing
        if self.stepped:
            i, j = np.rint(u).astype(int), np.rint(v).astype(int)
            inside = (i >= 0) & (i < h.shape[0]) & (j >= 0) & (j < h.shape[1])
            return np.where(
                inside, h[np.clip(i, 0, h.shape[0] - 1), np.clip(j, 0, h.shape[1] - 1)], 0.0
            )
        inside = (u >= 0) & (u <= h.shape[0] - 1) & (v >= 0) & (v <= h.shape[1] - 1)
        u, v = np.clip(u, 0, h.shape[0] - 1), np.clip(v, 0, h.shape[1] - 1)
        i = np.minimum(u.astype(int), h.shape[0] - 2)
        j = np.minimum(v.astype(int), h.shape[1] - 2)
        a, b = u - i, v - j
        z = (h[i, j] * (1 - a) * (1 - b) + h[i + 1, j] * a * (1 - b)
             + h[i, j + 1] * (1 - a) * b + h[i + 1, j + 1] * a * b)  # fmt: skip
        return np.where(inside, z, 0.0)


def ground_map(draw: TerrainDraw, rng: np.random.Generator) -> GroundMap:
    """The session's :class:`GroundMap` of ``draw`` (module docstring), random parts from
    ``rng``."""
    r = draw.ranges
    hs, vs = r.horizontal_scale, r.vertical_scale
    n, border, _ = tile_grid(r)
    rows, cols = tile_counts(r)
    units = np.zeros((2 * border + rows * n, 2 * border + cols * n), dtype=np.int16)
    for i in range(rows):
        d = tile_difficulty(draw, i)
        for j in range(cols):
            tile = make_tile(draw.kind, d, n, hs, vs, rng)
            units[border + i * n : border + (i + 1) * n, border + j * n : border + (j + 1) * n] = (
                tile
            )
    stepped = r.mesh_type == "trimesh" and tile_generator(draw.kind).stepped
    i0, j0 = start_tile(draw)
    sx, sy = border + i0 * n + n // 2, border + j0 * n + n // 2
    return GroundMap(units * vs, -sx * hs, -sy * hs, hs, stepped)


def _free_body(spec: mujoco.MjSpec):
    for body in spec.bodies:
        if any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in body.joints):
            return body
    raise ValueError("add_ground: the plant has no free-floating body")


def _rectangles(units: np.ndarray):
    """``(i0, i1, j0, j1, value)``: ``units`` split into rectangles of one value each (greedy:
    a run along j, grown along i while the rows match)."""
    done = np.zeros(units.shape, dtype=bool)
    n0, n1 = units.shape
    for i in range(n0):
        for j in range(n1):
            if done[i, j]:
                continue
            v, j1 = units[i, j], j + 1
            while j1 < n1 and not done[i, j1] and units[i, j1] == v:
                j1 += 1
            i1 = i + 1
            while i1 < n0 and not done[i1, j:j1].any() and (units[i1, j:j1] == v).all():
                i1 += 1
            done[i:i1, j:j1] = True
            yield i, i1, j, j1, v


def add_ground(spec: mujoco.MjSpec, ground: GroundMap) -> None:
    """Replace ``spec``'s floor planes by ``ground`` (in place): a height field, or for a
    stepped ground boxes (one per rectangle of one height: vertical faces), named
    ``BORDER_PREFIX``..., and four boxes of top 0 around it; each takes the (first) plane's
    contact bits, friction, priority, solver settings and material (the field its name too),
    and the free-floating body is raised by :func:`spawn_height`.

    Raises:
        ValueError: a spec without a floor plane or a free-floating body.
    """
    planes = [g for g in spec.worldbody.geoms if g.type == mujoco.mjtGeom.mjGEOM_PLANE]
    if not planes:
        raise ValueError("add_ground: the plant has no floor (plane geom) to replace")
    keep = {k: getattr(planes[0], k) for k in FLOOR_SETTINGS}
    for g in planes:
        spec.delete(g)

    def add(kind, name: str | None, pos, size=None):
        geom = spec.worldbody.add_geom(type=kind)
        for k, v in keep.items():
            if k != "name":
                setattr(geom, k, v)
        geom.name = keep["name"] if name is None else name
        geom.pos = pos
        if size is not None:
            geom.size = size
        return geom

    h, s = ground.heights, ground.spacing
    nx, ny = h.shape
    low, high = float(h.min()), float(h.max())
    if ground.stepped:  # sample (i, j) the top of the square of side s about it
        bottom = min(low, 0.0) - BASE_DEPTH
        for k, (i0, i1, j0, j1, v) in enumerate(_rectangles(np.rint(h / 1e-4).astype(np.int64))):
            top = v * 1e-4
            cx, cy = ground.x0 + (i0 + i1 - 1) * s / 2, ground.y0 + (j0 + j1 - 1) * s / 2
            size = [(i1 - i0) * s / 2, (j1 - j0) * s / 2, (top - bottom) / 2]
            add(
                mujoco.mjtGeom.mjGEOM_BOX,
                f"{BORDER_PREFIX}tile_{k}",
                [cx, cy, (top + bottom) / 2],
                size,
            )
        xa, ya = ground.x0 - s / 2, ground.y0 - s / 2
        xb, yb = xa + nx * s, ya + ny * s
    else:
        rise = max(high - low, 1e-6)
        hf = spec.add_hfield(name="terrain", nrow=ny, ncol=nx)
        hf.size = [(nx - 1) * s / 2, (ny - 1) * s / 2, rise, BASE_DEPTH]
        hf.userdata = ((h.T - low) / rise).ravel().tolist()  # rows along y, columns along x
        field = add(
            mujoco.mjtGeom.mjGEOM_HFIELD,
            None,
            [ground.x0 + hf.size[0], ground.y0 + hf.size[1], low],
        )
        field.hfieldname = "terrain"
        xa, ya, xb, yb = (
            ground.x0,
            ground.y0,
            ground.x0 + 2 * hf.size[0],
            ground.y0 + 2 * hf.size[1],
        )
    f = BORDER_REACH
    frame = (  # (centre x, y, half sides x, y) of the four boxes around the tiles
        (xb + f, (ya + yb) / 2, f, (yb - ya) / 2 + 2 * f),
        (xa - f, (ya + yb) / 2, f, (yb - ya) / 2 + 2 * f),
        ((xa + xb) / 2, yb + f, (xb - xa) / 2, f),
        ((xa + xb) / 2, ya - f, (xb - xa) / 2, f),
    )
    for k, (cx, cy, sx, sy) in enumerate(frame):
        add(mujoco.mjtGeom.mjGEOM_BOX, f"{BORDER_PREFIX}{k}", [cx, cy, -0.5], [sx, sy, 0.5])
    body = _free_body(spec)
    body.pos = np.asarray(body.pos) + [0.0, 0.0, spawn_height(ground)]


def spawn_height(ground: GroundMap, x: float = 0.0, y: float = 0.0) -> float:
    """m, the ground's highest point within ``SPAWN_HALF_SIDE`` of world ``(x, y)`` m (default
    the start; legged_gym's ``env_origin_z``: the highest within 1 m of its tile's centre): the
    feet of a robot put there at its standing height are on the ground or above it, never in
    it."""
    h, s = ground.heights, ground.spacing
    i0, j0 = round((x - ground.x0) / s), round((y - ground.y0) / s)
    k = int(math.ceil(SPAWN_HALF_SIDE / s))
    return float(h[max(i0 - k, 0) : i0 + k + 1, max(j0 - k, 0) : j0 + k + 1].max())


def apply_terrain(spec: mujoco.MjSpec, draw: TerrainDraw, rng: np.random.Generator) -> GroundMap:
    """Lay ``draw``'s ground out (:func:`ground_map`, random parts from ``rng``) into the plant
    ``spec`` (:func:`add_ground`); returns the map (the truth's ground under the robot)."""
    ground = ground_map(draw, rng)
    add_ground(spec, ground)
    return ground


def parse_terrain(text: str, ranges: TerrainRanges | None = None) -> TerrainDraw:
    """A tile stated on a command line: ``KIND@LEVEL`` (difficulty ``LEVEL / num_rows``) or
    ``KIND:SIZE`` (the kind's generator's ``difficulty``,
    :mod:`~sim2real.eval.world.tile_generators`): stairs by their step height (m,
    ``stairs_up:0.10``), slopes by their angle (``slope_up:15deg``) or gradient, ``discrete`` by
    its obstacles' height (m); the difficulty is legged_gym's that gives it (module
    :mod:`~sim2real.eval.world.terrain_tiles`).

    Raises:
        ValueError: an unknown kind (named, with those the soak builds), a malformed size or
            level, or one outside difficulties [0, 1).
    """
    # one stated tile: the grid of it (a curriculum walk's column is a soak session's)
    ranges = TerrainRanges() if ranges is None else dataclasses.replace(ranges, walk="grid")
    kind, sep, rest = text.replace("@", ":@", 1).partition(":")
    if kind not in tile_kinds():
        raise ValueError(
            f"--terrain {text}: terrain kind '{kind}' is not one the soak builds; expected one "
            f"of {list(tile_kinds())}"
        )
    if not sep:
        raise ValueError(
            f"--terrain {text}: expected KIND:SIZE or KIND@LEVEL (stairs_up:0.10, "
            "slope_up:15deg, discrete@5)"
        )
    try:
        if rest.startswith("@"):
            level = int(rest[1:])
            if not 0 <= level < ranges.num_rows:
                raise ValueError
            return TerrainDraw(kind, level / ranges.num_rows, level, ranges)
        d = tile_generator(kind).difficulty(rest)
    except ValueError:
        raise ValueError(
            f"--terrain {text}: expected KIND:SIZE (a number; slopes may end in deg) or "
            f"KIND@LEVEL (0..{ranges.num_rows - 1})"
        ) from None
    if not 0.0 <= d < 1.0:
        raise ValueError(
            f"--terrain {text}: size outside legged_gym's difficulties [0, 1) (difficulty {d:.3g})"
        )
    return TerrainDraw(kind, d, None, ranges)
