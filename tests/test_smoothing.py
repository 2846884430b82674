"""CommandSmoother: limits of the commands, sync to the measured state, faults, safe stop."""

import math

import numpy as np
import pytest

from sim2real.deploy.smoothing import (
    TORQUE_RISE_TIME,
    CommandSmoother,
    SmoothingError,
    stopping_distance,
    stopping_speed,
)
from sim2real.robots import load_robot

RTOL = 1e-6  # finite differences of Ruckig's samples meet the limits to rounding


@pytest.fixture(scope="module", params=["arm3", "arm6"])
def robot(request):
    return load_robot(request.param)


def random_targets(robot, mode, envs, ticks, seed, scale=1.2):
    """Policy-like targets: uniform[-1, 1] actions scaled to the mode's range (``scale`` > 1
    reaches past the limits), held for random spells, with per-tick jitter and a few NaN."""
    rng = np.random.default_rng(seed)
    n = robot.n_joints
    if mode == "position":
        centre = (robot.position_lower + robot.position_upper) / 2
        half = (robot.position_upper - robot.position_lower) / 2
    else:
        centre, half = 0.0, robot.velocity_limit
    out = np.empty((ticks, envs, n))
    action = rng.uniform(-1, 1, (envs, n))
    for k in range(ticks):
        change = rng.random((envs, 1)) < 0.01
        action = np.where(change, rng.uniform(-1, 1, (envs, n)), action)
        jitter = 0.02 * rng.uniform(-1, 1, (envs, n))
        out[k] = centre + scale * np.clip(action + jitter, -1, 1) * half
    out[rng.random((ticks, envs, n)) < 0.002] = np.nan
    return out


def derivatives(samples, dt):
    """Finite differences of a command sequence (ticks, envs, n): first, second, third."""
    d1 = np.diff(samples, axis=0) / dt
    d2 = np.diff(d1, axis=0) / dt
    return d1, d2, np.diff(d2, axis=0) / dt


def assert_within(values, limit, what):
    worst = float(np.max(np.abs(values) / limit))
    assert worst <= 1.0 + RTOL, f"{what} reaches {worst:.9f} x its limit"


@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_commands_respect_every_limit(robot, mode):
    envs, ticks, dt = 2, 2000, robot.control_period
    smoother = CommandSmoother(robot, envs, mode)
    smoother.reset(np.tile(robot.home, (envs, 1)), np.zeros((envs, robot.n_joints)))
    targets = random_targets(robot, mode, envs, ticks, seed=1)
    commands, positions = [smoother.command.copy()], [smoother.position.copy()]
    for k in range(ticks):
        commands.append(smoother.step(targets[k]).copy())
        positions.append(smoother.position.copy())
    commands, positions = np.array(commands), np.array(positions)
    lo, hi = robot.position_lower, robot.position_upper
    if mode == "position":
        v, a, j = derivatives(commands, dt)
        assert ((commands >= lo) & (commands <= hi)).all()
    else:
        v = commands
        a, j, _ = derivatives(commands, dt)
        # Ruckig integrates the velocity commands: that is where the joint goes
        assert ((positions >= lo) & (positions <= hi)).all()
        integrated = robot.home + np.cumsum(commands[1:], axis=0) * dt  # commands held a period
        assert ((integrated >= lo - 1e-3) & (integrated <= hi + 1e-3)).all()
    # commands keep the soft velocity limit: the margin to the hard limit is the servo's
    assert_within(v, robot.soft_velocity_limit, "velocity")
    assert_within(a, robot.acceleration_limit, "acceleration")
    assert_within(j, robot.jerk_limit, "jerk")
    assert np.isfinite(commands).all()
    assert (smoother.non_finite_targets == np.isnan(targets).sum(axis=(0, 2))).all()
    assert (smoother.target_clamps > 0).all()  # scale 1.2 asked for more than the limits
    assert np.abs(v).max() > 0.9 * robot.soft_velocity_limit.min()  # the test really moved


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_velocity_mode_stops_at_the_soft_limit(robot, direction):
    """Full speed toward a limit: the commanded trajectory brakes in time and comes to rest at the
    soft limit, leaving the margin to the hard limit to the drive's tracking error."""
    smoother = CommandSmoother(robot, 1, "velocity")
    n, dt = robot.n_joints, robot.control_period
    q0 = (robot.soft_upper - 1.0) if direction > 0 else (robot.soft_lower + 1.0)  # 1 rad away
    smoother.reset(q0[None], np.zeros((1, n)))
    positions = []
    for _ in range(int(3.0 / dt)):  # full speed toward the limit for 3 s
        smoother.step(direction * robot.velocity_limit[None])
        positions.append(smoother.position[0].copy())
    positions = np.array(positions)
    assert (positions <= robot.soft_upper + 1e-9).all()
    assert (positions >= robot.soft_lower - 1e-9).all()
    soft = robot.soft_upper if direction > 0 else robot.soft_lower
    np.testing.assert_allclose(positions[-1], soft, atol=1e-3)  # and gets close
    np.testing.assert_allclose(smoother.velocity, 0.0, atol=1e-3)
    assert (smoother.stopping_distance_clamps > 0).all()


