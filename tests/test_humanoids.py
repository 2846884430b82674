"""unitree_rl_gym's published humanoid walking policies (the H1 and the H1-2) walk through the full
runtime (estimator, guard, smoother, default sensor noise) on the robots imported from their MJCF.

Test data: ``tests/data/unitree_rl_gym`` (its README says where each file comes from).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from sim2real.deploy.cli.deploy_run import deploy_run_main

DATA = Path(__file__).parent / "data" / "unitree_rl_gym"


@pytest.mark.parametrize("robot", ["h1", "h1_2"])
def test_published_humanoid_walks_without_a_fall_or_a_safe_stop(robot, tmp_path):
    """Eight simulated seconds commanded at 0.5 m/s: the robot walks at least 3 m, never falls,
    is never stopped, and the joint estimator does not re-initialize (at the limits the importer
    derives for PD targets)."""
    report = tmp_path / "run.json"
    deploy_run_main(
        [
            "--robot", f"sim2real/robots/{robot}",
            "--policy", str(DATA / robot / f"{robot}.onnx"),
            "--command", "0.5,0,0",
            "--duration", "8",
            "--report", str(report),
        ]
    )  # fmt: skip
    summary = json.loads(report.read_text())
    walk = summary["locomotion"]
    assert walk["falls"] == 0, walk
    assert summary["faults"]["safe_stops"] == 0, summary["faults"]
    assert summary["final_state"] == ["RUNNING"]
    assert summary["faults"]["estimator"]["reinitializations"] == 0, summary["faults"]
    assert walk["distance_m"] >= 3.0, walk
    # the first two seconds accelerate from standing, outside the 0.2 m/s band
    assert walk["tracking_success"] >= 0.7, walk


@pytest.mark.parametrize("reference", [False, True], ids=["compiled", "reference"])
def test_a_humanoids_legs_predicted_to_touch_are_not_held(reference):
    """The H1's legs brush in a recovery step; holding every joint's target there lays it down.
    Its target with both hips rolled inward until the legs touch passes the guard unchanged (an
    arm's is held: tests/test_safety.py); the violation monitor counts true contacts."""
    import numpy as np

    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.safety.guard import SafetyGuard
    from sim2real.deploy.safety.reference import ReferenceGuard
    from sim2real.robots import load_robot

    h1 = load_robot("h1")
    guard = (ReferenceGuard if reference else SafetyGuard)(h1, 1, "position")
    state = RobotState.legged(1, h1.n_joints, h1.n_feet, 25.0)
    state.q[:] = h1.home
    guard.reset(state.q)
    target = np.array([h1.home])
    target[0, h1.joint_names.index("left_hip_roll_joint")] = -0.3  # legs touch from 0.24
    target[0, h1.joint_names.index("right_hip_roll_joint")] = 0.3
    for _ in range(3):
        out = guard.filter(target.copy(), state, out=np.empty_like(target))
        np.testing.assert_array_equal(out, target)
    assert guard.counts["self_collision"].tolist() == [0]


@pytest.mark.parametrize("push_seed", [1, 4])
def test_the_published_h1_walks_through_half_metre_per_second_pushes(push_seed):
    """legged_gym's push (the base's horizontal velocity set to U(-0.5, 0.5) m/s per axis every
    5 s) on the H1 walking at 0.5 m/s through the full runtime with its default sensor noise:
    40 s without a fall, as in unitree_rl_gym's own loop (deploy_mujoco.py, no guard). With the
    guard holding every joint where the legs were predicted to touch, seed 4 fell at 21.7 s."""

    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import RUNNING, Runtime
    from sim2real.eval.world.pushes import push_velocity
    from sim2real.robots import load_robot

    h1 = load_robot("h1")
    policy = OnnxPolicy(DATA / "h1" / "h1.onnx", h1)
    plant = SimBackend(h1, "position", envs=1, seed=0)
    rt = Runtime(h1, policy, plant)
    rt.velocity_command[0] = [0.5, 0.0, 0.0]
    rt.start()
    every = round(5.0 / rt.dt)
    pushes = 0
    for k in range(round(40.0 / rt.dt)):
        rt.tick()
        assert rt.mode[0] == RUNNING or pushes == 0, (rt.cause_names(), k * rt.dt)
        if rt.mode[0] == RUNNING and k % every == 0:
            plant.set_base_velocity(0, push_velocity(push_seed, k // every, 0.5))
            pushes += 1
    assert pushes >= 7
    assert plant.true_base_state()[0, 0] > 5.0  # it walked on


def test_the_soak_tells_a_stop_on_a_falling_robot_from_a_stop_that_felled_it(tmp_path, monkeypatch):
    """H1-2 in its training domain (legged_gym's pushes, as forces) under a stricter guard, any
    estimate past a hard limit for 0.1 s a stop (``LEGGED_HARD_LIMIT_TOLERANCE`` 0): seed 25's
    robot is stopped 0.88 s after its first push (seed 22's, 0.44 s after, while a push was a
    force on the base alone; seed 7's, 0.74 s after, while the barrier's least inertia was the
    mass matrix's diagonal: with the effective inertia it keeps seed 7's and 21's estimates
    inside the range, a fall stop instead; of 0, 7, 21, 25, 35, seeds 0, 25, 35 are still
    stopped at the limit). Replayed without the stop it falls anyway (the
    push began its fall: origin ``push``). The replay repeats the session: with the stop left on
    it stops on the same tick, the estimate as far past. (Seeds 1 and 10 were a falling robot and
    one the stop felled while the guard clamped PD targets into the soft limits; with the barrier
    guard, seeds 0-89 have no stop that felled a robot. tests/test_domain.py attributes both.)"""
    import sim2real.deploy.safety.limits as limits
    from sim2real.deploy.safety import pd_barrier
    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.soak.falls import attribute_falls
    from sim2real.eval.soak.session import SessionConfig
    from sim2real.eval.world.domain import training_domain
    from sim2real.eval.world.ranges_file import load_ranges_text
    from sim2real.robots import load_robot

    monkeypatch.setattr(limits, "LEGGED_HARD_LIMIT_TOLERANCE", 0.0)  # read when a guard is built
    # the barrier judging a loaded leg with its least inertia alone, as when the seed was chosen:
    # with the heavier one too the falling robot's estimate stays inside the range (a fall stop)
    monkeypatch.setattr(pd_barrier, "INERTIA_SPREAD", 1.0)
    policy = "tests/data/unitree_rl_gym/h1_2/h1_2.onnx"
    ranges = load_ranges_text(training_domain(policy), policy, load_robot("h1_2"), None)
    config = SessionConfig(robot="h1_2", policy=policy, seed=25, hours=1.0, ranges=ranges)
    batch = SessionBatch([config], tmp_path / "25", progress=False)
    batch.rt.run(int(round(7.0 / batch.dt)), on_tick=batch.on_tick)
    log = batch.task.parts()["tracker"].fall_log[0]
    stops = [r for r in log if r["cause"] == "hard_limit"]
    assert [r["would_fall"] for r in stops] == [True]
    origins = attribute_falls(stops, [], batch.pushes.times[0])
    assert [f["origin"] for f in origins] == ["push"]
    # the replay with the stop on: the same stop on the same tick
    replay = batch.stop_replay
    twin = replay.copies[0]
    arrays, meta = replay.captures[0]
    twin.restore(arrays, json.loads(json.dumps(meta)), "test")
    log = twin.task.parts()["tracker"].fall_log[0]
    before = len(log)
    stop = stops[0]
    twin.rt.run(int(round((stop["t_s"] + 0.5 - twin.rt.time) / twin.dt)), on_tick=twin.on_tick)
    assert [(r["t_s"], r["cause"], r["past_rad"]) for r in log[before:]] == [
        (stop["t_s"], "hard_limit", stop["past_rad"])
    ]


def test_a_humanoid_session_is_the_same_alone_and_batched_with_one_that_stands_up(tmp_path):
    """H1-2 seed 8 alone and batched with seed 1, which falls at 6 s and is stood up (its
    sensors reset) at 16 s: seed 8's state is the same bit for bit at 19 s. A reset of one env
    drew the IMU's turn-on bias and a forced reading from every env's noise stream before."""
    import numpy as np

    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.soak.session import SessionConfig
    from sim2real.eval.world.domain import training_domain
    from sim2real.eval.world.ranges_file import load_ranges_text
    from sim2real.robots import load_robot

    policy = "tests/data/unitree_rl_gym/h1_2/h1_2.onnx"
    ranges = load_ranges_text(training_domain(policy), policy, load_robot("h1_2"), None)
    states = []
    for seeds in ((8,), (1, 8)):
        configs = [
            SessionConfig(robot="h1_2", policy=policy, seed=s, hours=1.0, ranges=ranges)
            for s in seeds
        ]
        batch = SessionBatch(configs, tmp_path / str(len(seeds)), progress=False)
        batch.rt.run(int(round(19.0 / batch.dt)), on_tick=batch.on_tick)
        if len(seeds) == 2:
            assert batch.sessions[0].stood_up == 1
        states.append(batch.rt.state_dict(len(seeds) - 1))
    alone, batched = states
    differ = [
        k
        for k, v in alone.items()
        if isinstance(v, np.ndarray)
        and v.dtype != object
        and not k.startswith(("latency/", "tick_cost/"))  # the wall clock's
        and not np.array_equal(v, batched[k], equal_nan=True)
    ]
    assert differ == []
