"""The compiled lower bounds of the collision pairs' distances (sim2real.deploy.monitors.pair_bounds)
against coal's own distances, and the violation monitor that skips coal by them."""

from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest

from sim2real.deploy.monitors.pair_bounds import APART, PairBounds, pair_lower_bounds
from sim2real.deploy.monitors.violations import ViolationMonitor
from sim2real.deploy.safety.collision import collision_model
from sim2real.robots import load_robot
from sim2real.robots.chain_bounds import collision_pair_weights


def _bounds_and_distances(robot, poses: int, seed: int):
    """Per random pose within the joint limits: the bounds (pairs,) m, coal's distances (pairs,)
    m, whether coal finds a contact and whether the bounds say some pair may touch."""
    model = robot.fixed_base_model
    data = model.createData()
    geom_model, geom_data = collision_model(robot)
    bounds = PairBounds.build(model, geom_model)
    assert bounds is not None
    pairs, n = len(geom_model.collisionPairs), robot.n_joints
    checked, clearance = np.zeros((1, n)), np.zeros((1, pairs))
    weights = collision_pair_weights(robot)
    rng = np.random.default_rng(seed)
    for _ in range(poses):
        q = rng.uniform(robot.position_lower, robot.position_upper)[None]
        clearance.fill(-np.inf)  # none measured yet: every pair's bound measured at q
        near = pair_lower_bounds(q, *bounds.arrays(), weights, 1e-9, checked, clearance, APART, 0)
        assert np.array_equal(checked, q)
        hit = pin.computeCollisions(model, data, geom_model, geom_data, q[0], False)
        pin.computeDistances(geom_model, geom_data)
        distances = np.array([r.min_distance for r in geom_data.distanceResults])
        yield clearance[0] + APART, distances, hit, near


@pytest.mark.parametrize("name", ["go2", "so101", "h1"])
def test_each_bound_is_at_most_coals_distance_and_every_contact_is_near(name):
    """At random poses (many in contact), no pair's bound exceeds coal's distance by more than
    round-off (far below ``APART``), each contact coal finds is one the bounds call near, and
    go2's bounds, most of them of two capsules or spheres (their segments' distance), are
    mostly coal's distances."""
    robot = load_robot(name)
    excess, contacts, apart, slack = [], 0, 0, []
    for bound, distance, hit, near in _bounds_and_distances(robot, 400, 3):
        excess.append(np.max(bound - distance))
        slack.append(np.median(distance - bound))
        contacts += bool(hit)
        apart += not near
        assert near or not hit
    assert max(excess) < 1e-9 < APART
    assert contacts > 40 and apart > 40  # both kinds of pose were met
    if name == "go2":
        assert np.median(slack) < 1e-9


def test_coal_reports_contact_only_within_its_tolerance_far_below_apart():
    """``APART`` is 100 x coal's GJK tolerance, the request's own setting (read back)."""
    _, geom_data = collision_model(load_robot("go2"))
    assert geom_data.collisionRequests[0].security_margin == 0.0
    assert geom_data.collisionRequests[0].gjk_tolerance * 100 <= APART


def test_a_model_with_cylinders_has_no_bounds_and_is_checked_by_coal(arm3):
    """arm3's cylinders are not bounded: its monitor screens by coal's distances as before."""
    geom_model, _ = collision_model(arm3)
    assert PairBounds.build(arm3.fixed_base_model, geom_model) is None
    assert ViolationMonitor(arm3, 1)._pair_bounds is None


def test_a_walking_go2_is_screened_every_tick_without_coal(go2, monkeypatch):
    """Legs swinging through a trot (every joint, +-0.3 rad at 2 Hz, the diagonal pairs in
    phase) pass the joint-motion screen's bound every tick; the bounds keep coal out of every
    tick, and the monitor counts what the reference (coal on every pair each tick) counts."""
    from sim2real.deploy.monitors import violations
    from sim2real.deploy.monitors.reference import ReferenceViolationMonitor

    envs, n = 2, go2.n_joints
    q, dq, tau = np.tile(go2.home, (envs, 1)), np.zeros((envs, n)), np.zeros((envs, n))
    backend = SimpleNamespace(
        true_position=lambda: q, true_velocity=lambda: dq, joint_torque=lambda: tau,
        end_effector_position=lambda out: out,
    )  # fmt: skip
    ours, reference = ViolationMonitor(go2, envs), ReferenceViolationMonitor(go2, envs)
    queries, query = [0], violations.collision_query

    def counted(*args, **kwargs):
        queries[0] += 1
        return query(*args, **kwargs)

    monkeypatch.setattr(violations, "collision_query", counted)
    phase = np.repeat([0.0, np.pi, np.pi, 0.0], 3)  # FL, FR, RL, RR legs
    checks = 0
    for tick in range(300):
        t = tick * go2.control_period
        for e in range(envs):
            q[e] = go2.home + 0.3 * np.sin(2 * np.pi * 2.0 * t + phase + e)
        down = np.zeros(envs, dtype=bool)
        ours.update(backend, down=down)
        reference.update(backend, down=down)
        checks += int(ours._need.sum())
    a, b = ours.state_dict(), reference.state_dict()
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    assert checks > 0.8 * 300 * envs  # the joint-motion screen let most ticks through
    assert ours.counts["self_collision"].sum() == 0 and queries[0] == 0, queries
