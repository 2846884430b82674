"""The plant's motors follow their torque-speed line (robots.torque_speed): a servo commanded far
away does not outrun its no-load speed, a hot winding lowers the line, the compiled range equals
its numpy reference in both quadrants, and pybullet's plant applies the same line."""

import numpy as np
import pytest

from deploy.backends.sim.drives_kernel import torque_speed_range
from deploy.backends.sim.plant import SimBackend
from robots.torque_speed import TorqueSpeedEnvelope


def _fastest(plant, robot, seconds=0.5):
    """Largest true joint speed (rad/s) while position targets 1.5 rad off home are held."""
    target = np.asarray(robot.home) + np.where(np.arange(robot.n_joints) % 2 == 0, 1.5, -1.5)
    fastest = np.zeros(robot.n_joints)
    for _ in range(int(round(seconds / robot.control_period))):
        plant.write(target[None])
        plant.advance()
        fastest = np.maximum(fastest, np.abs(plant.true_velocity()[0]))
    return fastest


def test_the_stall_torque_follows_from_the_datasheet_constants(so101, go2):
    """w_0 k_t^2 N^2 eta / R: a servo's line starts at its (voltage-limited) stall torque, the
    Go2's outrunner at about twice its current-limited peak."""
    servo = TorqueSpeedEnvelope(so101.motors)
    assert servo.stall_coefficient[0] == pytest.approx(so101.motors[0].peak_torque, rel=0.01)
    legs = TorqueSpeedEnvelope(go2.motors)
    assert legs.stall_coefficient[0] == pytest.approx(51.8, rel=0.01)
    hot = legs.stall_torque(np.full(go2.n_joints, 90.0))
    assert hot[0] == pytest.approx(51.8 / (1 + 0.00393 * 65), rel=0.01)  # R rises with T


def test_a_servo_commanded_far_away_does_not_outrun_its_no_load_speed(so101):
    """Without the line the SO-101's unloaded joints reached 3-4x the STS3215's 4.71 rad/s; with
    it the fastest stays within 15 % of it (gravity and the joint stops add a little)."""
    fastest = _fastest(SimBackend(so101, mode="position"), so101)
    no_load = so101.motors[0].max_velocity
    assert fastest.max() < 1.15 * no_load
    assert fastest.max() > 0.7 * no_load  # it does move at about its no-load speed


def test_the_compiled_range_equals_the_numpy_reference_in_both_quadrants(go2):
    env = TorqueSpeedEnvelope(go2.motors)
    rng = np.random.default_rng(0)
    limit = np.array([m.peak_torque for m in go2.motors])
    for _ in range(200):
        velocity = rng.uniform(-1.5, 1.5, go2.n_joints) * env.no_load_speed
        temperature = rng.uniform(25.0, 90.0, go2.n_joints)
        lower, upper = env.limits(velocity, limit, temperature)
        out = np.zeros((go2.n_joints, 2))
        stall = env.stall_torque(temperature)
        torque_speed_range(velocity, limit, stall, env.no_load_speed, env.active, out)
        np.testing.assert_allclose(out[:, 0], lower, rtol=0, atol=1e-12)
        np.testing.assert_allclose(out[:, 1], upper, rtol=0, atol=1e-12)
    # driving with the motion: less than the peak past the knee; against it: the full peak
    v = 0.9 * env.no_load_speed
    lower, upper = env.limits(v, limit, np.full(go2.n_joints, 25.0))
    assert (upper < 0.25 * limit).all() and np.allclose(lower, -limit)


def test_a_motor_without_a_no_load_speed_keeps_its_effort_limit(arm3):
    env = TorqueSpeedEnvelope(arm3.motors)
    assert not env.any
    lower, upper = env.limits(np.full(3, 100.0), np.full(3, 5.0), np.full(3, 25.0))
    assert np.allclose(upper, 5.0) and np.allclose(lower, -5.0)


def test_pybullet_applies_the_same_line(so101):
    pytest.importorskip("pybullet")
    from deploy.backends.sim.bullet.plant import BulletBackend

    fastest = _fastest(BulletBackend(so101, mode="position"), so101)
    assert fastest.max() < 1.15 * so101.motors[0].max_velocity
