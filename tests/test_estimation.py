"""JointStateEstimator: accuracy on the plant, time stamps, faults, and the filterpy reference."""

import tracemalloc

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.estimation.joints import JointStateEstimator
from sim2real.deploy.estimation.reference import ReferenceJointStateEstimator
from sim2real.robots import load_robot

#: the compiled estimator and its filterpy reference
ESTIMATORS = pytest.mark.parametrize(
    "estimator", [JointStateEstimator, ReferenceJointStateEstimator], ids=["compiled", "filterpy"]
)


def frame(time, position, stamp, envs=1, n=3, temperature=30.0):
    """A hand-made SensorFrame (envs, n): position and stamp broadcast."""
    f = SensorFrame.empty(envs, n)
    f.time[:] = time
    f.position[:] = position
    f.position_stamp[:] = stamp
    f.winding_temperature[:] = temperature
    f.temperature_stamp[:] = time
    return f


def sinusoid(robot, t):
    """A smooth position command within the acceleration limits: 0.5 rad at 0.5 Hz about home."""
    return (robot.home + 0.5 * np.sin(np.pi * t))[None, :]


def sinusoid_acceleration(robot, t0, t1):
    """(1, n) rad/s^2, mean acceleration of :func:`sinusoid` over [t0, t1]."""
    v = lambda t: 0.5 * np.pi * np.cos(np.pi * t) * np.ones(robot.n_joints)  # noqa: E731
    return ((v(t1) - v(t0)) / (t1 - t0))[None, :]


def test_compiled_kernel_equals_filterpy_reference_for_10000_ticks(arm3):
    envs = 2
    plant = SimBackend(arm3, mode="position", envs=envs, seed=7)
    plant.dropout_probability[:] = 0.1
    plant.latency_ticks[:] = [2, 3]
    plant.reset()
    fast = JointStateEstimator(arm3, envs)
    reference = ReferenceJointStateEstimator(arm3, envs)
    states = [RobotState.zeros(envs, 3), RobotState.zeros(envs, 3)]
    for est in (fast, reference):
        est.reset(plant.true_position(), 0.0)
    worst = dict(q=0.0, dq=0.0, P=0.0)
    dt = arm3.control_period
    for k in range(10_000):
        f = plant.read()
        u = sinusoid_acceleration(arm3, (k - 1) * dt, k * dt).repeat(envs, axis=0)
        u = None if k % 2 else u  # with and without the control input
        fast.update(f, states[0], u)
        reference.update(f, states[1], u)
        worst["q"] = max(worst["q"], np.abs(states[0].q - states[1].q).max())
        worst["dq"] = max(worst["dq"], np.abs(states[0].dq - states[1].dq).max())
        worst["P"] = max(worst["P"], np.abs(fast.covariance - reference.covariance).max())
        plant.write(sinusoid(arm3, k * arm3.control_period).repeat(envs, axis=0))
        plant.advance()
    assert max(worst.values()) <= 1e-9, worst
    # the stream really had dropouts and absorbed readings, and nothing degenerated
    assert (fast.missing_readings > 0.09 * 10_000 * 3).all()
    np.testing.assert_array_equal(fast.missing_readings, reference.missing_readings)
    np.testing.assert_array_equal(fast.stale_readings, reference.stale_readings)
    assert (fast.reinitializations == 0).all()


@ESTIMATORS
def test_commanded_acceleration_input_removes_the_lag(arm3, estimator):
    """With the commanded acceleration as control input the filter follows an accelerating joint
    instead of lagging behind it (a constant-velocity model lags by ~a / omega^2). Measured, mean
    absolute error: 18.9 mrad without the input, 4.7 mrad with it."""
    plant = SimBackend(arm3, mode="velocity", envs=2, seed=5)  # env 1: with the input
    plant.reset()
    est = estimator(arm3, 2)
    state = RobotState.zeros(2, 3)
    est.reset(plant.true_position(), 0.0)
    dt, err = arm3.control_period, []
    w = 2.0 * np.pi  # 0.5 rad at 1 Hz: peak acceleration 19.7 rad/s^2, the arm's limit is 20

    def velocity(t):
        return 0.5 * w * np.cos(w * t) * np.ones((2, 3))

    for k in range(600):
        f = plant.read()
        u = (velocity(k * dt) - velocity((k - 1) * dt)) / dt
        u[0] = 0.0
        est.update(f, state, u)
        if k >= 100:
            err.append(np.abs(state.q - plant.true_position()).mean(axis=1))
        plant.write(velocity(k * dt))
        plant.advance()
    without, with_input = np.mean(err, axis=0)
    assert with_input < 0.5 * without, (without, with_input)


