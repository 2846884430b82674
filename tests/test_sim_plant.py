"""The MuJoCo plant: control modes, sensor model, motor heat, and refusal of bad states."""

import dataclasses

import mujoco
import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import (
    NonFiniteCommandError,
    SimBackend,
    SimulationDivergedError,
)


def run(plant, command, ticks):
    for _ in range(ticks):
        plant.read()
        plant.write(command)
        plant.advance()


def test_position_mode_holds_the_commanded_pose(arm3):
    plant = SimBackend(arm3, mode="position")
    target = np.array([[0.3, -0.4, 0.5]])
    run(plant, target, 400)  # 2 s
    np.testing.assert_allclose(plant.true_position(), target, atol=0.03)
    assert plant.time == pytest.approx(2.0)


def test_velocity_mode_tracks_the_commanded_velocity(arm3):
    plant = SimBackend(arm3, mode="velocity")
    run(plant, np.array([[0.5, -0.5, 0.5]]), 60)
    np.testing.assert_allclose(plant.true_velocity(), [[0.5, -0.5, 0.5]], atol=0.1)


def test_torque_mode_applies_the_commanded_torque(arm3):
    plant = SimBackend(arm3, mode="torque")
    q0 = plant.true_position()[0].copy()
    run(plant, arm3.gravity_torque(q0)[None], 200)  # gravity compensation: the arm stays put
    np.testing.assert_allclose(plant.true_position()[0], q0, atol=0.02)
    np.testing.assert_allclose(plant.joint_torque()[0], arm3.gravity_torque(q0), rtol=1e-9)


def test_encoder_noise_sigma_matches_configuration(arm3):
    plant = SimBackend(arm3, mode="position", seed=1)
    plant.noise_sigma[:] = 0.01
    errors = []
    for _ in range(10_000):
        frame = plant.read()
        errors.append(frame.position[0] - plant.true_position()[0])
        plant.write(arm3.home[None])
        plant.advance()
    sigma = np.std(np.array(errors), axis=0)
    np.testing.assert_allclose(sigma, 0.01, rtol=0.05)


def test_readings_are_quantized_to_the_encoder_resolution(arm3):
    plant = SimBackend(arm3)
    quantum = 2 * np.pi / arm3.config.sensors.encoder_resolution
    counts = plant.read().position / quantum
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)


def test_latency_delays_readings_by_exactly_the_configured_ticks(arm3):
    plant = SimBackend(arm3, mode="velocity")
    plant.noise_sigma[:] = 0.0
    plant.latency_ticks[:] = 3
    plant.reset()  # sensor settings apply from the next sample on
    quantum = 2 * np.pi / arm3.config.sensors.encoder_resolution
    truth, times = [], []
    for k in range(40):
        frame = plant.read()
        truth.append(np.round(plant.true_position()[0] / quantum) * quantum)
        times.append(plant.time)
        if k < 3:
            assert np.isnan(frame.position).all()  # nothing has arrived yet
        else:
            np.testing.assert_array_equal(frame.position[0], truth[k - 3])
            np.testing.assert_array_equal(frame.position_stamp[0], times[k - 3])
            assert not np.array_equal(frame.position[0], truth[k])  # the arm moves
        plant.write(np.array([[1.0, -1.0, 1.0]]))
        plant.advance()


def test_dropout_frequency_matches_configuration(arm3):
    plant = SimBackend(arm3, seed=3)
    p, ticks = 0.1, 10_000
    plant.dropout_probability[:] = p
    lost = 0
    for _ in range(ticks):
        frame = plant.read()
        lost += int(np.isnan(frame.position).sum())
        assert np.array_equal(np.isnan(frame.position), np.isnan(frame.position_stamp))
        plant.advance()
    n = ticks * arm3.n_joints - arm3.n_joints  # the very first frame was sampled before the change
    se = np.sqrt(p * (1 - p) / n)
    assert abs(lost / n - p) < 3 * se


