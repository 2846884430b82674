"""Training episodes meet the soak's faults: each env its own schedule, from the soak's ranges at
the training interval, shifted to its episode's start, gone when the episode ends."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim2real.deploy.backends.sim.faults import Fault
from sim2real.eval.world.dynamics import DynamicsRanges
from sim2real.eval.world.sensors import SensorRanges
from sim2real.eval.world.session_draw import sample_session
from sim2real.eval.world.session_ranges import session_ranges
from sim2real.policies import envs as reach_envs
from sim2real.policies.envs import ReachConfig, ReachTask
from sim2real.policies.episode_faults import FAULT_WARMUP

#: fixed encoder settings: every episode draws the same (latency 1 tick, dropout 0.001)
SENSORS = SensorRanges(noise_sigma=(0.001, 0.001), latency_ticks=(1, 1), dropout=(0.001, 0.001))
NOMINAL = ReachConfig(dynamics=DynamicsRanges.none(), sensors=SENSORS, episode_seconds=10.0)


def forced(monkeypatch, module, schedules: list) -> list:
    """Make ``module.sample_faults`` hand out ``schedules`` in turn (then empty ones); returns the
    list of its calls' seeds."""
    calls = []

    def fake(robot, seed, duration, sensors, ranges, plant=None):
        calls.append(seed)
        return list(schedules.pop(0)) if schedules else []

    monkeypatch.setattr(module, "sample_faults", fake)
    return calls


def test_a_latency_fault_raises_its_envs_latency_exactly_during_it(arm3, monkeypatch):
    """Env 0's schedule holds one latency fault at 0.5 s for 0.25 s: its latency is raised by the
    fault's ticks on exactly the ticks the fault covers (episode time from its start) and back
    after; env 1 keeps its own latency throughout. Only then is env 0's injector armed."""
    fault = Fault("latency", 0.5, 0.25, magnitude=3.0)
    forced(monkeypatch, reach_envs, [[fault]])
    task = ReachTask(arm3, 2, NOMINAL, seed=1)
    t0 = task.backend.time  # the episode's start (the task's clock: the plant's)
    assert task.faults.schedules[0] == (fault,) and task.faults.schedules[1] == ()
    shifted = dataclasses.replace(fault, start=fault.start + t0)
    latency, other, active, armed = [], [], [], []
    for _ in range(200):  # 1 s
        task.step(np.zeros((2, arm3.n_joints)))
        active.append(shifted.active(task.backend.time))  # the time of the tick's reading
        latency.append(int(task.backend.latency_ticks[0]))
        other.append(int(task.backend.latency_ticks[1]))
        armed.append([inj is not None for inj in task.faults.session_faults.armed])
    assert latency == [4 if on else 1 for on in active]
    assert armed == [[on, False] for on in active]  # an injector only while its fault is on
    assert sum(active) == round(fault.duration / arm3.control_period)
    assert latency[-1] == 1  # restored after the fault
    assert other == [1] * 200
    log = task.faults.log[0]
    assert [(e["kind"], round(e["start"] - t0, 6)) for e in log] == [("latency", fault.start)]


def test_a_reset_mid_fault_leaves_no_fault_behind(arm3, monkeypatch):
    """Reset env 0 while a stale frame, a dropout, a latency spike and a push are all in force:
    the new episode has its own sensor settings, no force, fresh readings and no injector; env 1
    is untouched."""
    during = [
        Fault("stale", 0.2, 1.0),
        Fault("dropout", 0.2, 1.0),
        Fault("latency", 0.2, 1.0, magnitude=3.0),
        Fault("push", 0.2, 1.0, magnitude=15.0),
    ]
    forced(monkeypatch, reach_envs, [during])
    task = ReachTask(arm3, 2, NOMINAL, seed=2)
    b = task.backend
    body = b.models[0].site_bodyid[arm3.ee_site_id]
    frozen = []
    for k in range(100):  # 0.5 s: every fault in force
        task.step(np.zeros((2, arm3.n_joints)))
        if k >= 80:
            frozen.append(b.frame.position_stamp[0].copy())
    assert b.latency_ticks[0] == 4 and b.dropout_probability[0] == 1.0
    assert np.linalg.norm(b.datas[0].xfrc_applied[body, :3]) == pytest.approx(15.0)
    assert all(np.array_equal(f, frozen[0], equal_nan=True) for f in frozen)  # a stale frame
    env1 = (int(b.latency_ticks[1]), float(b.dropout_probability[1]))

    task.reset(np.array([True, False]))  # the next schedule is empty
    assert task.faults.session_faults.armed[0] is None and task.faults.schedules[0] == ()
    assert (int(b.latency_ticks[0]), float(b.dropout_probability[0])) == (1, 0.001)
    assert not b.datas[0].xfrc_applied[:, :3].any()
    stamps = []
    for _ in range(200):  # past the old schedule's end (1.2 s): nothing of it comes back
        task.step(np.zeros((2, arm3.n_joints)))
        assert (int(b.latency_ticks[0]), float(b.dropout_probability[0])) == (1, 0.001)
        stamps.append(np.nanmax(b.frame.position_stamp[0]))
    assert not b.datas[0].xfrc_applied[:, :3].any()
    assert stamps[-1] > stamps[0]  # fresh readings, not a frozen frame
    assert (int(b.latency_ticks[1]), float(b.dropout_probability[1])) == env1


