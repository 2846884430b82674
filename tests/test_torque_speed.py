"""The plant's motors follow their torque-speed line (sim2real.robots.torque_speed): a servo commanded far
away does not outrun its no-load speed, a hot winding lowers the line, the compiled range equals
its numpy reference in both quadrants, and pybullet's plant applies the same line."""

from pathlib import Path

import numpy as np
import pytest

from sim2real.deploy.backends.sim.drives_kernel import torque_speed_range
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.robots.torque_speed import TorqueSpeedEnvelope
from tests.runtime_fixtures import shipped_onnx


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
    from sim2real.deploy.backends.sim.bullet.plant import BulletBackend

    fastest = _fastest(BulletBackend(so101, mode="position"), so101)
    assert fastest.max() < 1.15 * so101.motors[0].max_velocity


def _so101_with_delay(tmp_path, delay: float):
    """The SO-101 with its STS3215 motor table in robot.toml, ``command_delay`` added."""
    import shutil

    from sim2real.robots import load_robot
    from sim2real.robots.loading import motor_catalog

    root = Path(__file__).resolve().parent.parent
    folder = tmp_path / f"so101_delay_{delay:g}"
    shutil.copytree(root / "sim2real" / "robots" / "so101", folder)
    # the catalog file as robot.toml's table (its sub-tables under it), the delay added
    motor = motor_catalog()["sts3215"].read_text().replace("\n[", "\n[motors.sts3215.")
    toml = folder / "robot.toml"
    toml.write_text(toml.read_text() + f"\n[motors.sts3215]\ncommand_delay = {delay}\n{motor}")
    return load_robot(str(toml))


def _first_moving_step(plant, robot, steps: int) -> int:
    """Physics steps after a 0.3 rad step of joint 0's position target before its actuator
    torque leaves the value that held the old target."""
    hold = np.asarray(robot.home, float)
    for _ in range(3):
        plant.write(hold[None])
        plant.advance()
    before = plant.joint_torque()[0, 0]
    target = hold.copy()
    target[0] += 0.3
    plant.write(target[None])
    for k in range(steps):
        plant.advance()
        if abs(plant.joint_torque()[0, 0] - before) > 0.05:
            return round(k * robot.decimation)
    return -1


def test_a_motor_file_command_delay_holds_the_command_back(so101, tmp_path):
    """A motor table's ``command_delay`` (s) delays the plant's response by that many control
    periods (here 3 periods of the SO-101's 10 ms), and leaves the description hash alone."""
    delayed = _so101_with_delay(tmp_path, 0.03)
    assert delayed.description_hash == so101.description_hash
    plant = SimBackend(delayed, mode="position")
    assert plant.actuators.delay_steps[0] == 3 * so101.decimation
    assert _first_moving_step(plant, delayed, 10) == 3 * so101.decimation
    assert _first_moving_step(SimBackend(so101, mode="position"), so101, 10) == 0
    state = plant.state_dict()
    assert state["actuators/history"].shape == (1, 4, so101.n_joints)


def test_a_session_draws_the_supply_voltage_only_when_its_range_is_set(so101, tmp_path):
    """``[dynamics] supply_voltage`` scales every motor's line by one draw per session; without
    it the draws are those of before (the supply is drawn last, and not at all when off)."""
    from dataclasses import replace

    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.soak.session import SessionConfig
    from sim2real.eval.world.dynamics import DynamicsRanges, sample_dynamics
    from sim2real.eval.world.session_ranges import session_ranges

    plain = sample_dynamics(so101, np.random.default_rng(3))
    drawn = sample_dynamics(so101, np.random.default_rng(3), DynamicsRanges(supply_voltage=0.2))
    assert replace(drawn, supply_voltage=plain.supply_voltage) == plain
    assert plain.supply == 1.0 and 0.8 <= drawn.supply <= 1.2 and drawn.supply != 1.0
    ranges = session_ranges(so101)
    ranges = replace(ranges, dynamics=replace(ranges.dynamics, supply_voltage=0.2))
    config = SessionConfig(
        robot="so101", policy=str(shipped_onnx("so101", tmp_path)), seed=4, hours=0.01
    )
    batch = SessionBatch([replace(config, ranges=ranges)], tmp_path / "soak", progress=False)
    supply = batch.backend.actuators.supply[0]
    assert 0.8 <= supply <= 1.2 and supply != 1.0
    assert batch.sessions[0].draw.dynamics.supply == supply  # what the session reports
    assert "supply_voltage" not in plain.to_dict()  # results and checkpoints as before


@pytest.mark.parametrize("name", ["so101", "go2", "h1", "h1_2"])
def test_full_torque_cannot_drive_a_joint_far_past_its_no_load_speed(name):
    """Every joint of a shipped robot commanded its peak torque (each sign) for 1 s: away from
    its stops, no joint runs faster than 1.8x its no-load speed (the other links' swing and
    gravity push past it; the motor only brakes there). Without the line they ran at
    2.6-7.3x."""
    from sim2real.robots import load_robot

    robot = load_robot(name)
    lo, hi = np.asarray(robot.position_lower) + 0.1, np.asarray(robot.position_upper) - 0.1
    peak = np.array([m.peak_torque for m in robot.motors])
    no_load = np.array([m.max_velocity for m in robot.motors])
    for sign in (1.0, -1.0):
        plant = SimBackend(robot, mode="torque")
        worst = 0.0
        for _ in range(int(round(1.0 / robot.control_period))):
            plant.write(sign * peak[None])
            plant.advance()
            q, dq = plant.true_position()[0], np.abs(plant.true_velocity()[0])
            free = (q > lo) & (q < hi)
            if free.any():
                worst = max(worst, float(np.max(dq[free] / no_load[free])))
        assert worst < 1.8, (name, sign, worst)
