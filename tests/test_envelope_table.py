"""The motion envelope's pair tables (sim2real.deploy.safety.pair_grid): a lower bound of a pair's distance
over any box of the joints that move it, never above the true least distance there, looked up the
same by the compiled screen and the numpy reference; SO-101's pan sweeping past its base is no
longer braked, and a command that drives its upper arm into the base's margin still is."""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin
import pytest
from helpers_policies import target_policy

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.runtime import Runtime
from sim2real.deploy.safety import envelope_kernel as ek
from sim2real.deploy.safety.collision import collision_model
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.deploy.safety.pair_grid import PairTables, pair_grids, table_bound
from sim2real.robots import load_robot
from sim2real.robots.chain_bounds import collision_pair_weights


def _tabled(robot):
    """``(geometry, weights, apart, tables, pairs with a table)`` of ``robot``."""
    geometry = collision_model(robot)
    weights = collision_pair_weights(robot)
    apart, tables = pair_grids(robot, geometry, weights)
    return geometry, weights, apart, tables, np.flatnonzero(tables.offset[:, 0] >= 0)


def _boxes(rng, robot, count):
    """``count`` random boxes ``(centre, half)`` (n,) rad: centres across the range and a little
    past it, half-widths from a hundredth of a radian to the whole range."""
    lower, upper = np.asarray(robot.position_lower), np.asarray(robot.position_upper)
    n = robot.n_joints
    for _ in range(count):
        centre = rng.uniform(lower - 0.1, upper + 0.1)
        half = rng.choice([0.01, 0.05, 0.2, 1.0, 3.0]) * rng.random(n)
        yield centre, half


@pytest.mark.parametrize("name", ["so101", "arm6", "ur5"])
def test_a_tables_bound_never_exceeds_the_least_distance_over_the_box(name):
    """For random boxes (and boxes about each pair's closest grid point), no configuration
    sampled in the box, its corners included, lies closer than the table's bound."""
    robot = load_robot(name)
    geometry, weights, apart, tables, tabled = _tabled(robot)
    assert len(tabled) and not apart[tabled].any()
    geom_model, geom_data = geometry
    model = robot.fixed_base_model
    data = model.createData()
    rng = np.random.default_rng(0)
    n = robot.n_joints
    corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * n, indexing="ij")).reshape(n, -1).T
    boxes = list(_boxes(rng, robot, 150))
    lower, upper = np.asarray(robot.position_lower), np.asarray(robot.position_upper)
    informative = 0
    for p in tabled:
        for centre, half in boxes:
            bound = table_bound(tables, p, centre, half, weights[p])
            samples = np.concatenate([rng.uniform(centre - half, centre + half, (150, n)),
                                      centre + corners * half])  # fmt: skip
            least = np.inf
            for q in samples:
                pin.updateGeometryPlacements(model, data, geom_model, geom_data, q)
                least = min(least, pin.computeDistance(geom_model, geom_data, int(p)).min_distance)
            assert bound <= least, (name, p, centre, half, bound, least)
            informative += bound > 0.0
        # boxes about the closest point of a fine grid of the pair's joints
        joints = np.flatnonzero(weights[p] > 0)
        closest = np.asarray(robot.home, dtype=float).copy()
        best = np.inf
        for q in rng.uniform(lower, upper, (2000, n)):
            pin.updateGeometryPlacements(model, data, geom_model, geom_data, q)
            d = pin.computeDistance(geom_model, geom_data, int(p)).min_distance
            if d < best:
                best, closest[joints] = d, q[joints]
        for size in (0.003, 0.02, 0.1):
            half = np.full(n, size)
            bound = table_bound(tables, p, closest, half, weights[p])
            least = np.inf
            for q in rng.uniform(closest - half, closest + half, (300, n)):
                pin.updateGeometryPlacements(model, data, geom_model, geom_data, q)
                least = min(least, pin.computeDistance(geom_model, geom_data, int(p)).min_distance)
            assert bound <= least, (name, p, closest, size, bound, least)
    assert informative > 0  # the tables say something


@pytest.mark.parametrize("name", ["so101", "arm6"])
def test_the_compiled_lookup_equals_the_reference(name):
    """The screen's compiled lookup and the numpy reference give the same bound bit for bit,
    for boxes inside, across and past the grid, a box over the whole range, a NaN and an
    infinite box."""
    robot = load_robot(name)
    _, weights, _, tables, tabled = _tabled(robot)
    rng = np.random.default_rng(1)
    n = robot.n_joints
    boxes = list(_boxes(rng, robot, 400))
    boxes += [(np.zeros(n), np.full(n, 10.0)), (np.full(n, np.nan), np.zeros(n)),
              (np.zeros(n), np.full(n, np.inf))]  # fmt: skip
    for p in range(len(weights)):  # the pairs without a table: -inf from both
        for centre, half in boxes:
            ref = table_bound(tables, p, centre, half, weights[p])
            compiled = ek.table_bound(p, centre, half, weights[p], *tables.arrays())
            assert ref == compiled, (p, centre, half, ref, compiled)
            if p not in tabled:
                assert ref == -np.inf