def test_non_finite_actions_are_held_and_never_reach_the_reward(arm3, monkeypatch):
    """A nan-action fault: the task holds the last valid action, as the runtime's screen does;
    rewards, observations and commands stay finite."""
    forced(monkeypatch, reach_envs, [[Fault("nan-action", 0.1, 0.025)]])
    task = ReachTask(arm3, 1, NOMINAL, seed=3)
    action = np.full((1, arm3.n_joints), 0.3)
    held = []
    for _ in range(60):
        obs, reward, _, _ = task.step(action)
        assert np.isfinite(reward).all() and np.isfinite(obs).all()
        assert np.isfinite(task.smoother.position).all()
        held.append(task.state.last_action[0].copy())
    np.testing.assert_array_equal(np.array(held), np.full((60, arm3.n_joints), 0.3))
    assert [e["kind"] for e in task.faults.log[0]] == ["nan-action"]


def training_ranges(robot, interval: float):
    """The soak's ranges of ``robot`` with its faults at the training interval, built here."""
    soak = session_ranges(robot)
    faults = dataclasses.replace(soak.faults, mean_interval=interval, warmup=FAULT_WARMUP)
    return dataclasses.replace(soak, faults=faults)


def test_an_arm_episode_draws_the_soaks_schedule_for_its_seed(arm3):
    """An episode's schedule is ``sample_session``'s for its fault seed with the training
    interval (nominal dynamics and fixed sensors, so that the session's world is the episode's)."""
    cfg = dataclasses.replace(NOMINAL, episode_seconds=40.0, fault_interval=8.0)
    task = ReachTask(arm3, 3, cfg, seed=4)
    ranges = dataclasses.replace(
        training_ranges(arm3, 8.0), sensors=SENSORS, dynamics=DynamicsRanges.none()
    )
    schedules = [task.faults.schedules[e] for e in range(3)]
    assert any(schedules)
    for e in range(3):
        draw = sample_session(arm3, int(task.fault_seed[e]), 40.0, ranges)
        assert schedules[e] == draw.faults
    assert len(set(task.fault_seed.tolist())) == 3


def test_faults_off_draw_no_schedule_and_leave_the_other_draws_alone(arm3):
    """``faults=False``: no injector, no schedule; the episode's other draws are those of a task
    with faults on (the fault seeds have their own stream)."""
    on = ReachTask(arm3, 2, ReachConfig(episode_seconds=30.0), seed=5)
    off = ReachTask(arm3, 2, ReachConfig(episode_seconds=30.0, faults=False), seed=5)
    assert off.faults is None
    np.testing.assert_array_equal(on.backend.true_position(), off.backend.true_position())
    np.testing.assert_array_equal(on.goal, off.goal)
    np.testing.assert_array_equal(on.backend.latency_ticks, off.backend.latency_ticks)


# ---------------------------------------------------------------------------- legged
@pytest.fixture(scope="module")
def go2_spec():
    from sim2real.policies.gait import make_policy

    return make_policy("go2")[1]


def spy_sessions(monkeypatch, replace_faults: dict | None = None) -> list:
    """Record ``sim2real.policies.locomotion.sample_session``'s calls (seed, draw); with
    ``replace_faults`` {call index: schedule}, that call's draw gets the schedule instead."""
    import sim2real.policies.locomotion as loco

    real, calls = loco.sample_session, []

    def spy(robot, seed, duration, ranges=None, faults=True):
        draw = real(robot, seed, duration, ranges, faults)
        if replace_faults and len(calls) in replace_faults:
            draw = dataclasses.replace(draw, faults=tuple(replace_faults[len(calls)]))
        calls.append((seed, duration, faults, draw))
        return draw

    monkeypatch.setattr(loco, "sample_session", spy)
    return calls


