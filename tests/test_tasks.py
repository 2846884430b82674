"""One task protocol and one choice of it (deploy.tasks.task.task_for), one robot kind
(deploy.robot_kind): an arm reaches goals, a legged robot follows velocity commands, in deploy-run,
the soak and training alike."""

import numpy as np
import pytest

from deploy.robot_kind import ARM, LEGGED, robot_kind
from deploy.tasks.episodes import EpisodeCommands, EpisodeGoals
from deploy.tasks.goals import GoalTask
from deploy.tasks.locomotion import VelocityTask
from deploy.tasks.task import task_for


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
