"""legged_gym's ``terrain`` description as the soak draws from it: :class:`TerrainRanges` (a ranges
file's ``[terrain]`` table, :mod:`sim2real.eval.world.ranges_file`, or a legged_gym task's own class,
:mod:`sim2real.eval.world.legged_gym_domain`), its mesh types and walks; the draw and the ground it
lays are :mod:`sim2real.eval.world.terrain`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim2real.eval.world.terrain_choice import kind_shares
from sim2real.eval.world.terrain_tiles import (
    KINDS,
    UNBUILT_KINDS,
)

#: legged_gym ``terrain.mesh_type`` values: with tiles, and without (a flat plane).
MESH_TYPES, FLAT_MESH_TYPES = ("trimesh", "heightfield"), ("plane", "none")
#: How a session's robot walks its tiles (:attr:`TerrainRanges.walk`).
WALKS = ("grid", "curriculum")
#: legged_gym's difficulties without a curriculum (``Terrain.randomized_terrain``).
RANDOM_DIFFICULTIES = (0.5, 0.75, 0.9)


@dataclass(frozen=True)
class TerrainRanges:
    """legged_gym's ``terrain`` class as a session draws from it (defaults: legged_gym's
    ``LeggedRobotCfg.terrain``, and OpenRobotLab/HIMLoco's proportions).

    Attributes:
        mesh_type: ``trimesh`` or ``heightfield`` (``plane``/``none``: no terrain).
        terrain_proportions: Shares of [smooth slope, rough slope, stairs up, stairs down,
            discrete, stepping stones, gaps] (legged_gym's, up to 8), read by legged_gym's own
            cumulative rule (:mod:`~sim2real.eval.world.terrain_choice`): shares that do not sum
            to 1 give the last kinds what is left, or nothing. A draw that would reach a kind
            the soak does not build (stepping stones, gaps, pits: legged_gym's final ``else`` is
            pits), or an entry the list does not have (legged_gym's IndexError), is refused by
            name.
        num_rows: Levels; row ``i`` has difficulty ``i / num_rows``.
        num_cols: legged_gym's columns (kinds): with ``curriculum`` a session's kind is that of
            a column drawn uniformly (its robots are spread evenly over the columns), column
            ``j``'s choice ``j / num_cols + 0.001`` (``Terrain.curiculum``).
        levels: ``(low, high)`` rows drawn uniformly, inclusive (default every row).
        curriculum: False: the difficulty is one of ``RANDOM_DIFFICULTIES`` (legged_gym's).
        horizontal_scale, vertical_scale: m per grid step and per height unit.
        terrain_length, terrain_width: m, a tile's sides (legged_gym: 8 x 8; both taken square
            at ``terrain_width``, as its ``make_terrain`` does).
        border_size: m of flat ground around the session's tiles (ours: legged_gym's 25 m rings
            200 tiles).
        slope_treshold: Gradient above which a trimesh face is made vertical (legged_gym's
            spelling).
        tiles: The session's grid is ``tiles x tiles`` tiles (odd; ours); with ``walk =
            "curriculum"`` the columns of its strip.
        walk: ``"grid"`` (default): the session's tiles are all of its drawn kind and level, the
            robot starts on the middle one and is stood up there after a fall. ``"curriculum"``:
            the session's ground is legged_gym's column of its kind, one tile per level along x
            (``num_rows`` rows, difficulty ``i / num_rows``; legged_gym's rows, ``Terrain.
            curiculum``), ``tiles`` wide; the robot starts at the centre of its level's tile, and
            each episode (``episode_length_s`` of walking, or a fall) ends with legged_gym's
            curriculum rule moving its level and a respawn on that level's tile
            (:mod:`sim2real.eval.soak.curriculum_walk`). Needs ``curriculum``.
        episode_length_s: s, legged_gym's ``env.episode_length_s`` (20 in ``legged_robot_config.
            py``): a curriculum walk's episode (its timeout, and the distance its rule asks for).

    Raises:
        ValueError: a mesh type, proportion, level or size out of its bounds (named).
    """

    mesh_type: str = "trimesh"
    terrain_proportions: tuple[float, ...] = (0.1, 0.2, 0.3, 0.3, 0.1)
    num_rows: int = 10
    num_cols: int = 20
    levels: tuple[int, int] | None = None
    curriculum: bool = True
    horizontal_scale: float = 0.1
    vertical_scale: float = 0.005
    terrain_length: float = 8.0
    terrain_width: float = 8.0
    border_size: float = 1.0
    slope_treshold: float = 0.75
    tiles: int = 1
    walk: str = "grid"
    episode_length_s: float = 20.0

    def __post_init__(self):
        if self.mesh_type not in MESH_TYPES + FLAT_MESH_TYPES:
            raise ValueError(
                f"TerrainRanges.mesh_type: '{self.mesh_type}' is not one the soak builds; "
                f"expected one of {list(MESH_TYPES + FLAT_MESH_TYPES)}"
            )
        p = self.terrain_proportions
        if not 1 <= len(p) <= len(UNBUILT_KINDS) + 5 or any(not (x >= 0) for x in p):
            raise ValueError(
                f"TerrainRanges.terrain_proportions: expected 1 to 8 shares >= 0, got {list(p)}"
            )
        if self.num_cols < 1:
            raise ValueError(f"TerrainRanges.num_cols: expected >= 1, got {self.num_cols}")
        for kind, share in self.kind_shares.items():
            if kind in KINDS or share <= 0:
                continue
            if kind in UNBUILT_KINDS:
                raise ValueError(
                    f"TerrainRanges.terrain_proportions: terrain {kind} (share {share:g}) is "
                    f"not one the soak builds: legged_gym's cumulative rule gives it that share "
                    f"of the draws of {list(p)}; expected shares that leave nothing past the "
                    f"fifth (it builds {list(KINDS)})"
                )
            raise ValueError(
                f"TerrainRanges.terrain_proportions: {list(p)} sums to {float(np.sum(p)):g}; "
                f"legged_gym's make_terrain compares a share {share:g} of its choices with "
                f"{kind}, which the list does not have (its IndexError); expected shares that "
                "sum to at least 1"
            )
        if self.num_rows < 1 or (
            self.levels and not 0 <= self.levels[0] <= self.levels[1] < self.num_rows
        ):
            raise ValueError(
                "TerrainRanges.levels: expected 0 <= low <= high < num_rows = "
                f"{self.num_rows}, got {self.levels}"
            )
        for name in ("horizontal_scale", "vertical_scale", "terrain_width", "slope_treshold"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TerrainRanges.{name}: expected > 0, got {getattr(self, name)}")
        if self.tiles < 1 or self.tiles % 2 == 0 or self.border_size < 0:
            raise ValueError(
                "TerrainRanges.tiles: expected an odd count >= 1 and border_size >= 0, got "
                f"{self.tiles}, {self.border_size}"
            )

        if self.walk not in WALKS or (self.walk == "curriculum" and not self.curriculum):
            raise ValueError(
                f"TerrainRanges.walk: expected one of {list(WALKS)} ('curriculum' with "
                f"curriculum = true), got {self.walk!r} (curriculum {self.curriculum})"
            )
        if not (math.isfinite(self.episode_length_s) and self.episode_length_s > 0):
            raise ValueError(
                f"TerrainRanges.episode_length_s: expected s > 0, got {self.episode_length_s}"
            )

    @property
    def flat(self) -> bool:
        return self.mesh_type in FLAT_MESH_TYPES

    def describe(self) -> str:
        """One line: the mesh, the kinds' shares of the sessions by legged_gym's rule, the
        levels (``soak-test: terrain: ...``)."""
        shares = ", ".join(f"{k} {100 * x:.3g} %" for k, x in self.kind_shares.items())
        low, high = self.levels or (0, self.num_rows - 1)
        choice = f"{self.num_cols} curriculum columns" if self.curriculum else "a uniform choice"
        walk = (
            f"; curriculum walk: each session on its kind's column of {self.num_rows} levels, "
            f"episodes of {self.episode_length_s:g} s, levels moved by legged_gym's rule"
            if self.walk == "curriculum"
            else ""
        )
        return (
            f"{self.mesh_type} tiles, {shares} of the sessions (legged_gym's cumulative rule on "
            f"{list(self.terrain_proportions)}, {choice}); levels {low}-{high} of "
            f"{self.num_rows}{walk}"
        )

    @property
    def kind_shares(self) -> dict[str, float]:
        """``{kind: share of the sessions' draws}`` by legged_gym's rule
        (:func:`~sim2real.eval.world.terrain_choice.kind_shares`),
        the kinds it reaches only (legged_gym's unbuilt kinds and an entry the list lacks,
        ``terrain_proportions[k]``, included when reached)."""
        return kind_shares(self.terrain_proportions, self.num_cols if self.curriculum else None)