def test_sensors_run_at_their_own_rates(arm3):
    sensors = arm3.config.sensors.model_copy(update={"encoder_rate": 100.0})
    robot = dataclasses.replace(arm3, config=arm3.config.model_copy(update={"sensors": sensors}))
    plant = SimBackend(robot)
    assert plant.joint_sensors.encoder_every == 2  # a 100 Hz encoder under a 200 Hz control loop
    stamps, fresh = set(), []
    for _ in range(100):
        frame = plant.read()
        fresh.append(not np.isnan(frame.position).any())
        stamps.add(float(frame.temperature_stamp[0]))
        t = frame.winding_temperature
        np.testing.assert_array_equal(t, np.round(t))  # whole degrees, as drives report
        plant.advance()
    assert fresh[1::2] == [False] * 50 and fresh[2::2] == [True] * 49
    assert len(stamps) == 5  # 10 Hz temperature reports over 0.5 s


def test_non_finite_commands_never_reach_mujoco(arm3):
    plant = SimBackend(arm3, mode="velocity")
    plant.write(np.array([[0.2, 0.2, 0.2]]))
    with pytest.raises(NonFiniteCommandError, match="non-finite values in envs \\[0\\]"):
        plant.write(np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(ValueError, match="expected shape"):
        plant.write(np.zeros((1, 4)))
    plant.advance()
    assert np.isfinite(plant.datas[0].ctrl).all()
    np.testing.assert_allclose(plant.datas[0].ctrl, 0.2)  # the previous command stays in force


def test_divergence_raises_instead_of_silently_resetting(arm3):
    plant = SimBackend(arm3, mode="torque")
    assert plant.models[0].opt.disableflags & mujoco.mjtDisableBit.mjDSBL_AUTORESET
    plant.datas[0].qvel[:] = 1e12
    with pytest.raises(SimulationDivergedError, match="env 0: MuJoCo diverged"):
        plant.advance()


def test_batch_envs_are_independent_and_seeded(arm3):
    a = SimBackend(arm3, envs=3, seed=7)
    b = SimBackend(arm3, envs=3, seed=7)
    fa, fb = a.read().position.copy(), b.read().position.copy()
    np.testing.assert_array_equal(fa, fb)
    assert not np.array_equal(fa[0], fa[1])  # each env draws its own noise
    c = SimBackend(arm3, envs=3, seed=8)
    assert not np.array_equal(fa, c.read().position)


def test_arm3_held_horizontal_for_one_hour_reaches_the_thermal_steady_state(arm3):
    """maxon EC 45 flat 70 W + GP 42 C 113:1 (sim2real/robots/arm3/robot.toml): holding the arm stretched
    out horizontally for 1 simulated hour, the winding temperature must be within 1 % (of its rise
    over ambient) of the analytic steady state of the two-node model for the holding torque."""
    plant = SimBackend(arm3, mode="position")
    plant.reset(np.zeros(3))
    hold = np.zeros((1, 3))
    run(plant, hold, int(3600 / arm3.control_period))
    torque = plant.joint_torque()
    expected = plant.thermal.steady_state(torque)
    rise = expected - plant.thermal.ambient
    assert rise[0, 0] > 30.0  # the shoulder really heats up (about 60 K)
    np.testing.assert_array_less(np.abs(plant.thermal.winding_temperature - expected), 0.01 * rise)
    # and the drive reports it in whole degrees
    np.testing.assert_allclose(
        plant.read().winding_temperature, expected, atol=0.5 + 0.01 * rise.max()
    )


def test_a_hot_drive_limits_its_torque_to_the_derated_effort(arm3):
    """Above the derating start the drive's torque limit follows sim2real.robots.thermal.EffortDerating
    (down to the continuous torque at the maximum winding temperature): under a pull it cannot
    resist, the joint yields instead of the motor pushing past its derated limit."""
    plant = SimBackend(arm3, mode="velocity")
    plant.reset(np.zeros(3))
    plant.thermal.winding_temperature[0, 0] = 125.0
    plant.set_external_force(0, np.array([0.0, -30.0, 0.0]))  # 30 N down at the stretched arm
    run(plant, np.zeros((1, 3)), 20)
    continuous = arm3.motors[0].continuous_torque
    assert plant.effort_limit[0, 0] == pytest.approx(continuous, rel=0.02)
    assert abs(plant.joint_torque()[0, 0]) <= plant.effort_limit[0, 0] + 1e-9
    assert plant.true_velocity()[0, 0] < -0.05  # the shoulder gives way
    # cooled down, the drive has its peak torque again
    plant.set_external_force(0, np.zeros(3))
    plant.thermal.winding_temperature[0] = 25.0
    run(plant, np.zeros((1, 3)), 2)
    np.testing.assert_allclose(plant.effort_limit[0], arm3.effort_limit)


def test_a_sustained_pull_cannot_overheat_a_derating_drive(arm3):
    """A 15 N cable on the stretched arm held for 15 minutes (three times the soak's cable budget
    for its longest pull, 15 times that duration): the shoulder would need 22 N m, past its
    continuous rating. The drive derates, the winding settles below its 125 degC maximum, and the
    arm sags to where
    the continuous torque holds it, inside its soft limits."""
    plant = SimBackend(arm3, mode="position")
    plant.reset(np.zeros(3))
    plant.set_external_force(0, np.array([0.0, -15.0, 0.0]))
    run(plant, np.zeros((1, 3)), int(900 / arm3.control_period))
    peak = plant.thermal.winding_temperature[0, 0]
    assert 100.0 < peak < arm3.motors[0].max_winding_temperature
    q = plant.true_position()[0]
    assert q[0] < -0.2  # it did give way
    assert np.all(q > arm3.soft_lower) and np.all(q < arm3.soft_upper)


@pytest.mark.parametrize("per_env_streams", [False, True])
@pytest.mark.parametrize("name", ["arm6", "go2"])
def test_compiled_sensor_model_equals_its_numpy_reference(name, per_env_streams, request):
    """The encoder kernels give the numpy reference's readings and stamps bit for bit (the
    velocity reported with each angle too: go2's drives report one), and draw the same numbers
    from the streams, through changes of noise, dropout and latency."""
    from sim2real.deploy.backends.sim.reference import ReferenceJointSensorModel
    from sim2real.deploy.backends.sim.sensors import JointSensorModel
    from sim2real.deploy.core.backend import SensorFrame

    robot = request.getfixturevalue(name)
    envs, n = 3, robot.n_joints
    feet = robot.n_feet if robot.floating_base else None
    models = []
    for model in (JointSensorModel, ReferenceJointSensorModel):
        m = model(robot, envs, SensorFrame.empty(envs, n, feet), 7, max_latency_ticks=4)
        if per_env_streams:
            m.set_streams([np.random.default_rng(100 + e) for e in range(envs)])
        models.append(m)
    compiled, reference = models
    walk = np.random.default_rng(0)
    q = np.zeros((envs, n))
    for tick in range(3000):
        if tick % 250 == 0:  # new settings, as the fault injector and randomization set them
            sigma = walk.uniform(0.0, 0.01)
            for m in models:
                m.noise_sigma[:] = sigma
                m.dropout_probability[:] = [0.0, 0.2, 0.9][tick // 250 % 3]
                m.latency_ticks[:] = (tick // 250 + np.arange(envs)) % 5
        q += walk.normal(0.0, 0.01, q.shape)
        temperature = 25.0 + walk.uniform(0.0, 60.0, q.shape)
        compiled.read(tick)
        reference.read(tick)
        fields = ("position", "position_stamp", "winding_temperature", "temperature_stamp")
        fields += ("velocity",) if compiled.has_velocity else ()
        for field in fields:
            a, b = getattr(compiled.frame, field), getattr(reference.frame, field)
            np.testing.assert_array_equal(a, b, err_msg=f"{field} at tick {tick}")
        dq = walk.normal(0.0, 1.0, q.shape) if compiled.has_velocity else None
        compiled.sample(tick, tick * 0.002, q, temperature, dq)
        reference.sample(tick, tick * 0.002, q, temperature, dq)
    assert compiled.stream_state() == reference.stream_state()
    assert np.isnan(compiled.frame.position).any() and np.isfinite(compiled.frame.position).any()
    assert compiled.has_velocity == (name == "go2")


@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
@pytest.mark.parametrize("name", ["arm3", "arm6", "go2"])
def test_compiled_step_equals_its_python_reference(name, mode, request):
    """advance's compiled step (sim2real.deploy.backends.sim.plant_kernel) gives the states,
    readings and stream draws of its reference (Python calls per env) bit for bit: three envs,
    per-env streams, noise, dropout, latency, encoder bias, hot windings (derating, the velocity
    loop's anti-windup), a partial reset and a new model for an env."""
    from sim2real.deploy.backends.sim.reference import reference_advance

    robot = request.getfixturevalue(name)
    envs, plants = 3, []
    for _ in range(2):
        p = SimBackend(robot, mode=mode, envs=envs, seed=3)
        p.set_sensor_streams([np.random.default_rng(50 + e) for e in range(envs)])
        p.reset()
        p.dropout_probability[:] = 0.2
        p.latency_ticks[:] = [0, 1, 2]
        p.encoder_bias[:] = 0.002
        p.thermal.winding_temperature[:] = np.linspace(60.0, 140.0, envs)[:, None]
        plants.append(p)
    compiled, reference = plants
    base = compiled._command.copy()
    scale = {"position": 0.3, "velocity": 3.0, "torque": 2.0}[mode]
    for tick in range(120):
        if tick == 40:
            for p in plants:
                p.set_model(1, robot.plant_model(mode))
                p.reset(envs=np.array([False, True, False]))
        command = base + scale * np.sin(0.05 * tick + np.arange(robot.n_joints))
        for p in plants:
            p.read()
            p.write(command)
        compiled.advance()
        reference_advance(reference)
        a, b = compiled.state_dict(), reference.state_dict()
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=f"{key} at tick {tick}")
        np.testing.assert_array_equal(compiled.true_velocity(), reference.true_velocity())


def test_a_copied_plant_steps_its_own_data_as_the_original_does(arm6):
    """copy.deepcopy of a plant: the copy's compiled step names the copy's arrays and MjData
    (its table is rebuilt at its first advance); both continue the same, the original
    untouched by the copy."""
    import copy

    plant = SimBackend(arm6, envs=2, seed=1)
    plant.thermal.winding_temperature[:] = 120.0  # derating on
    run(plant, plant._command + 0.1, 5)
    twin = copy.deepcopy(plant)
    for p in (plant, twin):
        run(p, p._command + 0.01, 50)
    a, b = plant.state_dict(), twin.state_dict()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    assert twin.datas[0] is not plant.datas[0]


def test_the_true_base_is_each_plants_own_after_a_copy_and_a_new_model(go2):
    """``true_base_state`` reads the free joint of the plant's present ``MjData``: a copy's
    its own (not the original's nor a stale copy of it), and a new model's data once set."""
    import copy

    plant = SimBackend(go2, "position", envs=2, seed=4)
    command = np.tile(np.asarray(go2.home), (2, 1))

    def own(p):
        return np.stack([np.concatenate([d.qpos[:7], d.qvel[:6]]) for d in p.datas])

    run(plant, command, 3)
    np.testing.assert_array_equal(plant.true_base_state(), own(plant))
    twin = copy.deepcopy(plant)
    run(twin, command + 0.2, 20)  # the copy alone moves
    np.testing.assert_array_equal(twin.true_base_state(), own(twin))
    np.testing.assert_array_equal(plant.true_base_state(), own(plant))
    assert not np.array_equal(twin.true_base_state(), plant.true_base_state())
    plant.set_model(1, go2.plant_model("position"))
    plant.reset()
    run(plant, command, 2)
    np.testing.assert_array_equal(plant.true_base_state(), own(plant))


def test_kernel_arrays_are_the_live_arrays_of_their_models(arm3):
    """The compiled step keeps addresses: each model hands over its arrays, not copies."""
    plant = SimBackend(arm3)
    for model in (plant, plant.joint_sensors, plant.thermal, plant.actuators):
        a, b = model.kernel_arrays(), model.kernel_arrays()
        assert all(a[k] is b[k] and a[k].flags.c_contiguous for k in a)
    th = plant.thermal
    assert th.kernel_arrays()["winding_temperature"] is th.winding_temperature
    assert plant.kernel_arrays()["torque"] is plant.joint_torque()
    plant.write(np.full((1, arm3.n_joints), 0.1))
    np.testing.assert_array_equal(plant.kernel_arrays()["command"], 0.1)
    views = plant.env_views(0)
    assert views["data"] is plant.datas[0] and views["model"] is plant.models[0]