@pytest.mark.parametrize("name", ["arm3", "arm6"])
def test_estimate_is_closer_to_the_truth_than_the_raw_encoder(name):
    robot = load_robot(name)
    n = robot.n_joints
    plant = SimBackend(robot, mode="position", seed=3)
    plant.dropout_probability[:] = 0.05
    est = JointStateEstimator(robot, 1)
    state = RobotState.zeros(1, n)
    est.reset(plant.read().position, 0.0)
    err_q, err_raw, err_dq, speed = [], [], [], []
    for k in range(2000):
        f = plant.read()
        est.update(f, state)
        if k >= 200:  # after the initial transient
            truth = plant.true_position()[0]
            err_q.append(state.q[0] - truth)
            err_dq.append(state.dq[0] - plant.true_velocity()[0])
            err_raw.append(f.position[0] - truth)  # NaN on dropouts
            speed.append(np.abs(plant.true_velocity()[0]).max())
        plant.write(sinusoid(robot, k * robot.control_period))
        plant.advance()
    rms_q = np.sqrt(np.mean(np.square(err_q)))
    rms_raw = np.sqrt(np.nanmean(np.square(err_raw)))
    rms_dq = np.sqrt(np.mean(np.square(err_dq)))
    # measured: arm3 7.6 vs 15.6 mrad, 0.20 rad/s; arm6 9.5 vs 15.8 mrad, 0.25 rad/s
    assert rms_q < 0.75 * rms_raw
    assert max(speed) > 1.2  # the joints really move (peak 1.57 rad/s)
    assert rms_dq < 0.35  # rad/s; a finite difference of the raw readings: ~4 rad/s


def test_latency_is_compensated_by_extrapolating_to_frame_time(arm3):
    plant = SimBackend(arm3, mode="velocity", seed=0)
    plant.noise_sigma[:] = 0.001
    plant.latency_ticks[:] = 3
    plant.reset()
    est = JointStateEstimator(arm3, 1, measurement_sigma=0.001)
    state = RobotState.zeros(1, 3)
    est.reset(plant.true_position(), 0.0)
    velocity = np.array([[0.5, 0.5, -0.5]])  # rad/s, constant
    err_est, err_raw, latest = [], [], None
    for k in range(400):
        f = plant.read()
        est.update(f, state)
        if np.isfinite(f.position).all():
            latest = f.position[0].copy()
        if k >= 200:
            truth = plant.true_position()[0]
            err_est.append(state.q[0] - truth)
            err_raw.append(latest - truth)
        plant.write(velocity)
        plant.advance()
    lag = np.abs(np.mean(err_raw, axis=0))  # 3 ticks x 5 ms x 0.5 rad/s = 7.5 mrad
    bias = np.abs(np.mean(err_est, axis=0))  # measured 0.0-0.2 mrad
    assert (lag > 0.006).all()
    assert (bias < 0.001).all()
    np.testing.assert_allclose(est.time_since_fresh, 3 * arm3.control_period)


def test_multi_rate_readings_track_a_constant_velocity(arm3):
    est = JointStateEstimator(arm3, 1)
    state = RobotState.zeros(1, 3)
    dt = arm3.control_period
    est.reset(np.full(3, 0.3), 0.0)
    for k in range(1, 400):
        t = k * dt
        truth = 0.3 + 1.0 * t
        if k % 4 == 0:  # an encoder at a quarter of the control rate, noise-free
            est.update(frame(t, truth, t), state)
        else:
            est.update(frame(t, np.nan, np.nan), state)
        if k > 200:
            np.testing.assert_allclose(state.q[0], truth, atol=2e-3)
            np.testing.assert_allclose(state.dq[0], 1.0, atol=0.05)
            assert est.time_since_fresh[0, 0] == pytest.approx((k % 4) * dt)


