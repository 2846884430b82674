"""MuJoCo's contact rules for a pybullet world: which bodies collide (``contype`` /
``conaffinity``, the parent-child filter, ``<exclude>`` pairs) and the friction a robot link meets
on the floor.

Friction pairs: bullet multiplies the two surfaces' friction coefficients where MuJoCo takes the
larger (or the floor's, with its priority). :mod:`sim2real.deploy.backends.sim.bullet.build` gives
robot links 1 and the floor the coefficient :func:`floor_friction` returns.
"""

from __future__ import annotations

import mujoco
import numpy as np


def weld_pair_filtered(m: mujoco.MjModel, b1: int, b2: int) -> bool:
    """MuJoCo's body filter: same weld group, or parent and child with the parent not the
    world (``filterparent``), or an ``<exclude>`` pair."""
    w1, w2 = int(m.body_weldid[b1]), int(m.body_weldid[b2])
    if w1 == w2:
        return True
    if not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT:
        p1, p2 = int(m.body_weldid[m.body_parentid[w1]]), int(m.body_weldid[m.body_parentid[w2]])
        if (p1 == w2 and w2 != 0) or (p2 == w1 and w1 != 0):
            return True
    signature = (min(b1, b2) << 16) + max(b1, b2)
    return bool(np.any(m.exclude_signature == signature))


def geoms_collide(m: mujoco.MjModel, g1: int, g2: int) -> bool:
    """MuJoCo's contype / conaffinity rule for geoms ``g1`` and ``g2``."""
    return bool(
        (m.geom_contype[g1] & m.geom_conaffinity[g2])
        or (m.geom_contype[g2] & m.geom_conaffinity[g1])
    )


def bodies_collide(m: mujoco.MjModel, b1: int, b2: int) -> bool:
    if weld_pair_filtered(m, b1, b2):
        return False
    g1 = range(m.body_geomadr[b1], m.body_geomadr[b1] + m.body_geomnum[b1])
    g2 = range(m.body_geomadr[b2], m.body_geomadr[b2] + m.body_geomnum[b2])
    return any(geoms_collide(m, a, b) for a in g1 for b in g2)


def floor_friction(m: mujoco.MjModel) -> float:
    """The sliding friction a robot link meets on the world's geoms under MuJoCo's rule (the
    geom of higher priority wins, else the larger coefficient), for the links' highest."""
    world = [g for g in range(m.ngeom) if m.geom_bodyid[g] == 0]
    robot = [g for g in range(m.ngeom) if m.geom_bodyid[g] != 0]
    if not world:
        return 1.0
    w = max(world, key=lambda g: (int(m.geom_priority[g]), float(m.geom_friction[g, 0])))
    if not robot:
        return float(m.geom_friction[w, 0])
    r = max(robot, key=lambda g: float(m.geom_friction[g, 0]))
    if m.geom_priority[w] > m.geom_priority[r]:
        return float(m.geom_friction[w, 0])
    return float(max(m.geom_friction[w, 0], m.geom_friction[r, 0]))
