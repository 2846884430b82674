"""Two-node motor thermal model and derating law."""

import numpy as np
import pytest

from sim2real.robots.chain_bounds import motion_bounds
from sim2real.robots.loading import load_motor, motor_catalog
from sim2real.robots.thermal import EffortDerating, TwoNodeThermalModel, derating_factor


def test_capacities_follow_the_datasheet_time_constants(arm3):
    model = TwoNodeThermalModel(arm3.motors, envs=1)
    # maxon EC 45 flat 70 W: tau_w = 43.1 s, R_wh = 6.64 K/W; tau_motor = 127 s, R_ha = 2.55 K/W
    np.testing.assert_allclose(model.c_w, 43.1 / 6.64)
    np.testing.assert_allclose(model.c_h, 127.0 / 2.55)


def test_integration_reaches_the_analytic_steady_state(arm3):
    model = TwoNodeThermalModel(arm3.motors, envs=2, ambient_temperature=[[25.0], [40.0]])
    torque = np.array([[9.0, 4.0, 0.5], [6.0, 6.0, 6.0]])
    for _ in range(int(3600 / 0.005)):
        model.step(torque, 0.005)
    np.testing.assert_allclose(model.winding_temperature, model.steady_state(torque), rtol=1e-6)
    # the hot winding loses more: the steady state is above the cold-resistance estimate
    cold = model.ambient + (torque / model.torque_per_amp) ** 2 * model.r_ref * (
        model.r_wh + model.r_ha
    )
    assert np.all(model.winding_temperature > cold)


def test_no_current_no_heat(arm3):
    model = TwoNodeThermalModel(arm3.motors, envs=1)
    for _ in range(1000):
        model.step(np.zeros((1, 3)), 0.005)
    np.testing.assert_array_equal(model.winding_temperature, 25.0)


def test_thermal_runaway_has_no_steady_state(arm3):
    model = TwoNodeThermalModel(arm3.motors, envs=1)
    with pytest.raises(ValueError, match="thermal runaway"):
        model.steady_state(np.full((1, 3), 1e3))


def test_derating_is_linear_between_start_and_maximum():
    t = np.array([20.0, 100.0, 112.5, 125.0, 150.0])
    np.testing.assert_allclose(derating_factor(t, 100.0, 125.0), [1.0, 1.0, 0.5, 0.0, 0.0])
    np.testing.assert_allclose(derating_factor(t, 100.0, 125.0, 0.4), [1.0, 1.0, 0.7, 0.4, 0.4])


def test_a_drive_derated_to_its_continuous_torque_cannot_overheat_its_motor(arm3, arm6):
    """The floor of the derating law is the continuous torque because its steady-state winding
    temperature at the datasheet's 25 degC ambient stays below the maximum; where the arm's weight
    needs more (arm6's stand-in motors), the floor holds the arm."""
    for robot in (arm3, arm6):
        model = TwoNodeThermalModel(robot.motors, envs=1, ambient_temperature=25.0)
        derating = EffortDerating(robot)
        hold = motion_bounds(robot)[1]
        assert np.all(
            EffortDerating(robot, hold).floor * derating.peak >= np.minimum(hold, derating.peak)
        )
        floor_torque = (derating.floor * derating.peak)[None]
        assert np.all(model.steady_state(floor_torque) < derating.maximum)
        # and the floor is what the law gives at and above the maximum
        hot = derating.factor(np.array([derating.maximum, derating.maximum + 30.0]))
        np.testing.assert_allclose(hot, np.vstack([derating.floor] * 2))


@pytest.mark.parametrize("name", sorted(motor_catalog()))
def test_every_catalog_motor_sustains_its_continuous_torque(name):
    """A continuous rating is the torque a motor holds forever at its maximum winding temperature
    in 25 degC air: the catalog's thermal constants must agree with it (within 2 K: sts3215's
    derivation left out copper's temperature coefficient, 1.3 K). GO-M8010-6's first estimates
    put that steady state at 404 degC: a standing Go2 overheated within minutes."""
    motor = load_motor(name)
    model = TwoNodeThermalModel([motor], envs=1, ambient_temperature=25.0)
    steady = model.steady_state(np.array([[motor.continuous_torque]]))
    assert steady[0, 0] <= motor.max_winding_temperature + 2.0, steady


def test_compiled_step_equals_the_numpy_reference_bit_for_bit():
    """go2's two motor models, 3 envs, 2,000 steps of random torques up to the peak."""
    from sim2real.robots import load_robot

    go2 = load_robot("go2")
    models = [TwoNodeThermalModel(go2.motors, envs=3, ambient_temperature=25.0) for _ in range(2)]
    models[1].ambient[1] = 35.0
    models[0].ambient[1] = 35.0
    for m in models:
        m.reset()
    rng = np.random.default_rng(0)
    for _ in range(2000):
        torque = rng.uniform(-1.0, 1.0, (3, go2.n_joints)) * go2.effort_limit
        models[0].step(torque, 0.02)
        models[1].step_reference(torque, 0.02)
    for name in ("winding_temperature", "housing_temperature", "current", "power"):
        np.testing.assert_array_equal(getattr(models[0], name), getattr(models[1], name))
    assert models[0].winding_temperature.max() > 40.0  # the motors did heat up