@ESTIMATORS
def test_dropout_predicts_only_and_time_since_fresh_grows(arm3, estimator):
    est = estimator(arm3, 1)
    state = RobotState.zeros(1, 3)
    dt = arm3.control_period
    est.reset(np.zeros(3), 0.0)
    for k in range(1, 50):  # moving at 0.2 rad/s
        est.update(frame(k * dt, 0.2 * k * dt, k * dt), state)
    x = est.position.copy(), est.velocity.copy(), est.covariance.copy(), est.filter_time.copy()
    missing = est.missing_readings.copy()
    for k in range(50, 60):  # every reading lost
        est.update(frame(k * dt, np.nan, np.nan), state)
        np.testing.assert_allclose(est.time_since_fresh, (k - 49) * dt)
        np.testing.assert_allclose(state.q, x[0] + (k - 49) * dt * x[1])  # prediction
        np.testing.assert_array_equal(state.dq, x[1])
    now = est.position, est.velocity, est.covariance, est.filter_time
    for before, after in zip(x, now, strict=True):
        np.testing.assert_array_equal(before, after)  # the filter state did not move
    np.testing.assert_array_equal(est.missing_readings, missing + 10 * 3)
    est.update(frame(60 * dt, 0.2 * 60 * dt, 60 * dt), state)  # a reading arrives again
    np.testing.assert_array_equal(est.time_since_fresh, 0.0)
    np.testing.assert_allclose(state.q, 0.2 * 60 * dt, atol=1e-3)
    assert (est.time_since_fresh < arm3.stale_limit).all()


@ESTIMATORS
def test_stale_reordered_and_future_readings_are_discarded_and_counted(arm3, estimator):
    est = estimator(arm3, 1)
    state = RobotState.zeros(1, 3)
    est.reset(np.zeros(3), 0.0)
    est.update(frame(0.010, 0.01, 0.010), state)
    est.update(frame(0.020, 0.02, 0.020), state)
    kept = est.position.copy(), est.velocity.copy(), est.covariance.copy()
    assert (est.stale_readings == 0).all()
    est.update(frame(0.030, 5.0, 0.015), state)  # older than the last absorbed reading
    est.update(frame(0.040, 5.0, 0.020), state)  # the same reading again
    est.update(frame(0.050, 5.0, 0.060), state)  # stamped after the frame: clock fault
    np.testing.assert_array_equal(est.stale_readings, [9])
    for before, after in zip(kept, (est.position, est.velocity, est.covariance), strict=True):
        np.testing.assert_array_equal(before, after)
    assert (np.abs(state.q) < 0.1).all()  # the 5 rad readings never got in
    np.testing.assert_allclose(est.time_since_fresh, 0.030)  # still the reading of t = 0.020


@ESTIMATORS
def test_non_finite_readings_never_poison_the_state(arm3, estimator):
    est = estimator(arm3, 1)
    state = RobotState.zeros(1, 3)
    est.reset(np.zeros(3), 0.0)
    dt = arm3.control_period
    bad = [
        ([np.nan, 0.1, 0.1], [dt, dt, dt]),  # NaN value, finite stamp
        ([0.1, np.inf, 0.1], [dt, dt, dt]),  # inf value
        ([0.1, 0.1, 0.1], [dt, np.nan, np.inf]),  # finite value, bad stamps
    ]
    for k, (value, stamp) in enumerate(bad, start=1):
        f = frame(k * dt, 0.0, 0.0)
        f.position[0] = value
        f.position_stamp[0] = np.array(stamp) + (k - 1) * dt
        est.update(f, state)
        assert np.isfinite(state.q).all() and np.isfinite(state.dq).all()
        assert np.isfinite(est.covariance).all()
    np.testing.assert_array_equal(est.missing_readings, [4])
    for k in range(4, 40):
        est.update(frame(k * dt, 0.1, k * dt), state)
    np.testing.assert_allclose(state.q, 0.1, atol=2e-3)  # it still tracks
    assert (est.reinitializations == 0).all()