def test_pair_grids_are_built_once_per_robot(so101):
    """A second guard of the same robot reuses the grids; the tables cannot be written."""
    geometry = collision_model(so101)
    weights = collision_pair_weights(so101)
    apart, tables = pair_grids(so101, geometry, weights)
    again, same = pair_grids(so101, geometry, weights)
    assert same is tables and (again == apart).all()
    again[:] = True  # the caller's copy
    assert (pair_grids(so101, geometry, weights)[0] == apart).all()
    with pytest.raises(ValueError):
        tables.values[0] = 1.0


def _pan_sweep(robot, target, ticks, tables=True):
    """Run ``robot`` in the simulator with a policy that holds ``target`` (n,) rad but swings
    the shoulder pan between -1.2 and 1.2 rad every second; ``tables=False`` runs the envelope
    without its pair tables and without its local approach bounds (the speeds read as the
    global weights: the chain bound alone). Returns ``(self-collision interventions,
    least true base / upper-arm distance (m), the pan's span (rad), the envelope)``."""

    def target_at(n):
        t = np.array(target, dtype=np.float64)
        t[0] = 1.2 if (n // 100) % 2 else -1.2
        return t

    policy = target_policy(robot, target_at)
    plant = SimBackend(robot, mode="position", envs=1, seed=0)
    rt = Runtime(robot, policy, plant)
    env = rt.guard.envelope
    if not tables:
        env.tables = PairTables.empty(env.pairs)
        chain = env.weights[: env.pairs].copy()
        env.local.speeds = lambda q: chain.copy()
    pair = [tuple(p) for p in robot.config.safety.collision_pairs].index(
        ("base_link", "upper_arm_link")
    )
    least, pans = [np.inf], []

    def on_tick(r):
        q = plant.true_position()[0]
        pans.append(q[0])
        least[0] = min(least[0], env.distances(q)[pair])

    rt.start()
    rt.run(ticks, on_tick=on_tick)
    braked = int(rt.guard.counts["self_collision"].sum())
    return braked, least[0], max(pans) - min(pans), env


@pytest.mark.parametrize("lift", [-0.6, 0.6])
def test_the_shoulder_pan_swinging_past_the_base_is_not_braked(so101, lift):
    """The base is nearly symmetric about the pan axis: the pan's chain bound (0.2 m/rad) says
    the upper arm may close on it fast, the table that it hardly does. With the shoulder lift
    held and the pan swinging, the chain bound alone brakes most ticks and the pan never reaches
    its targets; with the table it is hardly braked and swings the whole way."""
    target = np.asarray(so101.home, dtype=float).copy()
    target[1] = lift
    before, _, span_before, _ = _pan_sweep(so101, target, 600, tables=False)
    after, least, span, env = _pan_sweep(so101, target, 600)
    assert before > 200
    assert after * 20 < before
    assert span > 2.3 > span_before
    assert least > env.margin


def test_an_upper_arm_driven_into_the_bases_margin_is_still_braked(so101):
    """With a 2 cm clearance margin, a policy lifting the upper arm to its soft limit with the
    elbow folded, the pan swinging, would bring it within 7 mm of the base: the envelope brakes
    it at the margin (up to the estimate's error), table or not."""
    cfg = so101.config
    safety = cfg.safety.model_copy(update={"clearance_margin": 0.02})
    robot = dataclasses.replace(so101, config=cfg.model_copy(update={"safety": safety}))
    target = np.asarray(so101.home, dtype=float).copy()
    target[1], target[2] = so101.soft_upper[1], -1.14
    braked, least, _, env = _pan_sweep(robot, target, 600)
    assert env.margin == 0.02
    assert braked > 100
    assert least > env.margin - 0.002


def test_a_box_only_the_table_certifies_is_safe_and_a_brake_into_the_margin_is_not(so101):
    """The pan turning fast with the lift held: the chain bound cannot certify the box of the
    base and the upper arm (the envelope then cuts the path into segments), its table can; the
    lift rising fast toward its limit, where the upper arm comes within a millimetre of the base,
    is unsafe and brakes the lift and the pan."""
    guard = SafetyGuard(so101, 1, "position")
    env = guard.envelope
    n = so101.n_joints
    zero = np.zeros((1, n))
    full = np.ones((1, n))
    moving = np.zeros(1, dtype=bool)
    pose = np.asarray(so101.home, dtype=float)[None].copy()
    pose[0, 1] = -0.6
    speed = zero.copy()
    speed[0, 0] = 4.0
    state = np.stack([pose, speed, zero])
    assert not env.check(pose, state, state, moving, full)
    centre, half = env._box[0, 0], env._box[1, 0]  # the box the envelope certified
    chain = env.distances(centre)[0] - env.weights[0] @ half
    assert table_bound(env.tables, 0, centre, half, env.weights[0]) > env.margin >= chain
    guard = SafetyGuard(so101, 1, "position")
    env = guard.envelope
    pose[0, :2] = so101.position_upper[0] - 0.05, so101.position_upper[1] - 0.1
    speed[0, :2] = 0.0, 3.0
    state = np.stack([pose, speed, zero])
    assert env.check(pose, state, state, moving, full)
    assert env.unsafe[0, 0]
    assert env.joints[0, :2].all()
