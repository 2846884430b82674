"""SafetyGuard: the screened checks give exactly the answers of checking every env every tick."""

import numpy as np
import pinocchio as pin
import pytest

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.safety.checks import CHECKS
from sim2real.deploy.safety.collision import collision_model
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.deploy.safety.reference import ReferenceGuard
from sim2real.deploy.smoothing import stopping_distance
from sim2real.robots import load_robot
from sim2real.robots.chain_bounds import collision_pair_weights, end_effector_lever, motion_bounds


def random_walk(robot, envs, ticks, seed):
    """Joint trajectories that wander over the whole range, in and out of every limit."""
    rng = np.random.default_rng(seed)
    lo, hi = robot.position_lower, robot.position_upper
    q = rng.uniform(lo, hi, (envs, robot.n_joints))
    for _ in range(ticks):
        dq = rng.normal(0.0, 1.5, q.shape) * robot.velocity_limit
        q = np.clip(q + dq * robot.control_period * 4, lo - 0.05, hi + 0.05)
        yield q.copy(), dq


@pytest.mark.parametrize("robot_name", ["arm3", "arm6"])
@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_screened_guard_equals_the_exhaustive_guard(request, robot_name, mode):
    robot = request.getfixturevalue(robot_name)
    envs = 8
    fast = SafetyGuard(robot, envs, mode)
    slow = ReferenceGuard(robot, envs, mode)  # numpy: reads its bounds every tick
    slow.sweep, slow.gravity_bound = 1e12, np.full(robot.n_joints, 1e12)  # check everything
    slow.ee_lever = np.full(robot.n_joints, 1e12)
    slow.pair_weights = np.full_like(slow.pair_weights, 1e12)
    checked = {"workspace": 0}
    ee_outside = slow._ee_outside

    def counting(q, cache=None):
        checked["workspace"] += cache is not None
        return ee_outside(q, cache)

    slow._ee_outside = counting
    state = RobotState.zeros(envs, robot.n_joints)
    rng = np.random.default_rng(1)
    hot = np.linspace(25.0, 124.0, envs)[:, None] * np.ones(robot.n_joints)  # some derated
    for q, dq in random_walk(robot, envs, 400, seed=0):
        state.q[:], state.dq[:] = q, dq
        for g in (fast, slow):
            g.update_thermal(hot)
        if mode == "position":
            target = q + rng.normal(0, 0.05, q.shape)
        elif mode == "velocity":
            target = rng.uniform(-1, 1, q.shape) * robot.velocity_limit
        else:
            target = rng.uniform(-1, 1, q.shape) * robot.effort_limit
        a = fast.filter(target.copy(), state)
        b = slow.filter(target.copy(), state)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(fast.hard_violation, slow.hard_violation)
    for check in CHECKS:
        np.testing.assert_array_equal(fast.counts[check], slow.counts[check], err_msg=check)
    # the walk exercised the geometric checks, so the equality above means something
    assert fast.totals()["workspace"] + fast.totals()["self_collision"] > 0
    # the slow guard checked every env every tick (but where the predicted configuration is the
    # one it last checked: a target clamped to the same limits twice)
    assert checked["workspace"] >= 0.99 * 400 * envs


def test_motion_bounds_bound_the_motion_and_gravity(arm6):
    sweep, gravity_bound = motion_bounds(arm6)
    lever = end_effector_lever(arm6)
    assert (lever <= sweep).all() and lever[-1] < lever[0]
    rng = np.random.default_rng(2)
    for _ in range(200):
        q = rng.uniform(arm6.position_lower, arm6.position_upper)
        dq = rng.normal(0, 0.05, arm6.n_joints)
        moved = np.linalg.norm(arm6.forward_kinematics(q + dq) - arm6.forward_kinematics(q))
        assert moved <= sweep * np.abs(dq).sum()
        assert moved <= lever @ np.abs(dq)  # the end effector's own, tighter, bound
        assert np.all(np.abs(arm6.gravity_torque(q)) <= gravity_bound + 1e-9)


@pytest.mark.parametrize("robot_name", ["arm6", "so101", "go2"])
def test_collision_query_answers_as_the_full_queries_at_q(robot_name):
    """:func:`collision_query` (the distances at the placements ``computeCollisions`` left)
    answers and measures as Pinocchio's two queries at ``q`` each, bit for bit: whether a pair
    touches, and each pair's distance where none does (all -inf where one does)."""
    from sim2real.deploy.safety.collision import collision_query

    robot = load_robot(robot_name)
    model = robot.fixed_base_model
    data = model.createData()
    geom_model, geom_data = collision_model(robot)
    mine = np.zeros(len(geom_model.collisionPairs))
    rng = np.random.default_rng(8)
    hits = 0
    for _ in range(300):
        q = rng.uniform(robot.position_lower, robot.position_upper)
        hit = collision_query(model, data, geom_model, geom_data, q, distances=mine)
        assert hit == bool(pin.computeCollisions(model, data, geom_model, geom_data, q, True))
        want = np.full_like(mine, -np.inf)
        if not hit:
            pin.computeDistances(model, data, geom_model, geom_data, q)
            want = np.array([r.min_distance for r in geom_data.distanceResults])
        assert np.array_equal(mine, want)
        hits += hit
    assert 0 < hits < 300