@ESTIMATORS
@pytest.mark.parametrize(
    "P",
    [
        [[np.nan, 0.0], [0.0, 1.0]],  # not finite
        [[1e12, 0.0], [0.0, 1.0]],  # position variance above the bound
        [[1e-4, 0.1], [0.1, 1e-4]],  # not positive definite
        [[-1e-4, 0.0], [0.0, 1.0]],  # negative variance
    ],
    ids=["nan", "huge", "indefinite", "negative"],
)
def test_degenerate_covariance_is_reinitialized_and_counted(arm3, estimator, P):
    est = estimator(arm3, 2)
    state = RobotState.zeros(2, 3)
    dt = arm3.control_period
    est.reset(np.zeros((2, 3)), 0.0)
    for k in range(1, 20):
        est.update(frame(k * dt, 0.05, k * dt, envs=2), state)
    # with a fresh reading: re-initialized from it
    est.covariance[0, 1] = P
    f = frame(20 * dt, 0.05, 20 * dt, envs=2)
    f.position[0, 1] = 0.07
    est.update(f, state)
    np.testing.assert_array_equal(est.reinitializations, [1, 0])
    np.testing.assert_array_equal(est.covariance[0, 1], est.initial_covariance[1])
    assert est.position[0, 1] == 0.07 and est.filter_time[0, 1] == 20 * dt
    assert np.isfinite(state.q).all()
    # without a reading: re-initialized from the last estimate, filter time unchanged
    est.covariance[1, 2] = P
    position = est.position[1, 2]
    f = frame(21 * dt, 0.05, 21 * dt, envs=2)
    f.position[1, 2] = f.position_stamp[1, 2] = np.nan
    est.update(f, state)
    np.testing.assert_array_equal(est.reinitializations, [1, 1])
    np.testing.assert_array_equal(est.covariance[1, 2], est.initial_covariance[2])
    assert est.position[1, 2] == position and est.filter_time[1, 2] == 20 * dt
    # the filter carries on normally; covariance symmetric and positive definite
    for k in range(22, 60):
        est.update(frame(k * dt, 0.05, k * dt, envs=2), state)
    np.testing.assert_allclose(state.q, 0.05, atol=2e-3)
    P_all = est.covariance
    np.testing.assert_array_equal(P_all, P_all.transpose(0, 1, 3, 2))
    assert (np.linalg.eigvalsh(P_all) > 0).all()
    np.testing.assert_array_equal(est.reinitializations, [1, 1])


def test_lost_position_waits_for_a_reading_and_reports_infinite_age(arm3):
    est = JointStateEstimator(arm3, 1)
    state = RobotState.zeros(1, 3)
    est.reset(np.zeros(3), 0.0)
    est.position[0, 0] = np.nan  # fault injection: the state itself is lost
    est.update(frame(0.005, np.nan, np.nan), state)
    assert np.isnan(state.q[0, 0]) and est.time_since_fresh[0, 0] == np.inf
    assert np.isfinite(state.q[0, 1:]).all()
    est.update(frame(0.010, np.nan, np.nan), state)
    np.testing.assert_array_equal(est.reinitializations, [1])  # counted once
    est.update(frame(0.015, 0.3, 0.015), state)
    assert state.q[0, 0] == 0.3 and est.time_since_fresh[0, 0] == 0.0


def test_winding_temperature_is_copied_where_reported(arm3):
    est = JointStateEstimator(arm3, 1)
    state = RobotState.zeros(1, 3)
    est.reset(np.zeros(3), 0.0)
    f = frame(0.005, 0.0, 0.005, temperature=41.0)
    f.winding_temperature[0, 2] = np.nan
    est.update(f, state)
    np.testing.assert_array_equal(state.winding_temperature, [[41.0, 41.0, 25.0]])


def test_update_allocates_no_arrays(arm6):
    envs = 256  # one (envs, n) float array: 12 kB
    plant = SimBackend(arm6, envs=envs, seed=1)
    plant.dropout_probability[:] = 0.1
    est = JointStateEstimator(arm6, envs)
    state = RobotState.zeros(envs, 6)
    est.reset(plant.read().position, 0.0)
    frames = []
    for _ in range(20):
        plant.advance()
        f = plant.read()
        frames.append(SensorFrame(*(np.copy(a) for a in vars(f).values())))
    est.update(frames[0], state)
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        for f in frames[1:]:
            est.update(f, state)
        current, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak - base < 8 * envs * 6 // 2  # less than half of one work array
    assert current - base < 1024


def test_argument_errors(arm3):
    with pytest.raises(ValueError, match="measurement_sigma"):
        JointStateEstimator(arm3, 1, measurement_sigma=0.0)
    est = JointStateEstimator(arm3, 2)
    state = RobotState.zeros(2, 3)
    with pytest.raises(RuntimeError, match="reset"):
        est.update(frame(0.0, 0.0, 0.0, envs=2), state)
    with pytest.raises(ValueError, match="finite"):
        est.reset(np.full((2, 3), np.nan), 0.0)
    est.reset(np.zeros((2, 3)), [0.0, 0.1])
    with pytest.raises(ValueError, match="shaped"):
        est.update(frame(0.0, 0.0, 0.0, envs=1), state)


