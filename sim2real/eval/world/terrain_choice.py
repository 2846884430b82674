"""Which kind of tile a legged_gym terrain gives a choice: its own cumulative rule.

legged_gym's ``Terrain.make_terrain`` (legged_gym ``legged_gym/utils/terrain.py``, OpenRobotLab/HIMLoco's
copy) compares a choice in [0, 1) with the cumulative sums of ``terrain_proportions``, kind after
kind, and builds the first kind whose sum the choice is below (:func:`legged_gym_kind`); its
curriculum gives column ``j`` of ``num_cols`` the choice ``j / num_cols + 0.001``, its random
terrain a uniform one (:func:`kind_shares`). Shares are not normalised: those that sum past 1
leave the last kinds nothing, those that sum below 1 give the rest to its later kinds.
"""

from __future__ import annotations

import numpy as np

from sim2real.eval.world.terrain_tiles import UNBUILT_KINDS

#: A choice past the last cumulative share by less than this (the rounding of a float sum: HIMLoco's
#: [0.1, 0.2, 0.3, 0.3, 0.1] sums to 1 + 2e-16 in numpy, another mix to 1 - 1e-16) is no share of
#: the draws; a uniform choice that lands there (a chance below 1e-9) is given the kind below it.
ROUNDING = 1e-9


def cumulative_proportions(shares) -> list[float]:
    """legged_gym's ``Terrain.proportions``: ``[np.sum(shares[:i + 1]) for i in ...]`` (the same
    numpy sums, so the same floats)."""
    return [float(np.sum(shares[: i + 1])) for i in range(len(shares))]


def legged_gym_kind(choice: float, shares) -> str:
    """The kind legged_gym's ``Terrain.make_terrain`` builds for ``choice`` (its ``if``/``elif``
    chain on the cumulative proportions, legged_gym ``legged_gym/utils/terrain.py`` and
    OpenRobotLab/HIMLoco's copy): below the first cumulative share a smooth slope (below its
    half the negative slope: our ``slope_up``, a pit climbed out of), then ``rough_slope``,
    ``stairs_up`` (below the third: the negative step height), ``stairs_down``, ``discrete``,
    ``stepping_stones``, ``gaps``, and past them all its final ``else``: ``pits``. Shares that
    do not sum to 1 give the last kinds what is left, or nothing. A comparison with an entry
    ``shares`` does not have (legged_gym's IndexError) is returned as
    ``"terrain_proportions[k]"``."""
    cum = cumulative_proportions(shares)

    def below(k: int) -> bool | str:
        return choice < cum[k] if k < len(cum) else f"terrain_proportions[{k}]"

    for k, kind in (
        (0, None),
        (1, "rough_slope"),
        (3, None),
        (4, "discrete"),
        (5, None),
        (6, None),
    ):
        hit = below(k)
        if isinstance(hit, str):
            return hit
        if not hit:
            continue
        if k == 0:
            return "slope_up" if choice < cum[0] / 2 else "slope_down"
        if k == 3:
            return "stairs_up" if choice < cum[2] else "stairs_down"
        return kind or UNBUILT_KINDS[k - 5]
    return UNBUILT_KINDS[-1]


def kind_shares(shares, num_cols: int | None) -> dict[str, float]:
    """``{kind: share of the draws}`` of :func:`legged_gym_kind` over legged_gym's choices: with a
    curriculum (``num_cols``) the columns' ``j / num_cols + 0.001`` (``Terrain.curiculum``),
    each ``1 / num_cols``; without, a uniform choice in [0, 1) (``Terrain.randomized_terrain``),
    each kind the length of its interval (pieces shorter than ``ROUNDING`` left out). Only the
    kinds reached, in the order reached."""
    out: dict[str, float] = {}
    if num_cols is not None:
        for j in range(num_cols):
            kind = legged_gym_kind(j / num_cols + 0.001, shares)
            out[kind] = out.get(kind, 0.0) + 1.0 / num_cols
        return out
    cum = cumulative_proportions(shares)
    edges = sorted({0.0, 1.0, *(c for c in [*cum, cum[0] / 2] if 0.0 < c < 1.0)})
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b - a >= ROUNDING:
            kind = legged_gym_kind(a, shares)
            out[kind] = out.get(kind, 0.0) + (b - a)
    return out
