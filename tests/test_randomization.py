"""Seeded randomization of the soak harness: sessions, sensors, drift, the cable fault.

Fault schedules and their budgets: tests/test_fault_schedule.py."""

import json

import numpy as np
import pytest

from sim2real.deploy.backends.sim.faults import CABLE_FORCE, Fault, FaultInjector
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.eval.world.drift import Drift, DriftRanges, apply_drift, joint_dofs, sample_drift
from sim2real.eval.world.dynamics import randomized_model
from sim2real.eval.world.fault_schedule import FaultRanges
from sim2real.eval.world.sensors import SensorDraw, SensorRanges, apply_sensors, sample_sensors
from sim2real.eval.world.session_draw import SessionRandomization, sample_session, session_rng
from sim2real.eval.world.session_ranges import SessionRanges

HOURS8 = 8 * 3600.0


def test_a_session_is_replayable_from_its_seed_and_its_report(arm3):
    a = sample_session(arm3, 7, HOURS8)
    assert sample_session(arm3, 7, HOURS8) == a
    assert sample_session(arm3, 8, HOURS8) != a
    # what the report stores (JSON) gives the same draw back
    assert SessionRandomization.from_dict(json.loads(json.dumps(a.to_dict()))) == a


def test_each_kind_of_draw_has_its_own_stream(arm3):
    """Turning faults off, or changing the fault rate, leaves dynamics, sensors and drift alone."""
    a = sample_session(arm3, 3, HOURS8)
    b = sample_session(arm3, 3, HOURS8, faults=False)
    c = sample_session(arm3, 3, HOURS8, SessionRanges(faults=FaultRanges(mean_interval=30.0)))
    assert b.faults == () and len(c.faults) > len(a.faults) > 0
    for other in (b, c):
        assert (other.dynamics, other.sensors, other.drift) == (a.dynamics, a.sensors, a.drift)


def test_sensor_noise_follows_the_seed_section_5_range():
    draws = [sample_sensors(session_rng(s, "sensors")) for s in range(200)]
    sigma = np.array([d.noise_sigma for d in draws])
    assert sigma.min() >= 0.002 * np.pi and sigma.max() <= 0.010 * np.pi
    assert sigma.max() - sigma.min() > 0.006 * np.pi  # the whole range is used
    assert {d.latency_ticks for d in draws} == {0, 1, 2}
    assert all(0.0 <= d.dropout_probability <= 0.001 for d in draws)


def test_apply_sensors_sets_one_env_and_refuses_latency_beyond_the_buffer(arm3):
    backend = SimBackend(arm3, envs=2, max_latency_ticks=4)
    apply_sensors(backend, 1, SensorDraw(0.02, 3, 0.01))
    assert backend.noise_sigma.tolist() == [arm3.config.sensors.encoder_noise_sigma, 0.02]
    assert backend.latency_ticks.tolist() == [arm3.config.sensors.encoder_latency_ticks, 3]
    assert backend.dropout_probability[1] == 0.01
    with pytest.raises(ValueError, match="latency 5 ticks exceeds the backend's max_latency"):
        apply_sensors(backend, 0, SensorDraw(0.02, 5, 0.0))


def test_drift_raises_friction_in_the_sessions_model_over_time(arm3):
    drift = sample_drift(arm3, session_rng(0, "drift"))
    assert all(0.01 <= r <= 0.06 for r in drift.friction_rate)
    model = randomized_model(arm3, "velocity", sample_session(arm3, 0, 60.0).dynamics)
    dofs = joint_dofs(model, arm3)
    initial = model.dof_frictionloss[dofs].copy()
    assert np.array_equal(apply_drift(model, arm3, initial, drift, 0.0), initial)
    after = apply_drift(model, arm3, initial, drift, 8 * 3600.0)
    np.testing.assert_allclose(after, initial * (1 + 8 * np.array(drift.friction_rate)))
    assert np.array_equal(model.dof_frictionloss[dofs], after)  # the model itself, in place
    assert Drift.from_dict(drift.to_dict()) == drift


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: SensorRanges(noise_sigma=(0.02, 0.01)), "SensorRanges.noise_sigma"),
        (lambda: DriftRanges(friction_rate=(-0.1, 0.1)), "DriftRanges.friction_rate"),
    ],
)
def test_bad_ranges_name_the_field(make, field):
    with pytest.raises(ValueError, match=field):
        make()


def test_cable_fault_pulls_along_gravity_then_lets_go(arm3):
    backend = SimBackend(arm3, envs=2)
    body = backend.models[0].site_bodyid[arm3.ee_site_id]
    injector = FaultInjector([Fault("cable", 1.0, 2.0, envs=(1,), magnitude=12.0)], backend)
    injector.before_read(1.5)
    g = np.array(backend.models[1].opt.gravity)
    np.testing.assert_allclose(
        backend.datas[1].xfrc_applied[body, :3], 12.0 * g / np.linalg.norm(g)
    )
    assert not backend.datas[0].xfrc_applied.any()
    injector.before_read(3.0)
    assert not backend.datas[1].xfrc_applied.any()
    assert injector.log[0]["kind"] == "cable"
    # a given direction, and the default force; parsing like the other kinds
    injector = FaultInjector([Fault("cable", 0.0, 1.0, direction=(1.0, 0.0, 0.0))], backend)
    injector.before_read(0.5)
    assert backend.datas[0].xfrc_applied[body, :3].tolist() == [CABLE_FORCE, 0.0, 0.0]
    assert Fault.parse("cable@30:20") == Fault("cable", 30.0, 20.0)


def test_inject_takes_a_magnitude_where_the_fault_has_one():
    assert Fault.parse("latency=1@3:2") == Fault("latency", 3.0, 2.0, magnitude=1.0)
    assert Fault.parse("push=80@5:0.2") == Fault("push", 5.0, 0.2, magnitude=80.0)
    for text, message in (
        ("stale=2@1", "stale takes no MAGNITUDE"),
        ("latency=1.5@1", "latency MAGNITUDE is whole control ticks"),
        ("push=-3@1", "expected MAGNITUDE > 0"),
        ("push=x@1", "MAGNITUDE, SECONDS and DURATION must be numbers"),
    ):
        with pytest.raises(ValueError, match=message):
            Fault.parse(text)


def test_cable_pull_loads_the_motors(arm3):
    """The sustained pull is a real load: the held arm's motors carry more torque."""
    backend = SimBackend(arm3)
    for _ in range(200):
        backend.advance()
    before = np.abs(backend.joint_torque()[0]).sum()
    injector = FaultInjector([Fault("cable", 0.0, 10.0, magnitude=15.0)], backend)
    injector.before_read(0.1)
    for _ in range(200):
        backend.advance()
    assert np.abs(backend.joint_torque()[0]).sum() > before + 5.0


def test_encoder_noise_is_drawn_about_each_robots_own_noise():
    """arm3 keeps the seed's range exactly (its results do not move); an SO-101 with one-count
    (0.00153 rad) encoders gets 0.4-2 counts, not the 4-20 counts of the absolute range."""
    from sim2real.eval.world.sensors import SensorRanges
    from sim2real.eval.world.session_ranges import sensor_ranges, session_ranges
    from sim2real.robots import load_robot

    assert sensor_ranges(load_robot("arm3")).noise_sigma == SensorRanges().noise_sigma
    so101 = load_robot("so101")
    low, high = session_ranges(so101).sensors.noise_sigma
    count = so101.config.sensors.encoder_noise_sigma
    assert abs(low / count - 0.4) < 0.01 and abs(high / count - 2.0) < 0.01
