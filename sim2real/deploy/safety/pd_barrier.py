"""The guard's ``pd_barrier`` check: a PD target judged by its consequence, not by its value.

A robot whose drives run a PD law on a position target (the PD joints of its kind's
:class:`~sim2real.deploy.kinds.targets.DriveTargets`: the legged robots') asks for torque with
its targets: ``tau = kp (target - q) - kd dq``, saturated by the drive. A target past the
joint's range is such a request (legged_gym, Isaac Lab and mjlab train without any bound on
them), and the drive takes it (a Unitree motor clamps no target). So the target passes
unchanged unless its consequence is unsafe: the joint's motion over the next control period,
predicted per joint (a control-barrier-function-style filter): the drive's PD law at every
physics substep, its torque saturated by the (derated) effort limit and the motor's
torque-speed line; the joint's least inertia (:func:`~sim2real.deploy.safety.leg_model.
least_inertia`, legs in the air), and for a joint on a loaded foot's chain moving toward the
limit also ``INERTIA_SPREAD`` times it, the target safe under both (a loaded joint whose motion
toward the limit drives its foot into the ground, :func:`~sim2real.deploy.safety.leg_model.
pressing_joints`, with ``INERTIA_SPREAD`` times it alone: its push lifts the body, as a Go2's
knee extending to climb a step); the gravity torque toward the limit at the estimate
(:func:`barrier_rows`: the estimated tilt, plus ``SLACK_SHARE`` of the all-pose bound, at most
that bound); semi-implicit Euler from the estimate ``(q, dq)``.

The prediction is unsafe when the joint passes the hard limit less a margin (``MARGIN_SHARE``
of the soft band; or, already past it, goes farther), or ends the period too fast to stop
before it with ``BRAKE_SHARE`` of its drive's braking (the effort limit less that gravity
torque): ``dq > sqrt(2 a_brake room)``. Then the target is changed as little as makes the
prediction safe (``BISECTIONS`` halvings between it and a target braking with the whole
effort). Each changed env and tick counts once (``pd_barrier``). The lower limit is the upper
one mirrored (``q, target, dq -> -q, -target, -dq``). Arms and servos whose firmware clamps
targets keep the soft-limit clamp (:mod:`sim2real.deploy.safety.limits`). Its numpy reference
and compiled function do the same operations in the same order (tests/test_pd_barrier.py).
Units: rad, rad/s, N m, kg m^2, s.
"""

from __future__ import annotations

import math
import operator

import numba
import numpy as np
import pinocchio as pin

from sim2real.deploy.kernels import np_max, np_min
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.safety.check import CLAMP, EFFORT, FIRED, POSITION, GuardCheck
from sim2real.deploy.safety.leg_model import (  # noqa: F401 - the barrier's names for them
    INERTIA_POSES,
    PRESS_LEVER,
    foot_chains,
    least_inertia,
    pressing_joints,
)
from sim2real.robots.continuous import continuous_mask
from sim2real.robots.torque_speed import TorqueSpeedEnvelope