@pytest.mark.parametrize("robot_name", ["arm3", "arm6", "so101"])
def test_collision_pair_weights_bound_how_fast_each_pair_approaches(robot_name):
    """A pair's distance changes by at most ``weights[p] @ |dq|``; a joint upstream of both
    geometries of a pair (the base joint for every pair above it) has weight 0."""
    robot = load_robot(robot_name)
    weights = collision_pair_weights(robot)
    model = robot.fixed_base_model
    data = model.createData()
    geom_model, geom_data = collision_model(robot)
    assert weights.shape == (len(geom_model.collisionPairs), robot.n_joints)

    def distances(q):
        pin.computeDistances(model, data, geom_model, geom_data, q)
        return np.array([r.min_distance for r in geom_data.distanceResults])

    rng = np.random.default_rng(5)
    worst = 0.0
    for _ in range(200):
        q = rng.uniform(robot.position_lower, robot.position_upper)
        dq = rng.normal(0.0, 0.1, robot.n_joints)
        change = np.abs(distances(q + dq) - distances(q))
        bound = weights @ np.abs(dq)
        assert (change <= bound + 1e-9).all()
        worst = max(worst, float((change / bound).max()))
    assert worst > 0.2  # the bound is not vacuous
    assert (weights == 0.0).any() and (weights.max(axis=0) < 2.0 * motion_bounds(robot)[0]).all()


def test_collision_answers_do_not_depend_on_the_previous_query(arm6):
    """The guard's coal queries give the answer of a fresh query whatever came before: with
    Pinocchio's default warm start (the cached GJK guess of the last query) coal reported no
    contact for pairs penetrating by millimetres after a query at another configuration."""
    model = arm6.fixed_base_model
    data = model.createData()
    geom_model, geom_data = collision_model(arm6)
    rng = np.random.default_rng(7)
    lo, hi = arm6.position_lower, arm6.position_upper
    q = rng.uniform(lo, hi)
    hits = 0
    for _ in range(3000):  # a walk, as the guard queries: small and large steps
        q = np.clip(q + rng.normal(0.0, rng.choice([0.02, 0.5]), q.shape), lo, hi)
        reused = pin.computeCollisions(model, data, geom_model, geom_data, q, True)
        fresh_data = pin.GeometryData(geom_model)
        fresh = pin.computeCollisions(model, model.createData(), geom_model, fresh_data, q, True)
        assert reused == fresh, q.tolist()
        hits += fresh
    assert hits > 100


def test_velocity_band_leaves_room_to_brake_before_the_soft_limit(arm3):
    """Velocity mode: a target the guard lets through can still be braked to rest before the soft
    limit under the jerk limit, with the brake starting one control period later."""
    robot, envs = arm3, 64
    guard = SafetyGuard(robot, envs, "velocity")
    rng = np.random.default_rng(3)
    state = RobotState.zeros(envs, robot.n_joints)
    state.q[:] = rng.uniform(robot.soft_lower, robot.soft_upper, state.q.shape)
    target = rng.choice([-1.0, 1.0], state.q.shape) * robot.velocity_limit
    out = guard.filter(target.copy(), state)
    room = np.where(out > 0, robot.soft_upper - state.q, state.q - robot.soft_lower)
    need = np.abs(out) * robot.control_period + stopping_distance(
        out, robot.acceleration_limit, robot.jerk_limit
    )
    assert (need <= room + 1e-9).all()
    assert (np.abs(out) < robot.velocity_limit).any()  # the band did clamp
    assert not guard.hard_violation.any()


def test_a_full_absolute_action_is_at_the_limit_not_past_it():
    """An absolute position action of exactly +-1 (SB3 clips to the action space, so a policy
    outputs it often) maps to ``offset +- scale``; float rounding puts it an ulp past so101's
    wrist_roll and gripper limits. That is the limit itself: clamped, not a hard violation.
    A target really past the limit still is one."""
    from sim2real.deploy.spec.policy_spec import PolicySpec
    from sim2real.robots import load_robot

    so101 = load_robot("so101")
    spec = PolicySpec.for_robot(so101, mode="position", position_range="hard")
    state = RobotState.zeros(2, so101.n_joints)
    guard = SafetyGuard(so101, 2, "position")
    target = spec.action_to_target(np.array([[1.0] * 6, [-1.0] * 6]), state)
    assert (target > so101.position_upper).any() or (target < so101.position_lower).any()
    out = guard.filter(target, state)
    assert not guard.hard_violation.any()
    assert (out <= so101.soft_upper).all() and (out >= so101.soft_lower).all()
    target[0, 4] = so101.position_upper[4] + 1e-6
    guard.filter(target, state)
    assert guard.hard_violation.tolist() == [True, False]
