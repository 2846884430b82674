"""The soak's fault schedule: onsets, kinds, and faults sized to be survivable by design."""

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.modes import NAN_ACTION_LIMIT
from sim2real.eval.world.dynamics import randomized_model
from sim2real.eval.world.fault_schedule import (
    FaultRanges,
    cable_budget,
    sample_fault_schedule,
    stale_budget,
)
from sim2real.eval.world.sensors import SensorDraw
from sim2real.eval.world.session_draw import sample_session, session_rng
from sim2real.robots.chain_bounds import end_effector_lever, motion_bounds

HOURS8 = 8 * 3600.0


def test_fault_schedule_is_ordered_spaced_and_survivable_by_default(arm3):
    sensors = SensorDraw(0.01, 2, 0.0)
    ranges = FaultRanges()
    faults = sample_fault_schedule(arm3, session_rng(1, "faults"), HOURS8, sensors, ranges)
    assert 150 < len(faults) < 350  # one every ~2 minutes over 8 hours
    assert {f.kind for f in faults} == {
        "dropout",
        "stale",
        "nan-action",
        "latency",
        "push",
        "cable",
    }
    assert faults[0].start >= ranges.warmup
    for a, b in zip(faults[:-1], faults[1:], strict=True):
        assert b.start >= a.start + a.duration + ranges.min_gap - 1e-9  # one at a time
    assert faults[-1].start + faults[-1].duration <= HOURS8
    dt = arm3.control_period
    budget = stale_budget(arm3, sensors.latency_ticks)
    stale_ticks = round(arm3.stale_limit / dt)
    for f in faults:
        if f.kind in ("dropout", "stale"):  # shorter than the stale limit: bridged by prediction
            assert f.duration <= budget + 1e-9
        elif f.kind == "nan-action":  # fewer than the runtime's limit in a row: held
            assert 1 <= round(f.duration / dt) < NAN_ACTION_LIMIT
        elif f.kind == "latency":
            assert 1 <= f.magnitude <= stale_ticks - sensors.latency_ticks - 2
        elif f.kind == "cable":  # a sustained pull the drives hold for its duration
            cable = cable_budget(arm3, np.array([f.duration, f.duration + 0.25]))
            assert 0.5 * cable[1] - 1e-9 <= f.magnitude <= cable[0] + 1e-9
            assert 10.0 <= f.duration <= 60.0


def test_fault_schedule_fits_short_sessions(arm3):
    ranges = FaultRanges(mean_interval=2.0, warmup=1.0, min_gap=3.0)
    faults = sample_fault_schedule(
        arm3, session_rng(0, "faults"), 30.0, SensorDraw(0.01, 0, 0.0), ranges
    )
    assert faults and all(f.start + f.duration + 3.0 <= 30.0 for f in faults)


def test_the_cable_budget_is_the_reserve_above_gravity_and_shrinks_with_the_duration(arm3, arm6):
    """Instantly, a cold-or-warm drive gives its peak torque: the budget is the weakest joint's
    peak minus its gravity bound over its lever (arm3: the shoulder, (22.5 - 9.14) / 0.9 m). The
    longer the pull, the more the winding heats and the drive folds back."""
    hold = motion_bounds(arm3)[1]
    lever = end_effector_lever(arm3)
    np.testing.assert_allclose(lever, [0.9, 0.6, 0.3], atol=1e-9)  # arm3's link lengths
    budget = cable_budget(arm3, np.array([0.0, 10.0, 30.0, 60.0]))
    assert budget[0] == pytest.approx(np.min((arm3.effort_limit - hold) / lever), rel=1e-9)
    assert np.all(np.diff(budget) < 0) and budget[-1] > 0
    # arm6's stand-in motors cannot even hold the stretched arm continuously: no sustained pull
    assert cable_budget(arm6, np.array([0.0, 30.0])).tolist()[1] == 0.0


def test_a_heavier_plant_gets_a_smaller_cable_budget(arm3):
    """Faults are sized against the session's own plant: heavier, longer links leave less."""
    session = sample_session(arm3, 0, 60.0)
    plant = randomized_model(arm3, "velocity", session.dynamics)
    heavier = motion_bounds(arm3, plant)[1][0] > motion_bounds(arm3)[1][0]
    nominal, randomized = (
        cable_budget(arm3, np.array([30.0])),
        cable_budget(arm3, np.array([30.0]), plant),
    )
    assert (randomized < nominal) == heavier and randomized != nominal