#: Rows of the check's constants (n,) each: the PD gains (N m/rad, N m s/rad), 1 / inertia
#: (1/(kg m^2)), the gravity bound (N m), the stall torque (N m; inf without a torque-speed
#: line), the no-load speed (rad/s; inf without one), the upper bound ``upper - margin`` and the
#: mirrored lower bound ``-(lower + margin)`` (rad), the physics substep (s), the substeps per
#: period (left 0.0 on a robot without a PD joint in position mode: the check is off, as the
#: kernel and the per-tick preparation test with one scalar), and 1.0 where the check acts (0.0: an
#: arm's joint, or not position mode). ``GRAVITY`` is the
#: all-pose bound; the prediction uses the rows from ``TOWARD`` on (:func:`barrier_rows`).
KP, KD, INV_INERTIA, GRAVITY, STALL, NO_LOAD, BOUND_UP, BOUND_DOWN, STEP, SUBSTEPS, ACTIVE = range(
    11
)
#: Row of ``BRAKE_SHARE``, per joint.
BRAKE = 11
#: Row of ``SLACK_SHARE`` times ``GRAVITY`` (N m).
SLACK = 12
#: Row of 1 / (``INERTIA_SPREAD`` times the least inertia) (1/(kg m^2)): the heavier joint.
INV_HEAVY = 13
#: Rows of 1.0 where a joint's motion toward its upper (``PRESS_UP``) or lower (``PRESS_DOWN``)
#: limit drives its foot into the ground (:func:`pressing_joints`): on a loaded foot's chain it
#: lifts the body, not the leg, and is judged with the heavier inertia only.
PRESS_UP, PRESS_DOWN = 14, 15
ROWS = 16
#: Rows ``TOWARD + 2 e`` and ``TOWARD + 2 e + 1``: env ``e``'s gravity torque toward the upper
#: and toward the lower limit over the next period (N m, :func:`barrier_rows`), after ``ROWS``;
#: then, row ``TOWARD + 2 envs + e``: env ``e``'s joints on the chain of a foot in contact
#: (> 0.0; :func:`barrier_rows`), the ones judged with the heavier inertia too.
TOWARD = ROWS
#: Share of the soft band (between the soft and the hard limit) kept clear of the hard limit by
#: the predicted motion. Our choice: a quarter (0.026 rad on the Go2's hips, 0.011 rad on the
#: H1's hip yaw): above the estimate's noise, well inside the band.
MARGIN_SHARE = 0.25
#: Share of the drive's braking (effort limit less the gravity bound) a joint may need to stop
#: before the hard limit less the margin at the end of the predicted period. Our choice: half,
#: leaving the rest to what the 1-D prediction leaves out (the other joints' coupling, contacts).
BRAKE_SHARE = 0.5
#: Share of a joint's all-pose gravity bound added to its gravity torque at the estimate (our
#: choice): a quarter, what the joint's whole bound gives under a base acceleration of a quarter
#: of gravity or a pose 14 deg off the estimate's. The all-pose bound itself (the masses beyond
#: the joint at their longest lever) is no prediction where a joint's effort is barely above it:
#: judged with it, such a joint can never brake (a G1's waist: docs/measurements.md).
SLACK_SHARE = 0.25
#: The most a loaded leg joint's effective inertia may exceed its least one while it brakes, as
#: a factor: a joint on the chain of a foot in contact (the estimate's ``foot_contact``), a foot
#: rolling on its edge as it lifts off, moves as if heavier than the least inertia (the leg in
#: the air) says, and brakes worse. Such a joint moving toward its limit is predicted with the
#: least inertia and with this many times it, and a target must be safe under both (the least
#: inertia is the worst case of a target pushing toward the limit, the heavier one of a target
#: braking). Our choice: 3, above the 1.6-2.7 fitted at a G1 ankle's lift-off
#: (docs/measurements.md).
INERTIA_SPREAD = 3.0
#: Halvings of the bisection's bracket (its width, a few rad, to below 1e-9 rad).
BISECTIONS = 32


@numba.njit(cache=True, nogil=True, _nrt=False)
def _unsafe(t, q, v, hi, d, kp, kd, inv_i, effort, stall, no_load, h, steps, brake) -> bool:
    """Whether the PD target ``t`` carries the joint (``q`` rad, ``v`` rad/s; the upper side,
    bound ``hi``) past ``hi`` within the period or leaves it too fast to stop before it
    (module docstring); ``d`` the gravity torque toward the bound (N m), ``effort`` the
    (derated) effort limit, ``brake`` the braking deceleration (rad/s^2)."""
    top = q
    for _ in range(steps):
        tau = t - q
        tau = tau * kp
        damp = kd * v
        tau = tau - damp
        w = v / no_load
        up = np_min(effort, stall * (1.0 - w))
        lo = np_max(-effort, -(stall * (1.0 + w)))
        up = np_max(up, lo)
        tau = np_min(np_max(tau, lo), up)
        a = (tau + d) * inv_i
        v = v + a * h
        q = q + v * h
        top = np_max(top, q)
    room = np_max(hi - q, 0.0)
    return top > hi or v > math.sqrt(2.0 * brake * room)