def test_anchor_keeps_the_integrated_position_near_the_measured_joint(arm3):
    """A joint held back (a saturated drive) leaves Ruckig's integral ahead of it; the anchor
    pulls the integral back to within the tolerance without a jump in the velocity command, and
    the soft-limit brake then reads the joint's true room to its limit."""
    n, dt, tol = arm3.n_joints, arm3.control_period, 0.1
    smoother = CommandSmoother(arm3, 2, "velocity")
    q = np.tile(arm3.home, (2, 1))
    smoother.reset(q, np.zeros((2, n)))
    target = np.full((2, n), 1.0)
    for _ in range(100):  # 0.5 s at ~1 rad/s while the joints are held at q
        smoother.step(target)
    assert (smoother.position - q).min() > 0.3  # the integral ran away from the held joints
    before = smoother.command.copy()
    moved = smoother.anchor(q, tol)
    np.testing.assert_array_equal(moved, [1, 1])
    np.testing.assert_allclose(smoother.position, q + tol)
    np.testing.assert_allclose(smoother.tracking_error(q), [tol, tol])
    after = smoother.step(target).copy()
    assert np.abs(after - before).max() <= arm3.jerk_limit.max() * dt**2 + 1e-12  # continuous
    np.testing.assert_allclose(smoother.position, q + tol + after * dt, atol=1e-3)
    # within the tolerance nothing moves
    np.testing.assert_array_equal(smoother.anchor(smoother.position - 0.05, tol), [0, 0])
    # position mode re-syncs through tracking_error instead: anchor is a no-op there
    pos = CommandSmoother(arm3, 1, "position")
    pos.reset(q[:1], np.zeros((1, n)))
    held = pos.position.copy()
    np.testing.assert_array_equal(pos.anchor(q[:1] - 1.0, tol), [0])
    np.testing.assert_array_equal(pos.position, held)


@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_sync_starts_from_the_measured_state(robot, mode):
    n, dt = robot.n_joints, robot.control_period
    smoother = CommandSmoother(robot, 1, mode)
    q = (robot.home + 0.1)[None]
    dq = np.full((1, n), 0.5)
    smoother.reset(q, dq)
    target = (robot.home - 0.5)[None] if mode == "position" else np.full((1, n), -1.0)
    first = smoother.step(target).copy()
    jerk_step = robot.jerk_limit * dt**3 / 6  # acceleration starts at 0
    if mode == "position":
        assert (np.abs(first - (q + dq * dt)) <= jerk_step + 1e-12).all()
    else:
        assert (np.abs(first - dq) <= robot.jerk_limit * dt**2 / 2 + 1e-12).all()
    for _ in range(50):
        smoother.step(target)
    # the joint lags behind (measured state elsewhere): the runtime sees the drift and re-syncs
    measured_q, measured_dq = smoother.position - 0.05, np.zeros((1, n))
    np.testing.assert_allclose(smoother.tracking_error(measured_q), [0.05])
    smoother.sync(measured_q, measured_dq)
    assert smoother.tracking_error(measured_q)[0] == 0.0
    command = smoother.step(target)
    if mode == "position":
        assert (np.abs(command - measured_q) <= jerk_step + 1e-12).all()
    else:
        assert (np.abs(command) <= robot.jerk_limit * dt**2 / 2 + 1e-12).all()