@pytest.mark.parametrize(("multiple", "holds"), [(1.0, True), (2.0, False)])
def test_a_warm_stretched_arm_holds_a_pull_at_its_budget_and_yields_to_twice_it(
    arm3, multiple, holds
):
    """The worst case the budget is computed for: the arm stretched horizontally (largest gravity
    and cable levers), the shoulder warm from holding it, the velocity loop commanded to stand
    still, a pull of the budget for 10 s. Twice the budget drags the arm down."""
    duration = 10.0
    force = multiple * cable_budget(arm3, np.array([duration]))[0]
    plant = SimBackend(arm3, mode="velocity")
    plant.reset(np.zeros(3))
    thermal = plant.thermal
    warm = thermal.steady_state(np.abs(arm3.gravity_torque(np.zeros(3)))[None])
    thermal.winding_temperature[:] = warm
    thermal.housing_temperature[:] = 25.0 + (warm - 25.0) * thermal.r_ha / (
        thermal.r_wh + thermal.r_ha
    )
    plant.set_external_force(0, np.array([0.0, -force, 0.0]))
    for _ in range(int(duration / arm3.control_period)):
        plant.read()
        plant.write(np.zeros((1, 3)))
        plant.advance()
    sag = -plant.true_position()[0, 0]
    assert (sag < 0.05) == holds, f"shoulder sagged {sag:.3f} rad under {force:.1f} N"


def test_cable_pulls_beyond_the_budget_are_refused():
    with pytest.raises(ValueError, match="FaultRanges.cable_force: expected fractions"):
        FaultRanges(cable_force=(0.5, 1.5))


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: FaultRanges(kinds=("dropout", "meteor")), "FaultRanges.kinds: 'meteor'"),
        (lambda: FaultRanges(weights=(1.0,)), "FaultRanges.weights"),
        (lambda: FaultRanges(min_gap=1.0), "FaultRanges.min_gap"),
        (lambda: FaultRanges(mean_interval=0.0), "FaultRanges.mean_interval"),
        (lambda: cable_budget_of_negative_duration(), "cable_budget: expected durations"),
    ],
)
def test_bad_ranges_name_the_field(make, field):
    with pytest.raises(ValueError, match=field):
        make()


def cable_budget_of_negative_duration():
    from sim2real.robots import load_robot

    return cable_budget(load_robot("arm3"), np.array([-1.0]))


def test_soak_pushes_are_sized_by_the_robots_soak_table():
    """so101's [soak] push_force (its drives' instant reserve at the tip) replaces the default
    range made for arm3; arm3 keeps the default."""
    from sim2real.eval.world.fault_schedule import cable_budget, fault_ranges
    from sim2real.robots import load_robot

    so101, arm3 = load_robot("so101"), load_robot("arm3")
    assert fault_ranges(arm3) == FaultRanges()
    ranges = fault_ranges(so101, mean_interval=60.0)
    assert ranges.push_force == (1.0, 3.7) and ranges.mean_interval == 60.0
    assert ranges.push_force[1] <= cable_budget(so101, np.array([0.0]))[0] + 0.05


def _arm3_at(rate: float, folder):
    """arm3 with its control rate set to ``rate`` Hz (its robot.toml and MJCF copied)."""
    import shutil
    from pathlib import Path

    from sim2real.robots import load_robot

    here = Path(__file__).resolve().parents[1] / "sim2real" / "robots" / "arm3"
    shutil.copytree(here, folder)
    toml = folder / "robot.toml"
    text = toml.read_text()
    assert "control_rate = 200.0" in text
    toml.write_text(text.replace("control_rate = 200.0", f"control_rate = {rate}"))
    return load_robot(toml)