@numba.njit(cache=True, nogil=True, inline="always")
def _barrier_one(t, q, v, hi, effort, d, j, own, inv_i, stuck) -> float:
    """The least change of target ``t`` that makes the upper side's prediction with inertia
    ``1 / inv_i`` safe (``t`` itself when it is); ``stuck`` when no target does: whether to
    brake with the whole effort (else ``t``)."""
    kp, kd = own[KP, j], own[KD, j]
    stall, no_load, h = own[STALL, j], own[NO_LOAD, j], own[STEP, j]
    steps = int(own[SUBSTEPS, j])
    brake = effort - d
    brake = brake * own[BRAKE, j]
    brake = np_max(brake, 0.0) * inv_i
    if not _unsafe(t, q, v, hi, d, kp, kd, inv_i, effort, stall, no_load, h, steps, brake):
        return t
    far = effort + effort
    far = far + kd * abs(v)
    far = far / kp
    far = q - far  # a target that brakes with the whole effort
    if t <= far or _unsafe(
        far, q, v, hi, d, kp, kd, inv_i, effort, stall, no_load, h, steps, brake
    ):
        return np_min(far, t) if stuck else t
    lo, up = far, t
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + up)
        if _unsafe(mid, q, v, hi, d, kp, kd, inv_i, effort, stall, no_load, h, steps, brake):
            up = mid
        else:
            lo = mid
    return lo


@numba.njit(cache=True, nogil=True, inline="always")
def _barrier(t, q, v, bound, effort, d, j, own, loaded, press) -> float:
    """The least change of target ``t`` that makes the upper side's prediction safe with the
    least inertia and, ``loaded`` and moving toward the bound, with the heavier one (``t``
    itself when it is); ``bound`` the upper bound, ``effort`` the derated effort limit, ``d``
    the gravity torque toward the bound (N m). Where no target keeps the heavier joint off the
    bound, its motion is not the drive's to stop within the period: the least inertia's answer
    stands. ``loaded`` and ``press`` (its motion toward the bound drives its foot into the
    ground: row ``PRESS_UP``): the heavier inertia's answer alone (the push lifts the body)."""
    hi = np_max(bound, q)  # past the bound already: no farther
    if loaded and press:
        return _barrier_one(t, q, v, hi, effort, d, j, own, own[INV_HEAVY, j], True)
    r = _barrier_one(t, q, v, hi, effort, d, j, own, own[INV_INERTIA, j], True)
    if loaded and v > 0.0:
        r = np_min(r, _barrier_one(t, q, v, hi, effort, d, j, own, own[INV_HEAVY, j], False))
    return r


@numba.njit(cache=True, nogil=True, _nrt=False)
def pd_barrier_kernel(stage, e, out, q, dq, commanded, has_commanded, g, own) -> int:
    """:class:`PdBarrier`'s compiled share (signature of :class:`GuardCheck`)."""
    if stage != CLAMP or g.mode != POSITION or own[SUBSTEPS, 0] == 0.0:
        return 0  # SUBSTEPS left 0: no PD joint (pd_barrier_constants)
    changed = False
    up, down = own[TOWARD + 2 * e], own[TOWARD + 2 * e + 1]
    loaded = own[TOWARD + 2 * out.shape[0] + e]
    for j in range(out.shape[1]):
        if own[ACTIVE, j] == 0.0:  # a joint whose drive follows its command: not a PD target
            continue
        t = out[e, j]
        effort = g.lim[EFFORT, j] * g.effort_scale[e, j]
        on = loaded[j] > 0.0
        press = own[PRESS_UP, j] > 0.0
        r = _barrier(t, q[e, j], dq[e, j], own[BOUND_UP, j], effort, up[j], j, own, on, press)
        if r == t:
            qj, vj, bound = -q[e, j], -dq[e, j], own[BOUND_DOWN, j]
            press = own[PRESS_DOWN, j] > 0.0
            r = -_barrier(-t, qj, vj, bound, effort, down[j], j, own, on, press)
        if r != t:
            changed = True
            out[e, j] = r
    return FIRED if changed else 0


