"""Chain bounds: exact bounds of how far a robot's points move per radian of its joints, over all
configurations, from the MuJoCo model's chain of body offsets (facts about the robot, used below
both the plant and the guard).

:func:`motion_bounds` bounds any point's displacement and each joint's gravity torque,
:func:`end_effector_lever` and :func:`end_effector_reach` the end effector's displacement per
joint and its distance from the origin, :func:`gravity_bound` each joint's gravity torque (none
about a fixed vertical axis), :func:`holding_command_limit` the fastest command a fixed base's
motors can follow under gravity, :func:`collision_pair_weights` how fast each listed
collision pair approaches per radian of each joint, :func:`collision_pair_nesting` which of those
joints lie below which, :func:`axis_levers` the end effector's displacement per joint along each
world axis. The guard's screens
(:mod:`sim2real.deploy.safety.guard`), the motion envelope (:mod:`sim2real.deploy.safety.envelope`), the
violation monitor and the plant's derating floor are built on them.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.robots.robot import Robot


def chain_lengths(model: mujoco.MjModel) -> np.ndarray:
    """(nbody,) m, the length of the chain of body offsets from the world to each body's origin:
    an upper bound of its distance from the world origin in any configuration."""
    chain = np.zeros(model.nbody)
    for b in range(1, model.nbody):
        chain[b] = chain[model.body_parentid[b]] + np.linalg.norm(model.body_pos[b])
    return chain


def anchor_offset(model: mujoco.MjModel) -> float:
    """m, the largest offset of a joint's anchor from its body's origin (0 without joints): the
    chain bounds add it once for the joint a motion turns about."""
    return float(np.linalg.norm(model.jnt_pos, axis=1).max()) if model.njnt else 0.0


def descends(model: mujoco.MjModel, body: int, ancestor: int) -> bool:
    """Whether ``body`` is ``ancestor`` or below it in the kinematic tree (a joint of
    ``ancestor`` moves it)."""
    while body > 0:
        if body == ancestor:
            return True
        body = model.body_parentid[body]
    return False


def motion_bounds(robot: Robot, model: mujoco.MjModel | None = None) -> tuple[float, np.ndarray]:
    """Exact bounds of the screens, from the MuJoCo model at its nominal geometry.

    Args:
        robot: The robot (joint names).
        model: The MuJoCo model to bound; default ``robot.mj_model`` (nominal geometry). A
            randomized plant (``sim2real.eval.world.dynamics.randomized_model``) gives that plant's
            bounds.

    Returns:
        ``(sweep, gravity_bound)``: ``sweep`` (m/rad) bounds the displacement of any point of the
        robot (geometry, end effector) per unit of ``sum |dq_i|``: the longest chain of body
        offsets from the base to a point, plus joint anchor offsets and geometry radii.
        ``gravity_bound`` (n,) N m bounds each joint's gravity torque over all configurations:
        ``|g| sum_b m_b l_b`` over the bodies beyond the joint, ``l_b`` the chain length from the
        joint to the body's centre of mass.
    """
    m = robot.mj_model if model is None else model
    chain = chain_lengths(m)
    anchor = anchor_offset(m)
    reach = [
        chain[m.geom_bodyid[g]] + np.linalg.norm(m.geom_pos[g]) + m.geom_rbound[g]
        for g in range(m.ngeom)
    ]
    reach += [chain[m.site_bodyid[s]] + np.linalg.norm(m.site_pos[s]) for s in range(m.nsite)]
    sweep = float(max(reach)) + anchor
    g = float(np.linalg.norm(m.opt.gravity))
    bound = np.zeros(robot.n_joints)
    for i, name in enumerate(robot.joint_names):
        jb = m.jnt_bodyid[m.joint(name).id]
        for b in range(1, m.nbody):
            if descends(m, b, jb):
                lever = chain[b] - chain[jb] + np.linalg.norm(m.body_ipos[b]) + anchor
                bound[i] += m.body_mass[b] * lever
    return sweep, g * bound


def end_effector_lever(robot: Robot, model: mujoco.MjModel | None = None) -> np.ndarray:
    """(n,) m, bound of each joint's torque per newton of force on the end-effector site, over all
    configurations: the chain length from the joint's body to the site plus the joint anchor
    offset (the same chain bound as :func:`motion_bounds`).

    Args:
        robot: The robot (joint names, ``safety.end_effector_site``).
        model: The MuJoCo model; default ``robot.mj_model``.
    """
    m = robot.mj_model if model is None else model
    chain = chain_lengths(m)
    anchor = anchor_offset(m)
    site = m.site(robot.config.safety.end_effector_site).id
    tip = chain[m.site_bodyid[site]] + np.linalg.norm(m.site_pos[site])
    return np.array(
        [tip - chain[m.jnt_bodyid[m.joint(name).id]] + anchor for name in robot.joint_names]
    )


def end_effector_reach(robot: Robot, model: mujoco.MjModel | None = None) -> float:
    """m, bound of the end-effector site's distance from the world origin over all
    configurations: its chain of body offsets plus the joint anchor offset (the chain bounds of
    :func:`motion_bounds`). A workspace face farther out can never be crossed."""
    m = robot.mj_model if model is None else model
    site = m.site(robot.config.safety.end_effector_site).id
    chain = chain_lengths(m)
    return float(chain[m.site_bodyid[site]] + np.linalg.norm(m.site_pos[site]) + anchor_offset(m))


def collision_pair_weights(robot: Robot, model: mujoco.MjModel | None = None) -> np.ndarray:
    """(pairs, n) m/rad, for each pair of ``safety.collision_pairs`` (in that order): a bound of how
    fast its two geometries approach per radian of each joint.

    A joint upstream of both geometries (or of neither) moves them together: weight 0. A joint
    upstream of one moves that geometry's points by at most the chain length from the joint's
    body to the geometry's body, plus the geometry's offset and bounding radius and the joint
    anchor offset, per radian (the chain bounds of :func:`motion_bounds`). So the pair's distance
    changes by at most ``weights[p] @ |dq|`` when the joints move by ``dq``.

    Args:
        robot: The robot (collision pairs, joint names).
        model: The MuJoCo model; default ``robot.mj_model``.
    """
    m = robot.mj_model if model is None else model
    chain = chain_lengths(m)
    anchor = anchor_offset(m)
    joint_bodies = [m.jnt_bodyid[m.joint(name).id] for name in robot.joint_names]
    pairs = robot.config.safety.collision_pairs
    weights = np.zeros((len(pairs), robot.n_joints))
    for p, names in enumerate(pairs):
        geoms = [m.geom(name).id for name in names]
        bodies = [m.geom_bodyid[g] for g in geoms]
        for i, jb in enumerate(joint_bodies):
            moved = [descends(m, b, jb) for b in bodies]
            if moved[0] != moved[1]:
                g, b = (geoms[0], bodies[0]) if moved[0] else (geoms[1], bodies[1])
                offset = np.linalg.norm(m.geom_pos[g]) + m.geom_rbound[g]
                weights[p, i] = chain[b] - chain[jb] + offset + anchor
    return weights


def collision_pair_nesting(robot: Robot, model: mujoco.MjModel | None = None):
    """The order of the joints below one another along each pair's chain, for the local approach
    bounds of the motion envelope (:mod:`sim2real.deploy.safety.local_reach`).

    Args:
        robot: The robot (collision pairs, joint names).
        model: The MuJoCo model; default ``robot.mj_model``.

    Returns:
        ``(order, nest)``: ``order`` (n,) int64, the joints deepest body first (a joint's body
        below another's comes before it); ``nest`` (pairs, n, n) int8: for two joints ``j != k``
        that both move pair ``p`` (nonzero :func:`collision_pair_weights`), 1 where ``k``'s body
        lies strictly below ``j``'s (turning ``k`` moves the geometry ``j`` moves but not
        ``j``'s axis), 2 where both are on one body (either may come first), else 0.
    """
    m = robot.mj_model if model is None else model
    weights = collision_pair_weights(robot, m)
    bodies = [m.jnt_bodyid[m.joint(name).id] for name in robot.joint_names]
    depth = np.zeros(len(bodies), dtype=np.int64)
    for i, b in enumerate(bodies):
        while b > 0:
            b = m.body_parentid[b]
            depth[i] += 1
    order = np.argsort(-depth, kind="stable").astype(np.int64)
    nest = np.zeros((len(weights), len(bodies), len(bodies)), dtype=np.int8)
    for p, w in enumerate(weights):
        for j in np.flatnonzero(w > 0.0):
            for k in np.flatnonzero(w > 0.0):
                if k == j:
                    continue
                if bodies[k] == bodies[j]:
                    nest[p, j, k] = 2
                elif descends(m, bodies[k], bodies[j]):
                    nest[p, j, k] = 1
    return order, nest


def inertia_bound(robot: Robot, model: mujoco.MjModel | None = None) -> np.ndarray:
    """(n,) kg m^2, bound of each joint's own inertia (the diagonal of the joint-space mass matrix)
    over all configurations: its armature plus, over the bodies beyond the joint, each body's mass
    times its centre of mass's chain lever squared (the lever of :func:`motion_bounds`) plus the
    largest principal moment of its inertia.

    Args:
        robot: The robot (joint names).
        model: The MuJoCo model; default ``robot.mj_model``.
    """
    m = robot.mj_model if model is None else model
    chain = chain_lengths(m)
    anchor = anchor_offset(m)
    bound = np.zeros(robot.n_joints)
    for i, name in enumerate(robot.joint_names):
        j = m.joint(name).id
        jb = m.jnt_bodyid[j]
        bound[i] = m.dof_armature[m.jnt_dofadr[j]]
        for b in range(1, m.nbody):
            if descends(m, b, jb):
                lever = chain[b] - chain[jb] + np.linalg.norm(m.body_ipos[b]) + anchor
                bound[i] += m.body_mass[b] * lever**2 + float(m.body_inertia[b].max())
    return bound


#: Share of the velocity limit a joint's command keeps at least (our choice): where the motor
#: cannot hold its joint against gravity at half its velocity limit, the command keeps half of
#: it (a joint that may not be commanded at all could not be driven).
MIN_COMMAND_SHARE = 0.5


def fixed_axis(model: mujoco.MjModel, joint: int) -> bool:
    """Whether joint ``joint``'s axis keeps its direction in the world in every configuration: no
    joint above it in the tree (none on its body's ancestors, none before it on its body)."""
    body = model.jnt_bodyid[joint]
    if any(model.jnt_bodyid[k] == body for k in range(joint)):
        return False
    body = model.body_parentid[body]
    while body > 0:
        if model.body_jntnum[body]:
            return False
        body = model.body_parentid[body]
    return True


def gravity_bound(robot: Robot, model: mujoco.MjModel | None = None) -> np.ndarray:
    """(n,) N m, bound of each joint's gravity torque over all configurations: the bound of
    :func:`motion_bounds`, times ``|axis x g| / |g|`` (the sine of the angle between axis and
    gravity) for a joint whose axis keeps its direction in the world (:func:`fixed_axis`; a
    fixed base's first joint): the torque ``sum_b m_b (c_b - p) . (g x axis)`` is at most
    ``|g x axis| sum_b m_b |c_b - p|``, so a vertical axis carries none."""
    m = robot.mj_model if model is None else model
    bound = motion_bounds(robot, m)[1]
    g = np.asarray(m.opt.gravity, dtype=float)
    if not np.any(g):
        return bound
    data = mujoco.MjData(m)
    mujoco.mj_kinematics(m, data)
    for i, name in enumerate(robot.joint_names):
        j = m.joint(name).id
        if fixed_axis(m, j):
            axis = data.xaxis[j] / np.linalg.norm(data.xaxis[j])
            bound[i] *= min(1.0, float(np.linalg.norm(np.cross(axis, g))) / np.linalg.norm(g))
    return bound


def holding_speed(robot: Robot, model: mujoco.MjModel | None = None) -> np.ndarray:
    """(n,) rad/s, the fastest speed at which each joint's motor still has the torque to hold
    the joint against gravity: on its torque-speed line (:mod:`sim2real.robots.torque_speed`)
    ``w0 (1 - G / stall)``, ``w0`` the motor's no-load speed (``max_velocity``), ``stall`` its
    ``peak_torque``, ``G`` :func:`gravity_bound` (0 where ``G`` exceeds the joint's effort
    limit); ``inf`` for a motor without a no-load speed. A servo commanded faster falls behind
    its target under load and, once gravity turns with it, runs after the target with its full
    drive: gravity and that drive carry the joint past its no-load speed before the line's
    braking torque stops it."""
    gravity = gravity_bound(robot, model)
    out = np.full(robot.n_joints, np.inf)
    for i, motor in enumerate(robot.motors):
        w0, stall = motor.max_velocity, motor.peak_torque
        if w0 is not None and stall:
            held = gravity[i] <= robot.effort_limit[i]
            out[i] = float(w0) * max(0.0, 1.0 - gravity[i] / float(stall)) if held else 0.0
    return out


def holding_command_limit(robot: Robot) -> np.ndarray:
    """(n,) rad/s, the command velocity limit of a fixed-base robot whose motors can follow it
    under gravity: ``min(command, holding)`` (:func:`holding_speed`), at least
    :data:`MIN_COMMAND_SHARE` of the velocity limit. A joint with its own
    ``command_velocity_limit`` in robot.toml, and every joint of a floating-base robot (PD
    targets: the drive, not the target's speed, bounds the joint), keep theirs."""
    limit = np.asarray(robot.command_velocity_limit, dtype=float).copy()
    if robot.floating_base:
        return limit
    held = np.maximum(holding_speed(robot), MIN_COMMAND_SHARE * robot.velocity_limit)
    own = np.array([j.command_velocity_limit is not None for j in robot.config.joints])
    return np.where(own, limit, np.minimum(limit, held))


def axis_levers(robot, ee_lever: np.ndarray) -> np.ndarray:
    """(3, n) m/rad, bound of the end effector's displacement along world x, y, z per radian of
    each joint: ``ee_lever`` (n,), times ``|e_k x a_i|`` where joint ``i``'s axis ``a_i`` keeps
    its world direction in every configuration (every joint above it turns about a parallel
    axis; a rotation about ``a_i`` moves points perpendicular to it), else times 1."""
    m = robot.mj_model
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    ids = [m.joint(name).id for name in robot.joint_names]
    out = np.tile(np.asarray(ee_lever, dtype=float), (3, 1))
    for i, j in enumerate(ids):
        axis = d.xaxis[j] / np.linalg.norm(d.xaxis[j])
        body, invariant = m.jnt_bodyid[j], m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
        for k in range(m.njnt):
            if k == j or not invariant or not descends(m, body, m.jnt_bodyid[k]):
                continue
            if np.linalg.norm(np.cross(d.xaxis[k], axis)) > 1e-9 * np.linalg.norm(d.xaxis[k]):
                invariant = False
        if invariant:
            out[:, i] *= np.linalg.norm(np.cross(np.eye(3), axis), axis=1)
    return out