@pytest.mark.parametrize("rate", [50.0, 100.0, 200.0])
def test_every_sensor_fault_drawn_is_survived_at_50_100_and_200_hz(tmp_path, rate):
    """Dropouts, stale frames and latency spikes drawn for a session at its largest size, with
    0, 1 or 2 ticks of sensor latency (one env each), run on the runtime holding the home pose:
    no safe stop, and every session draws them: the stale limit spans 8 control periods
    (``Robot.stale_limit``), 4 ticks of gap with 2 of latency (before, at 50 Hz the 0.05 s limit
    fitted none with 1-2 ticks of latency, and those sessions drew no sensor fault)."""
    from sim2real.deploy.backends.sim.faults import FaultInjector
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime
    from sim2real.eval.world.fault_schedule import gap_ticks
    from tests.runtime_fixtures import zero_action_onnx

    robot = _arm3_at(rate, tmp_path / "arm3")
    dt = robot.control_period
    ranges = FaultRanges(
        mean_interval=0.3,
        min_gap=3.0,
        warmup=1.0,
        kinds=("dropout", "stale", "latency", "nan-action"),
        dropout=(0.8, 0.8),
        stale=(0.8, 0.8),
        latency_ticks=(1.0, 1.0),
        latency_duration=(0.2, 0.2),
    )
    plant = SimBackend(robot, envs=3, seed=0)
    faults, drawn = [], []
    for e, latency in enumerate((0, 1, 2)):
        plant.latency_ticks[e] = latency
        schedule = sample_fault_schedule(
            robot, session_rng(e, "faults"), 20.0, SensorDraw(1e-4, latency, 0.0), ranges
        )
        gaps = [f for f in schedule if f.kind in ("dropout", "stale", "latency")]
        assert bool(gaps) == (gap_ticks(robot, latency) >= 1), (latency, schedule)
        drawn.append(len(gaps))
        faults += [replace_envs(f, e) for f in schedule]
    assert all(n > 0 for n in drawn)  # at 50 Hz too: the stale limit spans 8 control periods
    policy = OnnxPolicy(zero_action_onnx(robot, tmp_path / "still.onnx"), robot)
    rt = Runtime(robot, policy, plant, injector=FaultInjector(faults, plant))
    rt.start()
    rt.run(int(round(20.0 / dt)))
    assert rt.counters.safe_stops.tolist() == [0, 0, 0], rt.cause_names()


def replace_envs(fault, e: int):
    import dataclasses

    return dataclasses.replace(fault, envs=(e,))


@pytest.mark.parametrize("rate", [50.0, 100.0])
def test_lost_readings_of_the_sessions_own_dropout_hold_and_a_silent_sensor_stops(tmp_path, rate):
    """At 50 Hz and at the importer's default rate (100 Hz), with 1 or 2 ticks of latency: 2 and
    4 readings lost in a row (what the session's own random dropout makes: 2 in a row about 5
    times an hour on a 30-joint robot at 50 Hz) hold; a sensor silent for 0.3 s stops the robot
    (stale_sensor). Before, at 50 Hz two lost readings with one tick of latency passed the 0.05 s
    limit and stopped it."""
    from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime
    from tests.runtime_fixtures import zero_action_onnx

    robot = _arm3_at(rate, tmp_path / "arm3")
    dt = robot.control_period
    plant = SimBackend(robot, envs=4, seed=0)
    faults = []
    for e, (latency, lost) in enumerate(((1, 2), (2, 2), (1, 4), (2, 4))):
        plant.latency_ticks[e] = latency
        faults.append(Fault("dropout", 50 * dt, lost * dt, envs=(e,)))
        faults.append(Fault("dropout", 100 * dt, lost * dt, envs=(e,)))
    policy = OnnxPolicy(zero_action_onnx(robot, tmp_path / "still.onnx"), robot)
    rt = Runtime(robot, policy, plant, injector=FaultInjector(faults, plant))
    rt.start()
    rt.run(150)
    assert rt.counters.safe_stops.tolist() == [0, 0, 0, 0], rt.cause_names()

    silent = SimBackend(robot, envs=1, seed=0)
    silent.latency_ticks[0] = 1
    injector = FaultInjector([Fault("dropout", 20 * dt, 0.3, envs=(0,))], silent)
    rt = Runtime(robot, policy, silent, injector=injector)
    rt.start()
    rt.run(20 + int(round(0.3 / dt)))
    assert rt.counters.safe_stops.tolist() == [1] and "stale_sensor" in str(rt.cause_names())
    assert robot.stale_limit == pytest.approx({50.0: 0.16, 100.0: 0.08}[rate])