def pd_barrier_constants(guard) -> np.ndarray:
    """(ROWS + 2 envs, n) float64: the check's constants for ``guard`` (module docstring), cached
    on it; the gravity rows from ``TOWARD`` on start at the all-pose bound and are rewritten in
    place every tick (:func:`barrier_rows`)."""
    cached = guard.__dict__.get("_pd_barrier_constants")
    if cached is not None:
        return cached
    robot = guard.robot
    n = robot.n_joints
    c = np.zeros((ROWS + 3 * guard.envs, n))
    active = guard.targets.barrier_joints(guard.mode)  # (n,) the PD joints in position mode
    if active.any():
        joints = robot.config.joints
        c[KP] = [j.kp for j in joints]
        c[KD] = [j.kd for j in joints]
        least = least_inertia(robot)
        c[INV_INERTIA] = 1.0 / least
        c[INV_HEAVY] = 1.0 / (INERTIA_SPREAD * least)
        c[PRESS_UP], c[PRESS_DOWN] = pressing_joints(robot)
        c[GRAVITY] = guard.gravity_bound
        envelope = TorqueSpeedEnvelope(robot.motors)
        c[STALL] = np.where(envelope.active, envelope.stall_coefficient, np.inf)
        c[NO_LOAD] = envelope.no_load_speed
        # a continuous joint (a wheel): no bound, +inf on both sides
        free = continuous_mask(robot.position_lower, robot.position_upper)
        with np.errstate(invalid="ignore"):
            margin = MARGIN_SHARE * (robot.position_upper - robot.soft_upper)
            c[BOUND_UP] = np.where(free, np.inf, robot.position_upper - margin)
            margin = MARGIN_SHARE * (robot.soft_lower - robot.position_lower)
            c[BOUND_DOWN] = np.where(free, np.inf, -(robot.position_lower + margin))
        c[STEP] = robot.physics_timestep
        c[SUBSTEPS] = robot.decimation
        c[ACTIVE] = active
        c[BRAKE] = BRAKE_SHARE
        c[SLACK] = SLACK_SHARE * guard.gravity_bound
        c[TOWARD : TOWARD + 2 * guard.envs] = guard.gravity_bound
    guard.__dict__["_pd_barrier_constants"] = c
    if c[ACTIVE].any():  # the rows' kernels compiled (or loaded) now, not at the first tick
        q = np.zeros((guard.envs, n))
        _bind_rows(guard, q, np.zeros((guard.envs, 3)), np.zeros((guard.envs, robot.n_feet)))
        _rows_model(guard)[4] = None
    return c


def barrier_rows(
    guard, q: np.ndarray, projected_gravity: np.ndarray | None, foot_contact: np.ndarray | None
) -> None:
    """Rewrite the rows of ``guard``'s constants that follow the estimate, every env's, from
    ``q`` (envs, n) rad, the base's ``projected_gravity`` (envs, 3; gravity's unit direction in
    the base frame; None: upright) and ``foot_contact`` (envs, n_feet) 1.0 or 0.0 (None: no foot
    is in contact):

    - the gravity rows (``TOWARD + 2 e`` and ``TOWARD + 2 e + 1``): each joint's gravity torque
      toward its upper and its lower limit, ``-G(q)`` and ``G(q)`` (Pinocchio's generalized
      gravity of the joints with gravity turned into the base frame: the floating-base model's,
      its base turned so that gravity points along ``projected_gravity``), plus ``SLACK_SHARE``
      of the all-pose bound, at most that bound; an env whose ``q`` or base direction is not
      finite keeps the bound;
    - the loaded rows (``TOWARD + 2 envs + e``): each joint's count of the feet in contact whose
      chain holds it (:func:`foot_chains`).

    Two compiled calls around Pinocchio's per env (:func:`_pose_env`, :func:`_rows_env`), bound
    to these arrays (made again for other arrays)."""
    model, data, config, torque, calls = _rows_model(guard)
    key = (q, projected_gravity, foot_contact)
    if calls is None or not all(map(operator.is_, key, calls[0])):
        calls = _bind_rows(guard, *key)
    _key, pose, rows = calls
    gravity = pin.computeGeneralizedGravity
    for e in range(q.shape[0]):
        pose(e)
        np.copyto(torque, gravity(model, data, config))
        rows(e)


def _rows_model(guard) -> list:
    """``guard``'s robot's Pinocchio model for :func:`barrier_rows` (the floating-base model for
    a floating base, else the fixed one), its data, a configuration (nq,) and a generalized
    gravity (nv,) of it, and the bound calls (None until the first); cached on the guard (a copy
    of the guard copies them together)."""
    cached = guard.__dict__.get("_pd_barrier_rows")
    if cached is None:
        robot = guard.robot
        free_flyer = robot.pin_model.nq != guard.model.nq  # the base's 7 coordinates
        model = pin.Model(robot.pin_model if free_flyer else guard.model)
        config = pin.neutral(model)
        cached = [model, model.createData(), config, np.zeros(model.nv), None]
        guard.__dict__["_pd_barrier_rows"] = cached
    return cached


