"""The floor of a floating-base robot's session: its sliding friction, drawn per session
(:class:`sim2real.eval.world.session_ranges.SessionRanges` ``floor_friction``) and applied to the compiled
plant model.
"""

from __future__ import annotations

import mujoco
import numpy as np

#: Sliding friction coefficient of the floor of a floating-base robot's session, uniform. Our
#: choice: 0.5-1.25, legged_gym's ``domain_rand.friction_range`` (LeggedRobotCfg / GO2RoughCfg in
#: unitree_rl_gym). There it is the robot's shapes' coefficient, which PhysX averages with the
#: terrain's 1.0 (an effective 0.75-1.125); here it is the contact's own (the floor has contact
#: priority, :func:`apply_floor_friction`): the low end is a more slippery floor than legged_gym's.
FLOOR_FRICTION = (0.5, 1.25)


#: The name prefix of a terrain's boxes: its stepped tiles and the flat ground around them
#: (:func:`sim2real.eval.world.terrain.add_ground`).
BORDER_PREFIX = "floor_border_"


def floor_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Indices of ``model``'s floor geoms: its planes, and a terrain's height fields and boxes
    (named ``BORDER_PREFIX``..., :func:`sim2real.eval.world.terrain.add_ground`)."""
    t = mujoco.mjtGeom
    floor = (model.geom_type == t.mjGEOM_PLANE) | (model.geom_type == t.mjGEOM_HFIELD)
    boxes = np.flatnonzero((model.geom_type == t.mjGEOM_BOX) & (model.geom_bodyid == 0))
    for g in boxes:  # a terrain's, by name
        floor[g] = model.geom(g).name.startswith(BORDER_PREFIX)
    return np.flatnonzero(floor)


def floor_pairs(model: mujoco.MjModel) -> np.ndarray:
    """Indices of ``model``'s explicit contact pairs (MJCF ``<contact><pair>``) with a floor geom
    on either side: feet that touch the floor through a pair (a robot file whose feet collide
    with nothing else, ``contype=0``)."""
    floor = floor_geoms(model)
    return np.flatnonzero(np.isin(model.pair_geom1, floor) | np.isin(model.pair_geom2, floor))


def apply_floor_friction(model: mujoco.MjModel, friction: float) -> None:
    """Set the sliding friction of ``model``'s floor (:func:`floor_geoms`) to ``friction``, in place,
    and give the floor contact priority: MuJoCo then takes its friction for every contact with
    it (without priority a contact takes the larger of the two geoms' coefficients, and the feet's
    default 1 would hide a slippery floor). A contact pair with the floor (:func:`floor_pairs`)
    carries its own friction, which neither the geoms nor their priority change: its two sliding
    coefficients are set to ``friction`` too (its torsional and rolling ones are kept).

    Raises:
        ValueError: the model has no floor geom.
    """
    floor = floor_geoms(model)
    if not len(floor):
        raise ValueError(
            "apply_floor_friction: the model has no floor (plane or height field geom)"
        )
    model.geom_friction[floor, 0] = friction
    model.geom_priority[floor] = max(int(model.geom_priority.max()), 0) + 1
    model.pair_friction[floor_pairs(model), :2] = friction
