"""Local approach bounds of the collision pairs: how far a pair's distance can shrink over a box of
configurations, from the speeds of its geometries' points at one configuration of the box
(:class:`LocalReach`), tighter than the global chain bound
(:func:`sim2real.robots.chain_bounds.collision_pair_weights`) where the arm is folded.

Joint ``j`` turning at 1 rad/s moves a point ``x`` at ``|v_j + w_j x x|`` m/s, ``(v_j, w_j)`` its
column of the world Jacobian (the spatial velocity at the world origin): for a revolute joint the
point's distance from the axis. Pair ``p``'s distance changes with ``j`` at most as fast as the
fastest point of the geometry ``j`` moves, ``r_pj``: a convex function's largest value over a
box lies at a vertex, over a capsule within ``|w_j| radius`` of an end of its segment (a cylinder
lies in the capsule of its radius and length), over any other geometry within ``|w_j|`` times
the radius of coal's local bounding sphere of its centre.

Over a box ``|q_k - c_k| <= D_k`` about ``c``: turning a joint above ``j`` moves ``j``'s axis and
the geometry together, turning a joint ``k`` below ``j`` moves the geometry's points by at most
``r_pk`` each and not the axis, so ``r_pj <= R_pj = min(w_pj, r_pj(c) + sum_k R_pk D_k)``, the
joints below first (``w`` the global weights; a joint on ``j``'s own body counts ``w_pk D_k``).
Along coordinate paths inside the box the distance then shrinks by at most ``sum_j R_pj D_j``
(:func:`local_reach`; compiled, as the envelope runs it:
:func:`sim2real.deploy.safety.envelope_kernel.pair_reach`, the same arithmetic in the same order).
"""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin

from sim2real.robots import Robot
from sim2real.robots.chain_bounds import collision_pair_nesting, collision_pair_weights, descends


class LocalReach:
    """The speeds ``r_pj`` of a robot's collision pairs at a configuration (:meth:`speeds`) and
    the joint order and nesting :func:`local_reach` reads.

    Args:
        robot: The robot (collision pairs, joint names; ``fixed_base_model``'s joints in the
            robot's joint order, one degree of freedom each).
        geometry: ``(geom_model, geom_data)``, :func:`sim2real.deploy.safety.collision.collision_model`
            (its data is used).

    Attributes:
        order: (n,) int64 and ``nest`` (pairs, n, n) int8,
            :func:`sim2real.robots.chain_bounds.collision_pair_nesting`.
        moved: (pairs, n) int64, the geometry (index in ``geom_model``) joint ``j`` moves
            relative to the other of pair ``p``; -1 where the pair's weight is 0.
    """

    def __init__(self, robot: Robot, geometry):
        self.model = robot.fixed_base_model
        self.data = self.model.createData()
        self.geom_model, self.geom_data = geometry
        m = robot.mj_model
        weights = collision_pair_weights(robot)
        self.order, self.nest = collision_pair_nesting(robot)
        bodies = [m.jnt_bodyid[m.joint(name).id] for name in robot.joint_names]
        names = [g.name for g in self.geom_model.geometryObjects]
        self.moved = np.full(weights.shape, -1, dtype=np.int64)
        for p, pair in enumerate(robot.config.safety.collision_pairs):
            for j in np.flatnonzero(weights[p] > 0.0):
                first = descends(m, m.geom_bodyid[m.geom(pair[0]).id], bodies[j])
                self.moved[p, j] = names.index(pair[0] if first else pair[1])
        # the moved geometries: their points (geoms, k, 3) m in their frames (padded by
        # repeating the first) and a radius (m) about each; rows of moved in that list
        self._geoms = np.unique(self.moved[self.moved >= 0])
        support = [_support(self.geom_model.geometryObjects[int(g)].geometry) for g in self._geoms]
        k = max([len(points) for points, _ in support], default=1)
        self._points = np.array([np.concatenate([pts, np.repeat(pts[:1], k - len(pts), 0)])
                                 for pts, _ in support]).reshape(-1, k, 3)  # fmt: skip
        self._radius = np.array([radius for _, radius in support])
        self._row = np.searchsorted(self._geoms, np.maximum(self.moved, 0))
        self._rows, self._cols = np.nonzero(self.moved >= 0)

    def speeds(self, q: np.ndarray) -> np.ndarray:
        """(pairs, n) m/rad, ``r_pj`` at ``q`` (n,) rad: the speed of the fastest point of the
        geometry joint ``j`` moves in pair ``p`` per rad/s of ``j`` (0 where the pair's weight
        is 0)."""
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateGeometryPlacements(self.model, self.data, self.geom_model, self.geom_data)
        jacobian = self.data.J  # (6, n): v at the world origin, then w
        v, w = jacobian[:3].T, jacobian[3:].T  # (n, 3)
        placements = [self.geom_data.oMg[int(g)] for g in self._geoms]
        rotation = np.array([m.rotation for m in placements])  # (geoms, 3, 3)
        translation = np.array([m.translation for m in placements])
        world = np.einsum("gij,gkj->gki", rotation, self._points) + translation[:, None]
        x, y, z = world[..., 0, None], world[..., 1, None], world[..., 2, None]  # (geoms, k, 1)
        # (geoms, k, n): |v_j + w_j x p| of each point p
        speed = np.sqrt(
            (v[:, 0] + w[:, 1] * z - w[:, 2] * y) ** 2
            + (v[:, 1] + w[:, 2] * x - w[:, 0] * z) ** 2
            + (v[:, 2] + w[:, 0] * y - w[:, 1] * x) ** 2
        )
        fastest = speed.max(axis=1) + np.outer(self._radius, np.linalg.norm(w, axis=1))
        out = np.zeros(self.moved.shape)
        rows, cols = self._rows, self._cols
        out[rows, cols] = fastest[self._row[rows, cols], cols]
        return out