def test_sync_of_some_envs_leaves_the_others_untouched(arm3):
    twin = CommandSmoother(arm3, 2, "position")
    smoother = CommandSmoother(arm3, 2, "position")
    for s in (smoother, twin):
        s.reset(np.tile(arm3.home, (2, 1)), np.zeros((2, 3)))
    target = np.tile(arm3.home + 0.4, (2, 1))
    for _ in range(20):
        smoother.step(target)
        twin.step(target)
    smoother.sync(np.zeros((2, 3)), np.zeros((2, 3)), envs=[1])
    a, b = smoother.step(target), twin.step(target)
    np.testing.assert_array_equal(a[0], b[0])
    # env 1 restarts from the (synced) zero pose, at rest: one jerk-limited step away
    assert np.abs(a[1]).max() <= arm3.jerk_limit.max() * arm3.control_period**3 / 6 + 1e-15


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_non_finite_target_holds_the_previous_target(arm3, mode, bad):
    smoother, twin = CommandSmoother(arm3, 1, mode), CommandSmoother(arm3, 1, mode)
    for s in (smoother, twin):
        s.reset(arm3.home[None], np.zeros((1, 3)))
    good = {"position": arm3.home + 0.3, "velocity": [1.0, -1.0, 0.5], "torque": [5.0, 1, 2]}
    target = np.array([good[mode]], dtype=float)
    for _ in range(10):
        smoother.step(target)
        twin.step(target)
    broken = target.copy()
    broken[0, 1] = bad
    for _ in range(30):
        a = smoother.step(broken)
        b = twin.step(target)  # what holding the previous target gives
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(smoother.non_finite_targets, [30])


def test_extrema_beyond_the_limit_are_clamped_and_counted(arm3):
    smoother = CommandSmoother(arm3, 1, "position")
    hi = arm3.position_upper
    q = np.array([[hi[0] - 0.02, 0.0, 0.0]])
    dq = np.array([[3.0, 0.0, 0.0]])  # too fast to stop within 0.02 rad
    smoother.reset(q, dq)
    commands = np.array([smoother.step(np.array([[hi[0], 0.0, 0.0]])).copy() for _ in range(300)])
    assert (commands <= hi).all()
    assert smoother.extrema_violations[0] > 0
    assert smoother.position[0, 0] == pytest.approx(hi[0])  # and it settles at the target


@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_safe_stop_reaches_rest_within_the_predicted_time(robot, mode):
    envs, n, dt = 3, robot.n_joints, robot.control_period
    smoother = CommandSmoother(robot, envs, mode)
    smoother.reset(np.tile(robot.home, (envs, 1)), np.zeros((envs, n)))
    rng = np.random.default_rng(4)
    if mode == "position":
        target = robot.home + rng.choice([-1.0, 1.0], (envs, n))
    else:
        target = rng.choice([-1.0, 1.0], (envs, n)) * robot.velocity_limit
    for _ in range(int(0.3 / dt)):  # get moving
        smoother.step(target)
    assert (np.abs(smoother.velocity) > 0.5).all()
    predicted = smoother.safe_stop(envs=[0, 2])
    assert smoother.stopping.tolist() == [True, False, True]
    assert predicted[1] == 0.0 and (predicted[[0, 2]] > 0).all()
    commands = [smoother.command.copy()]
    for _ in range(int(1.0 / dt)):
        commands.append(smoother.step(target).copy())  # targets of stopping envs are ignored
    commands = np.array(commands)
    settle = math.ceil(max(predicted) / dt - 1e-9)  # command k is the stop at k * dt
    if mode == "position":
        v, a, j = derivatives(commands, dt)
        moving = np.abs(v[settle:, [0, 2]])
    else:
        v = commands
        a, j, _ = derivatives(commands, dt)
        moving = np.abs(v[settle:, [0, 2]])
    assert moving.max() < 1e-9  # at rest from the predicted time on, and held
    assert np.abs(v[settle - 2, [0, 2]]).max() > 0  # not much earlier: the prediction is tight
    assert_within(v, robot.velocity_limit, "velocity")
    assert_within(a, robot.acceleration_limit, "acceleration")
    assert_within(j, robot.jerk_limit, "jerk")
    if mode == "position":
        assert ((commands >= robot.position_lower) & (commands <= robot.position_upper)).all()
    # env 1 kept following its target; a sync ends the stop
    smoother.sync(smoother.position, np.zeros((envs, n)))
    assert not smoother.stopping.any()


