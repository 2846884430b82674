"""One task protocol and one choice of it (sim2real.deploy.tasks.task.task_for), one robot kind
(sim2real.deploy.robot_kind): an arm reaches goals, a legged robot follows velocity commands, in deploy-run,
the soak and training alike."""

import numpy as np
import pytest

from sim2real.deploy.kinds import ARM, LEGGED, robot_kind
from sim2real.deploy.tasks.episodes import EpisodeCommands, EpisodeGoals
from sim2real.deploy.tasks.goals import GoalTask
from sim2real.deploy.tasks.task import follows_velocity_commands, task_entry, task_for
from sim2real.deploy.tasks.velocity import VelocityTask


class _Runtime:
    """What a task reads and writes of a runtime, for envs that never run."""

    def __init__(self, envs):
        self.goal = np.zeros((envs, 3))
        self.velocity_command = np.zeros((envs, 3))
        self.mode = np.zeros(envs, dtype=np.int64)  # not RUNNING
        self.time, self.ticks = 0.0, 0


def test_the_kind_of_a_robot_chooses_its_runtime_stages_and_task(arm3, go2):
    assert robot_kind(arm3) is ARM and robot_kind(go2) is LEGGED
    assert ARM.base_stages(arm3, 2) == (None, None)
    estimator, fall = LEGGED.base_stages(go2, 2)
    assert estimator is not None and fall is not None
    assert ARM.state(arm3, 2).base is None
    legged = LEGGED.state(go2, 2)
    assert legged.command.shape == (2, 3) and legged.foot_contact.shape == (2, go2.n_feet)
    # the part of the tick each kind's base adds: none for an arm (its estimate and observation
    # fuse), a legged robot's estimate, falls and damped stops
    from types import SimpleNamespace

    from sim2real.deploy.core.modes import RUNNING, SAFE_STOP

    fixed = ARM.tick_stage(SimpleNamespace(robot=arm3, envs=2, backend=None))
    assert fixed.fusable and fixed.stages == (None, None) and fixed.parts() == {}
    modes = np.array([RUNNING, SAFE_STOP], dtype=np.int8)
    assert not fixed.damping(modes).any()
    no_phase = SimpleNamespace(observation_blocks=())  # a spec without a motion_phase block
    floating = LEGGED.tick_stage(
        SimpleNamespace(robot=go2, envs=2, backend=None, spec=no_phase, state=legged, dt=0.02)
    )
    assert not floating.fusable and set(floating.parts()) == {"base_estimator", "fall_detector"}
    assert floating.damping(modes).tolist() == [False, True]
    assert task_entry(arm3).velocity_commands is False
    assert follows_velocity_commands(go2) and not follows_velocity_commands(arm3)


def test_task_for_gives_an_arm_goals_and_a_legged_robot_velocity_commands(arm3, go2):
    streams = [np.random.default_rng(s) for s in (1, 2)]
    goals = task_for(arm3, 2, None, period=4.0, rng=streams)
    assert isinstance(goals, GoalTask) and goals.name == "goals"
    soak = task_for(go2, 2, None, period=4.0, rng=streams)
    assert isinstance(soak, VelocityTask) and soak.schedule is not None
    assert set(soak.parts()) == {"commands", "tracker"}
    run = task_for(go2, 2, None, period=4.0, rng=streams[0], command="0.5,0,0.1", schedule=False)
    assert run.schedule is None and run.report(_Runtime(2))["goals"] is None
    rt = _Runtime(2)
    run.reset(rt, np.ones(2, dtype=bool))
    np.testing.assert_array_equal(rt.velocity_command, [[0.5, 0.0, 0.1]] * 2)
    with pytest.raises(ValueError, match="VX,VY,WZ"):
        task_for(go2, 2, None, period=4.0, rng=streams[0], command="fast")


def test_a_task_state_round_trips_under_its_checkpoint_prefixes(arm3, go2):
    for robot in (arm3, go2):
        task = task_for(robot, 2, None, period=4.0, rng=[np.random.default_rng(s) for s in (1, 2)])
        state = task.state_dict()
        prefixes = {key.split("/")[0] for key in state}
        assert prefixes == set(task.parts())
        task.load_state_dict(state)
        assert task.success() is None  # nothing issued or run yet
    clock = np.zeros(2)
    for robot, prefix in ((arm3, "goals"), (go2, "commands")):
        task = task_for(robot, 2, None, period=1.0, rng=np.random.default_rng(0), clock=clock)
        task.reset(_Runtime(2), np.ones(2, dtype=bool))
        state = task.state_dict()
        assert {key.split("/")[0] for key in state} == {prefix}
        again = task_for(robot, 2, None, period=1.0, rng=np.random.default_rng(1), clock=clock)
        again.load_state_dict(state)
        for key, value in again.state_dict().items():
            np.testing.assert_array_equal(value, state[key])


def test_training_tasks_are_episodic_on_the_trainer_clock(arm3, go2):
    clock = np.zeros(2)
    goals = task_for(arm3, 2, None, period=3.0, rng=np.random.default_rng(0), clock=clock)
    assert isinstance(goals, EpisodeGoals)
    goals.reset(None, np.ones(2, dtype=bool))
    first = goals.goal.copy()
    clock += 3.0  # the goals time out
    goals.judge(goals.goal + 1.0)  # far from them
    goals(None)
    assert goals.new.all() and (goals.missed == 1).all() and not np.allclose(goals.goal, first)
    commands = task_for(go2, 2, None, period=0.5, rng=np.random.default_rng(0), clock=clock)
    assert isinstance(commands, EpisodeCommands)
    rt = _Runtime(2)
    commands.reset(rt, np.array([True, False]))
    assert rt.velocity_command[1].tolist() == [0.0, 0.0, 0.0]