def _bind_rows(guard, q, projected_gravity, foot_contact) -> tuple:
    """:func:`_pose_env` and :func:`_rows_env` bound to these arrays (stand-ins for None: the
    upright direction, no foot in contact), kept with them in the cache of :func:`_rows_model`."""
    cached = _rows_model(guard)
    c, envs = pd_barrier_constants(guard), q.shape[0]
    chains = foot_chains(guard.robot)
    floating = 1 if cached[2].shape[0] != c.shape[1] else 0  # a free-flyer in the model
    direction = projected_gravity
    if direction is None:
        direction = np.tile([0.0, 0.0, -1.0], (envs, 1))
    contact = foot_contact
    if contact is None or chains.shape[0] == 0:
        contact, chains = np.zeros((envs, 1)), np.zeros((1, c.shape[1]))
    config, torque = cached[2], cached[3]
    pose = bind(_pose_env, config, q, direction, floating, rest=(0,))
    rows = bind(_rows_env, torque, c, contact, chains, rest=(0,))
    cached[4] = ((q, projected_gravity, foot_contact), pose, rows)
    return cached[4]


@numba.njit(cache=True, nogil=True, _nrt=False)
def _pose_env(config, q, direction, floating: int, e: int) -> None:
    """Env ``e``'s configuration for :func:`barrier_rows`: its joints ``q[e]`` and, for a
    floating base (``floating``), the base at the origin turned so that world gravity points
    along ``direction[e]`` in its frame: the rotation ``R`` with ``R^T e_z = u = -direction[e]``,
    the quaternion ``(1 + u_z, u_y, -u_x, 0)`` (w, x, y, z) normalized, half a turn about x where
    that is zero (Pinocchio's order: x, y, z, w)."""
    start = config.shape[0] - q.shape[1]
    for j in range(q.shape[1]):
        config[start + j] = q[e, j]
    if floating:
        ux, uy, uz = -direction[e, 0], -direction[e, 1], -direction[e, 2]
        w = 1.0 + uz
        norm = math.sqrt(w * w + uy * uy + ux * ux)
        if norm == 0.0:
            config[3], config[4], config[5], config[6] = 1.0, 0.0, 0.0, 0.0
        else:
            config[3], config[4], config[5], config[6] = uy / norm, -ux / norm, 0.0, w / norm


@numba.njit(cache=True, nogil=True, _nrt=False)
def _rows_env(torque, c, contact, chains, e: int) -> None:
    """Env ``e``'s gravity rows from the generalized gravity ``torque`` (nv,) N m (its joints'
    part, the last n; the bound where any entry is not finite) and its loaded rows from
    ``contact[e]`` and ``chains`` (:func:`barrier_rows`)."""
    n = c.shape[1]
    offset = torque.shape[0] - n
    bound, slack = c[GRAVITY], c[SLACK]
    up, down = c[TOWARD + 2 * e], c[TOWARD + 2 * e + 1]
    finite = True
    for j in range(n):
        finite = finite and math.isfinite(torque[offset + j])
    for j in range(n):
        if finite:
            t = torque[offset + j]
            up[j] = min(slack[j] - t, bound[j])
            down[j] = min(slack[j] + t, bound[j])
        else:
            up[j] = down[j] = bound[j]
    envs = (c.shape[0] - TOWARD) // 3
    loaded = c[TOWARD + 2 * envs + e]
    for j in range(n):
        total = 0.0
        for f in range(chains.shape[0]):
            total += contact[e, f] * chains[f, j]
        loaded[j] = total