def test_a_fine_encoder_at_a_slow_rate_gives_a_velocity_that_does_not_oscillate():
    """go2: one-count encoder noise (3e-5 rad), 50 Hz readings, calves allowed 1000 rad/s^2. A
    calf that bounces (0.5 |sin| at 2.5 Hz: its speed reverses at each touchdown) read through
    its encoder: the estimated speed follows the true one (the filter's tracking index is capped,
    MAX_TRACKING_INDEX), and a dropped reading extrapolates a few hundredths of a radian, not the
    0.8 rad that stopped a walking robot."""
    go2 = load_robot("go2")
    n, dt = go2.n_joints, go2.control_period
    est = JointStateEstimator(go2, 1)
    state = RobotState.zeros(1, n)
    rng = np.random.default_rng(0)
    sigma = go2.config.sensors.encoder_noise_sigma
    w = 2 * np.pi * 2.5
    est.reset(np.asarray(go2.home)[None], 0.0)
    errors, jumps = [], []
    for k in range(1, 300):
        t = k * dt
        truth = go2.home + 0.5 * np.abs(np.sin(w * t))
        speed = 0.5 * w * np.cos(w * t) * np.sign(np.sin(w * t))
        dropped = k % 50 == 0
        reading = np.nan if dropped else truth + sigma * rng.standard_normal(n)
        est.update(frame(t, reading, np.nan if dropped else t, n=n), state)
        if k > 50:
            errors.append(state.dq[0] - speed)
            if dropped:
                jumps.append(np.abs(state.q[0] - truth).max())
    rms = np.sqrt(np.mean(np.square(errors)))
    # rad/s, against a peak speed of 7.9 rad/s that reverses at once (22 rad/s uncapped)
    assert rms < 6.0, rms
    assert max(jumps) < 0.1, jumps


