"""Violations (the true state past a limit) apart from interventions (a command the guard or the
smoother changed), and the goal scheduler's windows and missed goals."""

from types import SimpleNamespace

import mujoco
import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.monitors.interventions import INTERVENTION_CHECKS, InterventionMonitor
from sim2real.deploy.monitors.violations import VIOLATION_TYPES, ViolationMonitor
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.deploy.smoothing import CommandSmoother
from sim2real.deploy.tasks.goals import GoalScheduler, success_windows


def place(backend, e, q, dq=None):
    """Put env ``e`` of a SimBackend at joint positions ``q`` (and velocities ``dq``) now."""
    m, d = backend.models[e], backend.datas[e]
    d.qpos[:] = q
    d.qvel[:] = 0.0 if dq is None else dq
    mujoco.mj_forward(m, d)


def guarded(robot, envs, mode):
    guard = SafetyGuard(robot, envs, mode)
    smoother = CommandSmoother(robot, envs, mode)
    state = RobotState.zeros(envs, robot.n_joints)
    state.q[:] = robot.home
    guard.reset(state.q)
    smoother.reset(state.q, state.dq)
    return guard, smoother, state, InterventionMonitor(guard, smoother)


# ---------------------------------------------------------------- violations: the true state
def test_a_true_hard_limit_crossing_is_a_violation_but_a_guard_clamp_is_not(arm3):
    backend = SimBackend(arm3, mode="velocity", envs=2)
    monitor = ViolationMonitor(arm3, 2)
    guard, smoother, state, interventions = guarded(arm3, 2, "velocity")

    # a guard clamp: the estimate sits 0.01 rad inside the soft limit of the wrist, the policy
    # asks for full speed toward it; the true robot rests at home
    state.q[:, 2] = arm3.soft_upper[2] - 0.01
    target = np.zeros((2, 3))
    target[:, 2] = arm3.velocity_limit[2]
    guard.filter(target, state, out=target)
    interventions.update()
    monitor.update(backend)
    assert guard.counts["velocity"].tolist() == [1, 1]
    assert interventions.counts["velocity"].tolist() == [1, 1]
    assert monitor.any.tolist() == [0, 0] and monitor.totals()["any"] == 0

    # the true wrist of env 1 past its hard limit (a push), no command changed
    q = arm3.home.copy()
    q[2] = arm3.position_upper[2] + 0.02
    place(backend, 1, q)
    interventions.update()
    monitor.update(backend)
    assert monitor.counts["hard_limit"].tolist() == [0, 1]
    assert monitor.counts["soft_limit"].tolist() == [0, 0]  # beyond the band: hard, not soft
    assert monitor.any.tolist() == [0, 1] and monitor.ticks == 2
    assert interventions.any.tolist() == [1, 1]  # only the clamp of the first tick


def test_the_monitor_keeps_each_joints_ticks_and_deepest_crossing_up_and_lying_down(arm3):
    backend = SimBackend(arm3, mode="velocity", envs=2)
    monitor = ViolationMonitor(arm3, 2)
    names = arm3.joint_names
    q = arm3.home.copy()
    for past, down in ((0.03, False), (0.08, False), (0.05, False), (0.2, True)):
        q[1] = arm3.position_lower[1] - past  # env 1's elbow below its hard limit
        place(backend, 1, q)
        monitor.update(backend, down=np.array([False, down]))
    q[2] = arm3.position_upper[2] + 0.01  # and its wrist above, once, while up
    q[1] = arm3.home[1]
    place(backend, 1, q)
    monitor.update(backend, down=np.array([False, False]))
    depths = monitor.hard_limit_depths(1)
    assert list(depths) == [names[1], names[2]]  # most ticks first
    assert depths[names[1]]["ticks"] == 3 and depths[names[2]]["ticks"] == 1
    assert depths[names[1]]["depth_rad"] == pytest.approx(0.08, abs=1e-9)  # the deepest, up
    assert depths[names[2]]["depth_rad"] == pytest.approx(0.01, abs=1e-9)
    down = monitor.hard_limit_depths(1, down=True)
    assert down == {names[1]: {"ticks": 1, "depth_rad": pytest.approx(0.2, abs=1e-9)}}
    assert monitor.hard_limit_depths(0) == {}
    assert monitor.hard_limit_depths() == depths  # every env's: env 0 never crossed
    # a checkpoint keeps them
    again = ViolationMonitor(arm3, 2)
    again.load_state_dict(monitor.state_dict())
    assert again.hard_limit_depths(1) == depths


