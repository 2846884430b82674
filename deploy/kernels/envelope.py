"""Kernel of :class:`deploy.envelope.MotionEnvelope`: the joint box of each env's motion envelope
and the screens that say where Pinocchio must look.

The box of env ``e``, joint ``i`` spans the estimated position, the smoother's position before
and after the step, and the point where the joint comes to rest if the smoother brakes from its
new state (:func:`brake_reach`). ``centre`` and ``half`` (envs, n) are written for every env;
``need`` (2, envs) bool, rows collision and workspace, marks the envs whose cached distances
cannot certify their box.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: Rows of ``need``.
COLLISION, WORKSPACE = 0, 1


@numba.njit(cache=True, nogil=True, inline="always")
def brake_reach(v: float, a: float, amax: float, jmax: float) -> tuple[float, float]:
    """``(forward, back)`` rad: how far a joint at speed ``v`` (rad/s) and acceleration ``a``
    (rad/s^2) can still move along (``forward``) and against (``back``) its direction of motion
    while a jerk-limited brake (``amax``, ``jmax``) brings it to rest.

    Forward: the acceleration toward the motion is ramped down first (time ``a / j``, the speed
    rising by ``a^2 / 2j`` to ``v_eff``), then the brake from ``v_eff`` at zero acceleration,
    ``v_eff^2 / 2a + v_eff a / 2j`` (:func:`deploy.smoothing.braking.stopping_distance`). Back: an
    acceleration against the motion cannot be released at once and may carry the joint past rest
    by at most ``a^3 / (2 j^2)``. Direction: that of ``v``, or of ``a`` at rest.
    """
    s = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else (1.0 if a >= 0.0 else -1.0))
    speed = abs(v)
    toward = max(a * s, 0.0)
    against = max(-a * s, 0.0)
    v_eff = speed + toward * toward / (2.0 * jmax)
    forward = v_eff * toward / jmax + v_eff * v_eff / (2.0 * amax) + v_eff * amax / (2.0 * jmax)
    back = against * against * against / (2.0 * jmax * jmax)
    return s * forward, -s * back


@numba.njit(cache=True, nogil=True, inline="always")
def brake_headroom(scale: float, gravity_share: float, floor: float) -> float:
    """Fraction of the full deceleration a drive derated to ``scale`` (of its effort limit) still
    has: the torque left above the worst gravity load, ``(scale - g) / (1 - g)`` with ``g`` the
    gravity bound's share of the effort limit (the share of the limit the acceleration limits
    were sized from), clipped to ``[floor, 1]``."""
    if gravity_share >= 1.0:
        return max(min(scale, 1.0), floor)
    return max(min((scale - gravity_share) / (1.0 - gravity_share), 1.0), floor)


@numba.njit(cache=True, nogil=True)
def envelope_boxes(
    q: np.ndarray,
    before: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
    acc: np.ndarray,
    amax: np.ndarray,
    jmax: np.ndarray,
    effort_scale: np.ndarray,
    headroom: np.ndarray,
    centre: np.ndarray,
    half: np.ndarray,
    stop: np.ndarray,
) -> None:
    """The box of every env (module docstring): ``q`` (envs, n) estimated positions, ``before``
    (envs, n) the smoother's position before the step, ``pos``, ``vel``, ``acc`` (envs, n) its
    state after it; ``amax``, ``jmax`` (n,) the smoother's limits. The brake's deceleration is
    ``amax`` times the drive's torque headroom (:func:`brake_headroom` of ``effort_scale``
    (envs, n), the thermal derating, with ``headroom`` (2, n): the gravity bound's share of the
    effort limit, and the smallest headroom assumed). Writes ``centre``, ``half`` and ``stop``
    (envs, n), the rest point of the brake."""
    envs, n = q.shape
    for e in range(envs):
        for i in range(n):
            share = brake_headroom(effort_scale[e, i], headroom[0, i], headroom[1, i])
            forward, back = brake_reach(vel[e, i], acc[e, i], amax[i] * share, jmax[i])
            p = pos[e, i]
            stop[e, i] = p + forward
            lo = min(q[e, i], before[e, i], p, p + forward, p + back)
            hi = max(q[e, i], before[e, i], p, p + forward, p + back)
            centre[e, i] = 0.5 * (lo + hi)
            half[e, i] = 0.5 * (hi - lo)


@numba.njit(cache=True, nogil=True)
def envelope_screen(
    active: np.ndarray,
    centre: np.ndarray,
    half: np.ndarray,
    cached_q: np.ndarray,
    clearance: np.ndarray,
    weights: np.ndarray,
    margin: float,
    need: np.ndarray,
) -> bool:
    """Mark ``need[row, e]`` for the ``active`` envs whose box the cache cannot certify: with
    ``cached_q`` (2, envs, n) rad the configurations of the last exact computation (rows as
    ``need``), ``clearance`` (envs, pairs + 3) m its pair distances and, last, the end
    effector's margins inside the workspace box along x, y, z (``inf`` without a box),
    ``weights`` (pairs + 3, n) m/rad the pairs' approach bounds and, last, the end effector's
    levers along x, y, z. A quantity can shrink by at most ``weights @ (|centre - cached| +
    half)`` anywhere in the box. Returns whether any env needs an exact check."""
    envs, n = centre.shape
    rows = weights.shape[0]
    pairs = rows - 3
    any_need = False
    for e in range(envs):
        need[COLLISION, e] = False
        need[WORKSPACE, e] = False
        if not active[e]:
            continue
        for r in range(rows):
            row = WORKSPACE if r >= pairs else COLLISION
            if need[row, e]:
                continue
            reach = 0.0
            for i in range(n):
                if weights[r, i] != 0.0:
                    d = abs(centre[e, i] - cached_q[row, e, i]) + half[e, i]
                    reach += weights[r, i] * d
            if not (clearance[e, r] - reach > margin):  # NaN-safe: unknown means check
                need[row, e] = True
                any_need = True
    return any_need


def warm_up() -> None:
    """Compile (or load numba's cache of) the kernels on small arrays, outside any tick."""
    z = np.zeros((1, 2))
    ones = np.ones(2)
    envelope_boxes(
        z, z, z, z, z, ones, ones, np.ones((1, 2)), np.zeros((2, 2)), z.copy(), z.copy(), z.copy()
    )
    envelope_screen(
        np.ones(1, dtype=bool), z, z, np.zeros((2, 1, 2)), np.full((1, 4), math.inf),
        np.zeros((4, 2)), 0.0, np.zeros((2, 1), dtype=bool),
    )  # fmt: skip