def test_a_legged_episode_meets_its_latency_fault_through_the_runtime(go2, go2_spec, monkeypatch):
    """Env 0 of two Go2s meets one latency burst at 1 s for 0.3 s: the runtime's injector raises
    its latency on exactly those ticks; env 1's stays; a reset mid-burst leaves the new
    episode's latency in force. A nan-action fault never makes the reward non-finite."""
    from sim2real.policies.locomotion import LocomotionConfig, LocomotionTask

    burst = Fault("latency", 1.0, 0.3, magnitude=1.0)
    nan = Fault("nan-action", 0.6, 0.1)
    calls = spy_sessions(monkeypatch, {0: [nan, burst]})
    task = LocomotionTask(go2, go2_spec, 2, LocomotionConfig(episode_seconds=5.0), seed=1)
    b, rt = task.backend, task.runtime
    base = b.latency_ticks.copy()
    for _ in range(60):  # 1.2 s
        t = rt.time  # the injector's time this tick
        reward, _, _ = task.tick()
        assert np.isfinite(reward).all()
        expected = base[0] + 1 if burst.start <= t < burst.start + burst.duration else base[0]
        assert b.latency_ticks[0] == expected, t
        assert b.latency_ticks[1] == base[1]
    assert rt.counters.non_finite_actions[0] == 5 and rt.counters.non_finite_actions[1] == 0
    task.reset(np.array([True, False]))  # mid-burst; the new 5-s episode has no faults
    assert task.faults.session_faults.armed[0] is None and task.faults.schedules[0] == ()
    new = calls[-1][3].sensors.latency_ticks
    for _ in range(20):  # past the old burst's end
        task.tick()
        assert b.latency_ticks[0] == new and b.latency_ticks[1] == base[1]


def test_a_legged_episode_draws_sample_sessions_schedule_at_the_training_interval(
    go2, go2_spec, monkeypatch
):
    """Each episode's schedule is ``sample_session``'s for its seed, its length and the soak's
    ranges with the training interval; with faults off every draw has an empty schedule and the
    runtime has no injector."""
    from sim2real.policies.locomotion import LocomotionConfig, LocomotionTask

    calls = spy_sessions(monkeypatch)
    cfg = LocomotionConfig(episode_seconds=20.0, fault_interval=4.0)
    task = LocomotionTask(go2, go2_spec, 3, cfg, seed=2)
    ranges = training_ranges(go2, 4.0)
    assert any(task.faults.schedules)
    for e, (seed, duration, faults, _) in enumerate(calls):
        assert (duration, faults) == (20.0, True)
        assert task.faults.schedules[e] == sample_session(go2, seed, 20.0, ranges).faults
        assert all(f.kind != "cable" for f in task.faults.schedules[e])

    calls.clear()
    off = LocomotionTask(go2, go2_spec, 2, dataclasses.replace(cfg, faults=False), seed=2)
    assert off.faults is None and off.runtime.injector is None
    assert [c[3].faults for c in calls] == [(), ()]


def test_the_training_commands_set_and_record_the_fault_settings(monkeypatch):
    """``--no-faults`` and ``--fault-interval`` reach the task's config (train.py and
    train_legged.py)."""
    import sim2real.policies.train as train
    import sim2real.policies.train_legged as train_legged

    seen = []

    class Stop(Exception):
        pass

    def fake(robot, *args, **kwargs):
        config = [a for a in args if hasattr(a, "fault_interval")][0]
        seen.append((config.faults, config.fault_interval))
        raise Stop

    monkeypatch.setattr(train, "ReachTask", fake)
    monkeypatch.setattr(train_legged, "LocomotionTask", fake)
    for main, argv in (
        (train.main, ["--no-faults"]),
        (train.main, ["--fault-interval", "30"]),
        (train_legged.main, []),
        (train_legged.main, ["--no-faults", "--fault-interval", "5"]),
    ):
        with pytest.raises(Stop):
            main(argv)
    assert seen == [(False, 90.0), (True, 30.0), (True, 10.0), (False, 5.0)]