def test_safe_stop_with_none_targets(arm3):
    smoother = CommandSmoother(arm3, 1, "velocity")
    smoother.reset(arm3.home[None], np.zeros((1, 3)))
    for _ in range(40):
        smoother.step(np.array([[1.0, -1.0, 1.0]]))
    predicted = smoother.safe_stop()[0]
    for _ in range(math.ceil(predicted / arm3.control_period)):
        smoother.step(None)
    np.testing.assert_allclose(smoother.command, 0.0, atol=1e-12)


def test_torque_is_rate_and_effort_limited(robot):
    envs, n, dt = 2, robot.n_joints, robot.control_period
    smoother = CommandSmoother(robot, envs, "torque")
    q = np.tile(robot.home, (envs, 1))
    smoother.reset(q, np.zeros((envs, n)))
    np.testing.assert_allclose(smoother.command[0], robot.gravity_torque(robot.home))
    rng = np.random.default_rng(2)
    commands = [smoother.command.copy()]
    for k in range(1000):
        target = 1.5 * rng.choice([-1.0, 1.0], (envs, n)) * robot.effort_limit
        if k % 100 == 0:
            target[0, 0] = np.nan
        commands.append(smoother.step(target if k % 50 < 25 else 0.2 * target).copy())
    steps = np.abs(np.diff(np.array(commands), axis=0))
    rate = robot.effort_limit * dt / TORQUE_RISE_TIME
    assert (steps <= rate * (1 + 1e-12)).all()
    assert (np.abs(commands) <= robot.effort_limit).all()
    assert np.isclose(steps, rate).any()  # the limit was reached
    # a held target is reached within the rise time
    for _ in range(math.ceil(TORQUE_RISE_TIME / dt) * 2):
        smoother.step(np.full((envs, n), 0.5) * robot.effort_limit)
    np.testing.assert_allclose(smoother.command, np.full((envs, n), 0.5) * robot.effort_limit)


@pytest.mark.parametrize("mode", ["position", "velocity"])
def test_one_instance_equals_one_instance_per_env(arm3, mode):
    envs, n = 4, 3
    rng = np.random.default_rng(3)
    q = arm3.home + rng.uniform(-0.5, 0.5, (envs, n))
    dq = rng.uniform(-1, 1, (envs, n))
    batch = CommandSmoother(arm3, envs, mode)
    batch.reset(q, dq)
    singles = [CommandSmoother(arm3, 1, mode) for _ in range(envs)]
    for e, s in enumerate(singles):
        s.reset(q[e : e + 1], dq[e : e + 1])
    targets = random_targets(arm3, mode, envs, 500, seed=5)
    for k in range(500):
        together = batch.step(targets[k])
        for e, s in enumerate(singles):
            # equal to rounding, not bit for bit: Ruckig recalculates only when its input
            # changes, and a batch's input changes whenever any env's target does
            np.testing.assert_allclose(together[e], s.step(targets[k, e : e + 1])[0], atol=1e-12)


def test_stopping_speed_inverts_stopping_distance(arm3):
    v = np.linspace(0.0, 5.0, 101)
    a, j = 20.0, 400.0
    np.testing.assert_allclose(stopping_speed(stopping_distance(v, a, j), a, j), v, atol=1e-12)
    assert stopping_speed(-1.0, a, j) == 0.0


def test_errors(arm3):
    with pytest.raises(ValueError, match="control mode"):
        CommandSmoother(arm3, 1, "impedance")
    smoother = CommandSmoother(arm3, 2, "position")
    with pytest.raises(RuntimeError, match="reset"):
        smoother.step(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="finite"):
        smoother.reset(np.full((2, 3), np.nan), np.zeros((2, 3)))
    smoother.reset(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="shape"):
        smoother.step(np.zeros((1, 3)))
    # fault injection: limits Ruckig refuses
    smoother._inp.max_jerk = np.zeros(6)
    with pytest.raises(SmoothingError, match="Ruckig"):
        smoother.step(np.ones((2, 3)))