def test_a_straight_command_holds_the_heading_it_began_with():
    """legged_gym's heading command: while RUNNING with a zero yaw rate asked, the policy is
    given ``gain * wrap(reference - yaw)`` clipped to 1 rad/s, the reference taken when the hold
    began; a yaw rate asked passes unchanged; a stop lets go, so the next walk holds its own
    heading. The state round-trips."""
    from sim2real.deploy.core.state import BaseState
    from sim2real.deploy.tasks.heading import HeadingHold

    def turned(yaw):  # base-to-world quaternions of yaw angles
        return np.stack([np.cos(np.asarray(yaw) / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], 1)

    class Rt:
        mode = np.array([2, 2, 2])  # RUNNING
        state = type("S", (), {"base": BaseState.zeros(3)})()
        velocity_command = np.zeros((3, 3))

    rt, hold = Rt(), HeadingHold(3, gain=0.5)
    asked = np.array([[0.5, 0, 0], [0.5, 0, 0], [0.5, 0, 0.3]])
    rt.state.base.orientation[:] = turned(np.array([0.1, 3.0, 0.0]))
    hold(rt, asked)  # the hold begins at these headings
    np.testing.assert_allclose(rt.velocity_command[:, 2], [0.0, 0.0, 0.3], atol=1e-12)
    rt.state.base.orientation[:] = turned(np.array([0.0, -3.0, 0.0]))  # env 1 across +-pi
    hold(rt, asked)
    np.testing.assert_allclose(rt.velocity_command[:, 2], [0.05, -0.5 * (2 * np.pi - 6.0), 0.3])
    rt.state.base.orientation[:] = turned(np.array([-3.0, -3.0, 0.0]))
    hold(rt, asked)
    assert rt.velocity_command[0, 2] == 1.0  # clipped
    again = HeadingHold(3, gain=0.5)
    again.load_state_dict(hold.state_dict())
    np.testing.assert_allclose(again.reference, [0.1, 3.0, 0.0])
    rt.mode = np.array([4, 2, 2])  # env 0 stopped: let go
    hold(rt, asked)
    assert not hold.holding[0] and rt.velocity_command[0, 2] == 0.0
    rt.mode = np.array([2, 2, 2])
    hold(rt, asked)  # walks again: holds the heading it has now
    assert hold.reference[0] == pytest.approx(-3.0)
    with pytest.raises(ValueError, match="gain"):
        HeadingHold(1, gain=0.0)


def test_a_backwards_command_is_taken_as_the_value_it_is():
    """``deploy-run --command -0.5,0,0`` was refused by argparse ("expected one argument": a
    value starting with '-' that is not a plain number looks like an option); now it walks
    backwards, as ``--command=-0.5,0,0`` always did."""
    from sim2real.deploy.cli.run_parser import attach_vectors, build_parser

    argv = attach_vectors(["--policy", "p.onnx", "--command", "-0.5,0,0", "--goal", "-0.1,0.2,0"])
    args = build_parser(argv).parse_args(argv)
    assert args.command == "-0.5,0,0" and args.goal == "-0.1,0.2,0"
    assert attach_vectors(["--command", "0.5,0,0", "--seed", "1"]) == [
        "--command",
        "0.5,0,0",
        "--seed",
        "1",
    ]


def test_a_robot_settling_to_a_new_command_is_tracking_it():
    """No robot follows a step of its command at once: the SETTLE_TIME after each change of the
    planar command counts as tracked, and after it the error counts again (a robot that never
    moves is untracked from then on). The soak's new command every 4 s left a humanoid that
    takes about 1 s to reach each one 77 % tracked at best."""
    from sim2real.deploy.core.state import BaseState
    from sim2real.deploy.tasks.locomotion import SETTLE_TIME, CommandTracker

    class Rt:
        def __init__(self):
            self.mode = np.array([2])  # RUNNING
            self.state = type("S", (), {"base": BaseState.zeros(1)})()
            self.velocity_command = np.zeros((1, 3))
            self.time, self.ticks = 0.0, 0
            self.cause = np.array([-1])

    rt, dt = Rt(), 0.02
    tracker = CommandTracker(1, dt, backend=None)
    tracked = []
    for k in range(300):  # 6 s: still, then a 1 m/s command at 2 s the robot never follows
        if k == 100:
            rt.velocity_command[0, 0] = 1.0
        rt.ticks, rt.time = k, k * dt
        tracker(rt)
        tracked.append(float(tracker.tracked_time[0]))
    change = 100
    settle = round(SETTLE_TIME / dt)
    assert tracked[change + settle - 1] - tracked[change - 1] == pytest.approx(SETTLE_TIME)
    assert tracked[-1] == pytest.approx(tracked[change + settle])  # untracked after settling
    # a joystick's gradual change (0.01 m/s a tick) is no step: nothing is given for settling
    before = float(tracker.tracked_time[0])
    for k in range(300, 400):
        rt.velocity_command[0, 0] = 1.0 + 0.01 * (k - 299)
        rt.ticks, rt.time = k, k * dt
        tracker(rt)
    assert float(tracker.tracked_time[0]) == before
    again = CommandTracker(1, dt, backend=None)
    again.load_state_dict(tracker.state_dict())
    np.testing.assert_array_equal(again.changed_at, [2.0])