def test_deploy_run_names_the_joint_how_deep_and_how_long_when_it_exits_1(tmp_path, arm3, capsys):
    """A run whose true joint crosses its hard limit (a cable pulling the arm) exits 1 and says
    which joint, for how many ticks and how far past (rad) in its summary and its report."""
    import json

    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.cli.run_verdict import EXIT_HARD_VIOLATION
    from tests.runtime_fixtures import adversarial_onnx

    policy = adversarial_onnx(tmp_path, arm3, "position")
    report = tmp_path / "run.json"
    argv = ["--robot", "arm3", "--policy", str(policy), "--duration", "3"]
    argv += ["--inject", "cable=200@1.0:1.0", "--report", str(report)]
    assert deploy_run_main(argv) == EXIT_HARD_VIOLATION
    out = capsys.readouterr().out
    r = json.loads(report.read_text())
    joints = r["violations"]["hard_limit_joints"]
    assert r["hard_violations"]["hard_limit"] > 0 and joints
    # each joint's ticks are at most the run's hard-limit ticks, and one joint makes them all
    assert max(j["ticks"] for j in joints.values()) == r["hard_violations"]["hard_limit"]
    for name, j in joints.items():
        assert name in arm3.joint_names and j["depth_rad"] > 0.0
        line = (
            f"hard_limit: {name} past its hard limit on {j['ticks']} ticks, at most "
            f"{j['depth_rad']:.4f} rad"
        )
        assert line in out, out
    # the joints above their velocity limit too: the cable swings the arm past it
    assert r["hard_violations"]["velocity"] > 0
    speeds = r["violations"]["velocity_joints"]
    assert max(j["ticks"] for j in speeds.values()) <= r["hard_violations"]["velocity"]
    for name, j in speeds.items():
        assert j["excess"] > 0.0
        assert f"velocity: {name} above its velocity limit on {j['ticks']} ticks" in out, out


def test_each_violation_type_counts_once_per_tick_from_the_true_state(arm3):
    backend = SimBackend(arm3, mode="velocity", envs=4)
    monitor = ViolationMonitor(arm3, 4)
    monitor.update(backend)
    assert monitor.totals() == dict.fromkeys((*VIOLATION_TYPES, "any"), 0)  # home pose, at rest

    q = arm3.home.copy()
    q[1] = q[2] = arm3.soft_upper[1] + 0.05  # two joints in the soft band: one tick
    place(backend, 0, q)
    dq = np.zeros(3)
    dq[2] = -1.01 * arm3.velocity_limit[2]
    place(backend, 1, arm3.home, dq)
    place(backend, 2, np.array([1.4, 1.4, 0.0]))  # folded back behind the base plane x = -0.05
    backend.joint_torque()[3] = arm3.effort_limit  # saturated at the limit: not a violation
    monitor.update(backend)
    backend.joint_torque()[3, 1] = -1.001 * arm3.effort_limit[1]
    monitor.update(backend)
    c = {k: v.tolist() for k, v in monitor.counts.items()}
    assert c["soft_limit"] == [2, 0, 0, 0]
    assert c["velocity"] == [0, 2, 0, 0]
    assert c["workspace"] == [0, 0, 2, 0]
    assert c["effort"] == [0, 0, 0, 1]
    assert c["hard_limit"] == [0, 0, 0, 0] and c["self_collision"] == [0, 0, 0, 0]
    assert monitor.any.tolist() == [2, 2, 2, 1] and monitor.ticks == 3