def _support(geometry) -> tuple[np.ndarray, float]:
    """``(points (k, 3) m, radius m)`` in the geometry's frame: every point of ``geometry`` lies
    within ``radius`` of the convex hull of ``points``."""
    if isinstance(geometry, coal.Box):
        h = np.asarray(geometry.halfSide)
        signs = np.array(np.meshgrid([-1.0, 1.0], [-1.0, 1.0], [-1.0, 1.0])).reshape(3, -1).T
        return signs * h, 0.0
    if isinstance(geometry, (coal.Capsule, coal.Cylinder)):
        ends = np.array([[0.0, 0.0, -geometry.halfLength], [0.0, 0.0, geometry.halfLength]])
        return ends, float(geometry.radius)
    if isinstance(geometry, coal.ConvexBase):  # a mesh's hull: its bounding box's corners
        pts = np.asarray(geometry.points(), dtype=float).reshape(-1, 3)  # (8 points, not 100s)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        signs = np.array(np.meshgrid([0.0, 1.0], [0.0, 1.0], [0.0, 1.0])).reshape(3, -1).T
        return lo + signs * (hi - lo), 0.0
    geometry.computeLocalAABB()
    return np.asarray(geometry.aabb_center, dtype=float)[None], float(geometry.aabb_radius)


def local_reach(
    weights: np.ndarray, speeds: np.ndarray, spread: np.ndarray, order: np.ndarray, nest
) -> np.ndarray:
    """(pairs,) m, how far each pair's distance can shrink over the box ``|q - c| <= spread``
    (n,) rad (module docstring): ``weights`` (pairs, n) m/rad the global bound, ``speeds``
    (pairs, n) m/rad :meth:`LocalReach.speeds` at ``c``, ``order`` and ``nest``
    :func:`sim2real.robots.chain_bounds.collision_pair_nesting`. Never above ``weights @ spread``. The
    numpy reference of :func:`sim2real.deploy.safety.envelope_kernel.pair_reach` and ``pairs_reach``."""
    pairs, n = weights.shape
    bound = np.zeros((pairs, n))
    # np.where computes both branches: an unbounded (inf) row times a joint that does not move
    # it (spread 0) is NaN in the branch not taken
    with np.errstate(invalid="ignore"):
        for j in order:
            s = speeds[:, j].copy()
            for k in range(n):
                s = np.where(nest[:, j, k] == 1, s + bound[:, k] * spread[k], s)
                s = np.where(nest[:, j, k] == 2, s + weights[:, k] * spread[k], s)
            bound[:, j] = np.where(s < weights[:, j], s, weights[:, j])
        reach = np.zeros(pairs)
        for j in range(n):
            reach = np.where(weights[:, j] != 0.0, reach + bound[:, j] * spread[j], reach)
    return reach