def _unsafe_np(t, q, v, hi, d, c, effort, brake, inv_i) -> np.ndarray:
    """:func:`_unsafe` for every env and joint at once ((envs, n) arrays; ``c`` the constants)."""
    kp, kd, stall, no_load, h = (c[r] for r in (KP, KD, STALL, NO_LOAD, STEP))
    top = q
    for _ in range(int(c[SUBSTEPS, 0])):
        tau = (t - q) * kp
        tau = tau - kd * v
        w = v / no_load
        up = np.minimum(effort, stall * (1.0 - w))
        lo = np.maximum(-effort, -(stall * (1.0 + w)))
        up = np.maximum(up, lo)
        tau = np.minimum(np.maximum(tau, lo), up)
        a = (tau + d) * inv_i
        v = v + a * h
        q = q + v * h
        top = np.maximum(top, q)
    room = np.maximum(hi - q, 0.0)
    return (top > hi) | (v > np.sqrt(2.0 * brake * room))


def _barrier_one_np(t, q, v, hi, effort, d, c, inv_i, stuck_brakes: bool) -> np.ndarray:
    """:func:`_barrier_one` for every env and joint at once."""
    kd, kp = c[KD], c[KP]
    brake = np.maximum((effort - d) * c[BRAKE], 0.0) * inv_i
    unsafe = _unsafe_np(t, q, v, hi, d, c, effort, brake, inv_i)
    if not unsafe.any():  # every target safe: itself, as the kernel returns it
        return t
    far = effort + effort
    far = far + kd * np.abs(v)
    far = q - far / kp
    stuck = (t <= far) | _unsafe_np(far, q, v, hi, d, c, effort, brake, inv_i)
    lo, up = far, t
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + up)
        over = _unsafe_np(mid, q, v, hi, d, c, effort, brake, inv_i)
        up = np.where(over, mid, up)
        lo = np.where(over, lo, mid)
    held = np.minimum(far, t) if stuck_brakes else t
    return np.where(unsafe, np.where(stuck, held, lo), t)


def _barrier_np(t, q, v, bound, effort, d, c, loaded, press) -> np.ndarray:
    """:func:`_barrier` for every env and joint at once (``d`` (envs, n) N m, ``loaded`` (envs,
    n) bool, ``press`` (n,) bool)."""
    hi = np.maximum(bound, q)
    r = _barrier_one_np(t, q, v, hi, effort, d, c, c[INV_INERTIA], True)
    heavy = _barrier_one_np(t, q, v, hi, effort, d, c, c[INV_HEAVY], False)
    r = np.where(loaded & (v > 0.0), np.minimum(r, heavy), r)
    pressed = _barrier_one_np(t, q, v, hi, effort, d, c, c[INV_HEAVY], True)
    return np.where(loaded & press, pressed, r)


class PdBarrier(GuardCheck):
    """A PD target whose predicted motion would reach the hard limit, or the soft band too fast
    to stop: changed as little as keeps the prediction safe (module docstring). Only for robots
    whose targets drive PD loops (``pd_targets``), in position mode."""

    name = "pd_barrier"
    what = "a PD target changed as little as keeps the joint's predicted motion off its hard limit"
    kernel = pd_barrier_kernel

    def constants(self, guard) -> np.ndarray:
        return pd_barrier_constants(guard)

    def prepare(self, g, state) -> None:
        if pd_barrier_constants(g)[SUBSTEPS, 0] != 0.0:  # a PD joint (a scalar test: per tick)
            base = state.base
            gravity = None if base is None else base.projected_gravity
            barrier_rows(g, state.q, gravity, state.foot_contact)

    def reference(self, stage, g, out, q, dq, commanded):
        c = pd_barrier_constants(g)
        if stage != CLAMP or g.mode != "position" or c[SUBSTEPS, 0] == 0.0:
            return None, None
        effort = g.robot.effort_limit * g.effort_scale
        envs = out.shape[0]
        up, down = c[TOWARD : TOWARD + 2 * envs : 2], c[TOWARD + 1 : TOWARD + 2 * envs : 2]
        on = c[TOWARD + 2 * envs : TOWARD + 3 * envs] > 0.0
        t = out.copy()
        r = _barrier_np(t, q, dq, c[BOUND_UP], effort, up, c, on, c[PRESS_UP] > 0.0)
        down = -_barrier_np(-t, -q, -dq, c[BOUND_DOWN], effort, down, c, on, c[PRESS_DOWN] > 0.0)
        r = np.where(r == t, down, r)
        r = np.where(c[ACTIVE] != 0.0, r, t)  # the PD joints only
        changed = (r != t).any(axis=1)
        out[:] = r
        return changed, None