def test_self_collision_at_the_true_configuration(arm6):
    """The guard's collision model at the true q: a configuration coal finds in contact."""
    guard = SafetyGuard(arm6, 1, "position")
    rng = np.random.default_rng(0)
    colliding = next(
        q
        for q in rng.uniform(arm6.soft_lower, arm6.soft_upper, (500, arm6.n_joints))
        if guard._in_collision(q)
    )
    backend = SimBackend(arm6, mode="position", envs=2)
    place(backend, 1, colliding)
    monitor = ViolationMonitor(arm6, 2)
    monitor.update(backend)
    assert monitor.counts["self_collision"].tolist() == [0, 1]
    assert monitor.any[1] >= 1


def test_violation_monitor_state_round_trip_and_errors(arm3):
    backend = SimBackend(arm3, mode="velocity", envs=2)
    place(backend, 1, np.array([arm3.position_upper[0] + 0.1, 0.5, 0.5]))
    a = ViolationMonitor(arm3, 2)
    for _ in range(3):
        a.update(backend)
    b = ViolationMonitor(arm3, 2)
    b.load_state_dict(a.state_dict(1), 1)
    assert b.counts["hard_limit"].tolist() == [0, 3] and b.ticks == 3
    bad = a.state_dict()
    bad["counts/velocity"] = np.zeros(5, dtype=np.int64)
    with pytest.raises(ValueError, match=r"field 'counts/velocity': expected shape \(2,\)"):
        b.load_state_dict(bad)
    bad = a.state_dict()
    del bad["any"]
    with pytest.raises(ValueError, match="field 'any' is missing"):
        b.load_state_dict(bad)


# ---------------------------------------------------------------- interventions: changed commands
def test_a_guard_velocity_clamp_is_an_intervention_and_its_fraction_of_ticks(arm3):
    guard, smoother, state, monitor = guarded(arm3, 1, "velocity")
    state.q[:, 2] = arm3.soft_upper[2] - 0.02  # close to the soft limit: the band is narrow
    fast = arm3.velocity_limit[2]
    clamped = 0
    for tick in range(40):
        target = np.array([[0.0, 0.0, fast if tick % 4 == 0 else 0.0]])
        before = target.copy()
        guard.filter(target, state, out=target)
        clamped += bool((target != before).any())
        monitor.update()
    assert clamped == 10
    s = monitor.summary()
    assert s["ticks"] == 40
    assert s["checks"]["velocity"] == {"count": 10, "fraction": 0.25}
    assert s["any"] == {"count": 10, "fraction": 0.25}
    assert all(s["checks"][k]["count"] == 0 for k in INTERVENTION_CHECKS if k != "velocity")


def test_smoother_clamps_count_once_per_tick_and_soft_band_estimate_is_a_warning(arm3):
    guard, smoother, state, monitor = guarded(arm3, 2, "velocity")
    # env 0: two joints beyond the soft velocity limit in one tick (the guard's band, the
    # hard velocity limit, lets them through): one tick of target_clamp
    target = np.zeros((2, 3))
    target[0, :2] = 0.99 * arm3.velocity_limit[:2]
    guard.filter(target, state, out=target)
    smoother.step(target)
    monitor.update()
    assert smoother.target_clamps_per_joint[0].tolist() == [1, 1, 0]
    assert monitor.counts["target_clamp"].tolist() == [1, 0]
    # env 1: the estimate in the soft band, zero target: the guard's soft_limit counter rises but
    # no command changed (velocity mode): a warning, not an intervention
    state.q[1, 2] = arm3.soft_upper[2] + 0.01
    guard.filter(np.zeros((2, 3)), state)
    smoother.step(np.zeros((2, 3)))
    monitor.update()
    assert guard.counts["soft_limit"].tolist() == [0, 1]
    assert monitor.warnings()["soft_band_estimate"].tolist() == [0, 1]
    assert monitor.any.tolist() == [1, 0] and monitor.counts["soft_limit"].tolist() == [0, 0]


def test_position_mode_soft_limit_clamps_are_interventions(arm3):
    guard, smoother, state, monitor = guarded(arm3, 1, "position")
    target = arm3.home[None, :].copy()
    target[0, 1] = arm3.soft_upper[1] + 0.05
    guard.filter(target, state, out=target)
    monitor.update()
    assert monitor.counts["soft_limit"].tolist() == [1] and monitor.any.tolist() == [1]
    assert monitor.warnings()["soft_band_estimate"].tolist() == [0]
    assert monitor.safety.tolist() == [1] and monitor.by_design == ()  # an arm's: judged


