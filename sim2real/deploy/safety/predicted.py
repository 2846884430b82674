"""The guard's checks at the predicted next state: ``workspace``, ``self_collision``, ``effort``.

Each screens every env with an exact bound (:mod:`sim2real.deploy.safety.guard`'s docstring) and asks for
its Pinocchio check (:meth:`GuardCheck.resolve`) only where the bound says it could fire; an env
that fails one is held (:meth:`sim2real.deploy.safety.guard.SafetyGuard.reject`) and the later checks skip
it. ``effort`` also clamps torque-mode targets to the derated effort limit (:data:`FINAL`).
Units: rad, m, N m.
"""

from __future__ import annotations

import numba
import numpy as np
import pinocchio as pin

from sim2real.deploy.kernels import np_max, np_min, pairs_may_touch, row_sum
from sim2real.deploy.safety.check import (
    EFFORT,
    FINAL,
    FIRED,
    NEEDS_PYTHON,
    PREDICTED,
    TORQUE,
    GuardCheck,
)

#: Rows of ``g.scalars``: dt (s), the screens' margin (m), whether there are collision pairs.
DT, MARGIN, HAS_PAIRS = 0, 1, 2
#: Row of the self-collision check's constants: 1.0 where it holds (a fixed base), else 0.0.
HOLDS = 0


@numba.njit(cache=True, nogil=True, _nrt=False)
def workspace_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`Workspace`'s compiled share; ``own[0]`` the end-effector lever (m/rad)."""
    if stage != PREDICTED:
        return 0
    tmp, pred, checked = g.tmp, g.pred, g.screen[0]
    for j in range(out.shape[1]):
        tmp[e, j] = abs(pred[e, j] - checked[e, j]) * own[0, j]
    move = row_sum(tmp, e)
    return NEEDS_PYTHON if g.workspace_margin[e] <= move + g.scalars[MARGIN] else 0


class Workspace(GuardCheck):
    """The end effector of the predicted state outside the workspace box (and not moving back
    toward it): held."""

    name = "workspace"
    what = "a target whose end effector leaves the workspace box: held"
    kernel = workspace_kernel

    def constants(self, guard) -> np.ndarray:
        return np.array([guard.ee_lever], dtype=np.float64)

    def reference(self, stage, g, out, q, dq, commanded):
        if stage != PREDICTED:
            return None, None
        np.subtract(g._pred, g._ws_q, out=g._tmp)
        np.abs(g._tmp, out=g._tmp)
        np.multiply(g._tmp, g.ee_lever, out=g._tmp)
        np.sum(g._tmp, axis=1, out=g._move)
        return None, g._ws_margin <= g._move + g.screen_margin

    def resolve(self, g, k, needs, q, dq, out) -> None:
        for e in np.flatnonzero(needs & ~g._held):
            outside = g._ee_outside(g._pred[e], cache=e)
            if outside > 0.0 and outside >= g._ee_outside(q[e]) - 1e-12:
                g.reject(k, e, q[e], dq[e], out)


@numba.njit(cache=True, nogil=True, _nrt=False)
def self_collision_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`SelfCollision`'s compiled share (signature of :class:`GuardCheck`)."""
    if stage != PREDICTED or g.scalars[HAS_PAIRS] == 0.0 or own[HOLDS, 0] == 0.0:
        return 0
    margin = g.scalars[MARGIN]
    touch = pairs_may_touch(g.pred, e, g.screen[1], g.pair_clearance, g.pair_weights, margin, g.tmp)
    return NEEDS_PYTHON if touch else 0


class SelfCollision(GuardCheck):
    """A listed collision pair in contact at the predicted state (coal): held. Not for a
    floating-base robot (:data:`HOLDS`): its legs pass close in every stride and brush in a
    recovery step, and a target held mid-stride lays a walking robot down, a response worse than
    the brush it answers; the violation monitor counts its true contacts by pair."""

    name = "self_collision"
    what = "a target in self-collision: held"
    kernel = self_collision_kernel

    def constants(self, guard) -> np.ndarray:
        """Row ``HOLDS``: 1.0 where the check holds a target in self-collision, 0.0 where it does
        not act (:meth:`~sim2real.deploy.kinds.targets.DriveTargets.self_collision_row`)."""
        return guard.targets.self_collision_row(guard.robot.n_joints)

    def reference(self, stage, g, out, q, dq, commanded):
        if stage != PREDICTED or not g._has_pairs or self.constants(g)[HOLDS, 0] == 0.0:
            return None, None
        check = np.zeros(g.envs, dtype=bool)
        moved = np.abs(g._pred - g._col_q)  # rad per joint since the last check
        for p, weights in enumerate(g.pair_weights):
            np.multiply(moved, weights, out=g._tmp)
            np.sum(g._tmp, axis=1, out=g._move)
            check |= g._pair_clearance[:, p] <= g._move + g.screen_margin
        return None, check

    def resolve(self, g, k, needs, q, dq, out) -> None:
        for e in np.flatnonzero(needs & ~g._held):
            if g._in_collision(g._pred[e], cache=e):
                g.reject(k, e, q[e], dq[e], out)


@numba.njit(cache=True, nogil=True, _nrt=False)
def effort_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`Effort`'s compiled share; ``own[0]`` the gravity bound (N m)."""
    n = out.shape[1]
    lim, scale = g.lim, g.effort_scale
    if stage == PREDICTED:
        for j in range(n):
            if own[0, j] > lim[EFFORT, j] * scale[e, j]:
                return NEEDS_PYTHON
        return 0
    if stage == FINAL and g.mode == TORQUE:
        clamped = False
        for j in range(n):
            limit = lim[EFFORT, j] * scale[e, j]
            t = out[e, j]
            if t > limit or t < -limit:
                clamped = True
            out[e, j] = np_min(np_max(t, -limit), limit)
        return FIRED if clamped else 0
    return 0


class Effort(GuardCheck):
    """Gravity at the predicted state above the derated effort limit: held; in torque mode also
    a commanded torque above it: clamped (counted on its own)."""

    name = "effort"
    what = "a torque clamped to the derated effort limit"
    kernel = effort_kernel

    def constants(self, guard) -> np.ndarray:
        return np.array([guard.gravity_bound], dtype=np.float64)

    def reference(self, stage, g, out, q, dq, commanded):
        effort = g.robot.effort_limit
        if stage == PREDICTED:
            return None, (g.gravity_bound > effort * g.effort_scale).any(axis=1)
        if stage == FINAL and g.mode == "torque":
            limit = effort * g.effort_scale
            np.logical_or(out > limit, out < -limit, out=g._mask)
            clamped = g._mask.any(axis=1)
            np.clip(out, -limit, limit, out=out)
            return clamped, None
        return None, None

    def resolve(self, g, k, needs, q, dq, out) -> None:
        effort = g.robot.effort_limit
        for e in np.flatnonzero(needs & ~g._held):
            grav = pin.computeGeneralizedGravity(g.model, g.data, g._pred[e])
            if np.any(np.abs(grav) > effort * g.effort_scale[e]):
                g.reject(k, e, q[e], dq[e], out)