def test_a_run_warns_about_joints_the_filter_keeps_reinitializing():
    from sim2real.deploy.estimation.joint_tuning import REINIT_WARNING_RATE, reinit_warning

    names = ("hip", "knee")
    seconds = 20.0
    rare = np.array([[1, 0], [0, 2]])  # a few, from injected faults: no warning
    assert reinit_warning(names, rare, seconds) is None
    every_tick = np.array([[0, 1000], [0, 1000]])
    text = reinit_warning(names, every_tick, seconds)
    assert "knee 2000 times in 20.0 s" in text and "hip" not in text
    edge = int(REINIT_WARNING_RATE * seconds) * 2  # exactly the rate over two envs: no warning
    assert reinit_warning(names, np.array([[edge // 2, 0], [edge // 2, 0]]), seconds) is None


def test_kernel_arrays_are_the_live_arrays_and_the_input_is_copied_only_when_it_must_be(arm3):
    """:meth:`JointStateEstimator.kernel_arrays`: the estimator's, frame's and state's own arrays
    (a fused caller keeps their addresses); an input the kernel cannot read in place (Fortran
    order) is the estimator's copy of it, None its zeros."""
    envs, n = 2, arm3.n_joints
    est, state = JointStateEstimator(arm3, envs), RobotState.zeros(envs, n)
    f = frame(0.01, arm3.home, 0.01, envs=envs, n=n)
    est.reset(np.broadcast_to(arm3.home, (envs, n)), 0.0)
    assert est.initialized
    acc = np.arange(envs * n, dtype=np.float64).reshape(envs, n)
    args = est.kernel_arrays(f, state, acc)
    assert args.u is acc and args.filt is est.filter_state and args.q_out is state.q
    assert args.z is f.position and args.now is f.time and args.dq_out is state.dq
    assert np.shares_memory(est.filter_state[7], est.time_since_fresh)
    fortran = np.asfortranarray(acc)
    args = est.kernel_arrays(f, state, fortran)
    assert args.u is not fortran and np.array_equal(args.u, acc)
    assert not est.kernel_arrays(f, state, None).u.any()


@ESTIMATORS
def test_the_drives_reported_velocity_removes_the_lag_of_a_stepping_joint(go2, estimator):
    """A Go2 joint swinging 0.4 rad at 3 Hz (140 rad/s^2, a stepping leg), its angle read at 50 Hz
    with the velocity its drive reports (``velocity_noise_sigma`` 0.02 rad/s, Unitree's
    ``motor_state.dq``): with that velocity absorbed the estimate's speed is within 0.05 rad/s
    RMS of the truth; from the angles alone the constant-velocity model lags it (0.96 rad/s here).
    Env 0 gets the drives' velocity, env 1 none."""
    rng = np.random.default_rng(4)
    n, dt, w = go2.n_joints, go2.control_period, 6.0 * np.pi
    est = estimator(go2, 2)
    state = RobotState.zeros(2, n)
    est.reset(np.tile(go2.home, (2, 1)), 0.0)
    f = SensorFrame.empty(2, n)
    f.velocity = np.full((2, n), np.nan)
    errors = []
    for k in range(1, 250):
        t = k * dt
        f.time[:] = f.position_stamp[:] = t
        f.position[:] = go2.home + 0.4 * np.sin(w * t)
        truth = 0.4 * w * np.cos(w * t)
        f.velocity[0] = truth + rng.normal(0.0, 0.02, n)
        est.update(f, state)
        if k > 50:
            errors.append(state.dq - truth)
    rms = np.sqrt(np.mean(np.square(errors), axis=(0, 2)))
    assert rms[0] < 0.05 and rms[1] > 0.3, rms


def test_the_velocity_step_equals_filterpy_reference_on_the_legged_plant(go2):
    """The compiled estimator and its filterpy reference on the Go2 plant's frames (angles and
    the drives' velocity), a trotting-like command: the same estimates to rounding."""
    plant = SimBackend(go2, mode="position", envs=2, seed=11)
    plant.reset()
    fast, reference = JointStateEstimator(go2, 2), ReferenceJointStateEstimator(go2, 2)
    states = [RobotState.zeros(2, go2.n_joints), RobotState.zeros(2, go2.n_joints)]
    for est in (fast, reference):
        est.reset(plant.true_position(), 0.0)
    worst = 0.0
    for k in range(300):
        f = plant.read()
        assert f.velocity is not None
        fast.update(f, states[0])
        reference.update(f, states[1])
        worst = max(worst, np.abs(states[0].dq - states[1].dq).max())
        worst = max(worst, np.abs(fast.covariance - reference.covariance).max())
        plant.write(
            np.tile(go2.home + 0.2 * np.sin(2 * np.pi * 2 * k * go2.control_period), (2, 1))
        )
        plant.advance()
    assert worst <= 1e-9, worst


@ESTIMATORS
@pytest.mark.parametrize("reports_velocity", [False, True], ids=["angle_only", "with_velocity"])
def test_a_stepping_legs_angle_follows_its_encoder(go2, estimator, reports_velocity):
    """A Go2 leg stepping (0.4 rad at 3 Hz plus 0.15 rad at 7 Hz: an acceleration that changes
    within each period), its angle read at 50 Hz to one encoder count, with or without the
    velocity its drive reports (0.02 rad/s of noise): the estimated angle stays within a few
    counts of the truth. The tracking-index floor (far coarser than the encoder, for a velocity
    estimate that does not oscillate) held the angle back: it lagged a stepping calf by up to
    20 mrad without the drive's velocity and drifted with the integrated velocity with it; the
    policy and the guard saw that angle. With the drive's velocity, the speed is within its
    noise too."""
    rng = np.random.default_rng(5)
    n, dt = go2.n_joints, go2.control_period
    sigma = go2.config.sensors.encoder_noise_sigma
    w1, w2 = 6.0 * np.pi, 14.0 * np.pi
    est = estimator(go2, 1)
    assert np.isfinite(est.angle_rest_variance).all()  # the floor acts on every go2 joint
    state = RobotState.zeros(1, n)
    est.reset(np.asarray(go2.home)[None], 0.0)
    f = SensorFrame.empty(1, n)
    f.velocity = np.zeros((1, n)) if reports_velocity else None
    angle, speed = [], []
    for k in range(1, 250):
        t = k * dt
        f.time[:] = f.position_stamp[:] = t
        truth = go2.home + 0.4 * np.sin(w1 * t) + 0.15 * np.sin(w2 * t)
        rate = 0.4 * w1 * np.cos(w1 * t) + 0.15 * w2 * np.cos(w2 * t)
        f.position[0] = truth + sigma * rng.standard_normal(n)
        if reports_velocity:
            f.velocity[0] = rate + rng.normal(0.0, 0.02, n)
        est.update(f, state)
        angle.append(np.abs(state.q[0] - truth).max())
        speed.append(state.dq[0] - rate)
    assert max(angle) < 10 * sigma, max(angle)
    if reports_velocity:
        assert np.sqrt(np.mean(np.square(speed))) < 0.05