def test_a_legged_robots_pd_targets_past_its_range_pass_and_a_barrier_change_is_judged(go2):
    """A walking policy's PD targets pass its joints' ranges on every stride (legged_gym,
    Isaac Lab and mjlab train them unbounded): a target whose predicted motion is safe passes
    unchanged and nothing is counted; one the guard changes (``pd_barrier``: the joint would
    reach its hard limit) is an intervention like any other, judged (``safety``)."""
    guard, smoother, state, monitor = guarded(go2, 1, "position")
    assert monitor.by_design == ()
    target = go2.home[None, :].copy()
    target[0, 2] = go2.soft_upper[2] + 0.3
    guard.filter(target, state, out=target)
    monitor.update()
    assert monitor.any.tolist() == [0] and target[0, 2] == go2.soft_upper[2] + 0.3
    state.q[0, 2] = go2.position_upper[2] - 0.05
    state.dq[0, 2] = 8.0
    target[0, 2] = go2.position_upper[2] + 0.3
    guard.filter(target, state, out=target)
    monitor.update()
    assert monitor.counts["pd_barrier"].tolist() == [1] and monitor.any.tolist() == [1]
    assert monitor.safety.tolist() == [1]
    summary = monitor.summary()
    assert summary["safety"]["count"] == 1 and summary["by_design"] == []
    other = InterventionMonitor(guard, smoother)
    other.load_state_dict(monitor.state_dict())
    assert other.safety.tolist() == [1] and other.any.tolist() == [1]


def test_intervention_monitor_state_round_trip(arm3):
    guard, smoother, state, monitor = guarded(arm3, 2, "velocity")
    state.q[:, 2] = arm3.soft_upper[2] - 0.02
    for _ in range(3):
        guard.filter(np.full((2, 3), 3.0), state)
        monitor.update()
    other = InterventionMonitor(guard, smoother)
    other.load_state_dict(monitor.state_dict(1), 1)
    assert other.ticks == 3 and other.counts["velocity"].tolist() == [0, 3]
    with pytest.raises(ValueError, match="field 'ticks': expected shape"):
        other.load_state_dict({**monitor.state_dict(), "ticks": np.zeros(2, dtype=np.int64)})


# ---------------------------------------------------------------- goals: windows and misses
def test_success_windows_merge_a_short_final_window_and_skip_empty_ones():
    issued = [4, 0, 5, 5, 5, 10, 2, 1]  # per 600-s window; index 7 lies past the end
    reached = [4, 0, 5, 4, 5, 9, 1, 1]
    rows = success_windows(issued, reached, 600.0, 3800.0)
    # windows 0..5 full, [3600, 3800) is 200 s < 300 s: merged into [3000, 3800) with the
    # goal issued past the end; window 1 had no goal
    assert [(r["start_s"], r["end_s"], r["issued"], r["reached"]) for r in rows] == [
        (0.0, 600.0, 4, 4),
        (1200.0, 1800.0, 5, 5),
        (1800.0, 2400.0, 5, 4),
        (2400.0, 3000.0, 5, 5),
        (3000.0, 3800.0, 13, 11),
    ]
    assert rows[2]["success_rate"] == pytest.approx(0.8)
    assert rows[-1]["success_rate"] == pytest.approx(11 / 13)
    # a final window of half a window or more stands alone; one short window stays one window
    assert len(success_windows([1] * 7, [1] * 7, 600.0, 3900.0)) == 7
    assert success_windows([3], [1], 600.0, 100.0) == [
        {"start_s": 0.0, "end_s": 100.0, "issued": 3, "reached": 1, "success_rate": 1 / 3}
    ]
    with pytest.raises(ValueError, match="window: expected a number of seconds > 0"):
        success_windows([], [], 0.0, 10.0)


def test_goal_scheduler_records_missed_goals_up_to_its_cap(arm3):
    """A robot that never moves misses every goal but the ones within 5 cm of its hand: each miss
    is recorded with its true end state, past ``max_missed`` only counted."""
    backend = SimBackend(arm3, mode="velocity", envs=1)
    guard, smoother, state, monitor = guarded(arm3, 1, "velocity")
    rt = SimpleNamespace(
        time=0.0, mode=np.full(1, 2), goal=np.zeros((1, 3)), backend=backend, state=state
    )
    goals = GoalScheduler(
        arm3, 1, 0.5, None, 0.3, np.random.default_rng(3), 2.0, monitor, max_missed=3
    )
    for tick in range(int(round(4.0 / arm3.control_period)) + 1):
        rt.time = tick * arm3.control_period
        if tick % 10 == 0:  # some guard clamps along the way
            guard.counts["velocity"] += 1
        monitor.update()
        goals(rt)
    assert goals.issued[0] == 9 and goals.hit_count[0] == 0
    assert len(goals.missed[0]) == 3 and goals.missed_dropped[0] == 5
    first = goals.missed[0][0]
    assert first["t_s"] == pytest.approx(0.5) and first["issued_s"] == 0.0
    assert first["q"] == pytest.approx(arm3.home.tolist(), abs=1e-3)
    assert first["q_estimate"] == arm3.home.tolist()
    ee = arm3.forward_kinematics(arm3.home)
    assert first["distance_m"] == pytest.approx(np.linalg.norm(ee - first["goal"]), abs=1e-3)
    assert first["best_distance_m"] == pytest.approx(first["distance_m"], abs=1e-3)
    assert first["best_distance_m"] > arm3.config.task.success_radius
    assert first["interventions"]["velocity"] == 10 and first["interventions"]["any"] == 10
    assert set(first["interventions"]) == {*INTERVENTION_CHECKS, "any"}
    assert goals.window_issued[0] == [4, 4, 1] and goals.window_reached[0] == []


@pytest.mark.parametrize("name", ["go2", "arm6"])
def test_distances_measured_less_often_count_the_same_collisions(name, request, monkeypatch):
    """An env checked by coal on consecutive ticks has its pairs' distances measured only every
    ``DISTANCE_REFRESH`` checks: the screen stays exact, so the self-collisions, the pairs that
    touched and every other count equal a monitor measuring them at each check, over trajectories
    that move fast (every tick checked), rest (screened out) and pass through contacts."""
    from types import SimpleNamespace

    from sim2real.deploy.monitors import violations

    robot = request.getfixturevalue(name)
    envs, n, rng = 2, robot.n_joints, np.random.default_rng(4)
    lo, hi = robot.position_lower, robot.position_upper
    q, dq, tau = np.tile(robot.home, (envs, 1)), np.zeros((envs, n)), np.zeros((envs, n))
    backend = SimpleNamespace(
        true_position=lambda: q, true_velocity=lambda: dq, joint_torque=lambda: tau,
        end_effector_position=lambda out: out,
    )  # fmt: skip
    monitors = {k: ViolationMonitor(robot, envs, pair_bounds=False) for k in (16, 1)}
    measured = {16: 0, 1: 0}
    query = violations.collision_query

    def counted(*args, distances=None):
        if distances is not None:
            measured[current] += 1
        return query(*args, distances=distances)

    monkeypatch.setattr(violations, "collision_query", counted)
    for tick in range(1500):
        phase = (tick // 100) % 3  # fast, at rest, jumps about (contacts)
        if phase == 0:
            q += rng.normal(0.0, 0.08, (envs, n))
        elif phase == 2 and tick % 5 == 0:
            q[:] = rng.uniform(lo, hi, (envs, n))
        np.clip(q, lo, hi, out=q)
        for refresh, monitor in monitors.items():
            current = refresh
            monkeypatch.setattr(violations, "DISTANCE_REFRESH", refresh)
            monitor.update(backend, down=np.zeros(envs, dtype=bool))
    a, b = monitors[16].state_dict(), monitors[1].state_dict()
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    assert monitors[16].counts["self_collision"].sum() > 0  # contacts were met
    assert measured[16] < measured[1] / 2  # and distances measured far less often


def _touching_pose(robot, rng, model, data, geom_model, geom_data):
    """A pose drawn within the hard limits at which some collision pair touches (coal, every
    pair), or None after 400 draws."""
    import pinocchio as pin

    for _ in range(400):
        q = rng.uniform(robot.position_lower, robot.position_upper)
        if pin.computeCollisions(model, data, geom_model, geom_data, q, True):
            return q
    return None


@pytest.mark.parametrize(("name", "bounds"), [("go2", False), ("go2", True), ("arm6", True)])
def test_the_screened_monitor_counts_what_checking_every_pair_counts(
    name, bounds, request, monkeypatch
):
    """Over trajectories that glide from free poses into contact and out again, hold in contact,
    wander and rest, the monitor (its screen sparing coal, its distances measured now and then,
    or bounded by the compiled pair bounds where the model has them: go2's capsules, spheres and
    box) counts the same self-collisions, the same pairs touching and every other count as the
    reference, which checks every pair on every tick; its screen spared checks, and long runs of
    checks were met (with the bounds: coal ran on fewer than 3 checks in 4)."""
    from sim2real.deploy.monitors import violations
    from sim2real.deploy.monitors.reference import ReferenceViolationMonitor
    from sim2real.deploy.safety.collision import collision_model

    robot = request.getfixturevalue(name)
    envs, n, rng = 2, robot.n_joints, np.random.default_rng(11)
    lo, hi = robot.position_lower, robot.position_upper
    geom_model, geom_data = collision_model(robot)
    model = robot.fixed_base_model
    data = model.createData()
    q, dq, tau = np.tile(robot.home, (envs, 1)), np.zeros((envs, n)), np.zeros((envs, n))
    backend = SimpleNamespace(
        true_position=lambda: q, true_velocity=lambda: dq, joint_torque=lambda: tau,
        end_effector_position=lambda out: out,
    )  # fmt: skip
    ours = ViolationMonitor(robot, envs, pair_bounds=bounds)
    reference = ReferenceViolationMonitor(robot, envs)
    bounded = ours._pair_bounds is not None
    assert bounded == (bounds and name == "go2")  # arm6's cylinders: coal's distances
    queries, query = [0], violations.collision_query

    def counted(*args, **kwargs):
        queries[0] += 1
        return query(*args, **kwargs)

    monkeypatch.setattr(violations, "collision_query", counted)
    paths = [[] for _ in range(envs)]
    ticks, checks, longest = 1500, 0, 0
    for _ in range(ticks):
        for e in range(envs):
            if not paths[e]:  # a new leg of the trip: glide into a contact, hold, glide out
                start = q[e].copy()
                goal = _touching_pose(robot, rng, model, data, geom_model, geom_data)
                if goal is None or rng.random() < 0.2:  # or wander, then rest
                    goal = np.clip(start + rng.normal(0.0, 0.3, n), lo, hi)
                steps = int(rng.integers(10, 60))
                glide = [start + (goal - start) * (k + 1) / steps for k in range(steps)]
                back = np.clip(goal + rng.normal(0.0, 0.4, n), lo, hi)
                away = [goal + (back - goal) * (k + 1) / 10 for k in range(10)]
                rest = [robot.home] * int(rng.integers(0, 60))  # clear of every pair
                paths[e] = glide + [goal] * int(rng.integers(0, 6)) + away + rest
            q[e] = paths[e].pop(0)
        down = np.zeros(envs, dtype=bool)
        ours.update(backend, down=down)
        reference.update(backend, down=down)
        checks += int(ours._need.sum())
        longest = max(longest, int(ours._run.max()))
    a, b = ours.state_dict(), reference.state_dict()
    for key in a:
        assert np.array_equal(a[key], b[key]), key
    assert ours.counts["self_collision"].sum() > 50
    assert ours.pair_ticks.astype(bool).sum() > 2  # several pairs touched
    assert checks < 0.9 * ticks * envs  # the screen spared coal
    if bounded:
        assert queries[0] < 0.75 * checks, (queries, checks)  # coal at each check without
    else:
        assert longest > 4 * violations.DISTANCE_REFRESH  # past several refreshes of distances
