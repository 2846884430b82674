"""The ranges a session draws from: each robot kind's defaults (session_ranges), a TOML file's
overrides (load_ranges) and their errors, and training drawing from the same ranges as the soak.

soak-test --ranges end to end: tests/test_soak.py."""

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from sim2real.eval.world.dynamics import DynamicsRanges
from sim2real.eval.world.fault_schedule import fault_ranges
from sim2real.eval.world.floor import FLOOR_FRICTION
from sim2real.eval.world.ranges_file import RangesError, load_ranges
from sim2real.eval.world.sensors import ImuRanges
from sim2real.eval.world.session_draw import sample_session
from sim2real.eval.world.session_ranges import (
    LEGGED_DYNAMICS,
    LEGGED_SENSORS,
    SessionRanges,
    sensor_ranges,
    session_ranges,
)

EXAMPLE = (
    Path(__file__).resolve().parent.parent / "sim2real" / "eval" / "world" / "example_ranges.toml"
)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "ranges.toml"
    path.write_text(text)
    return path


def test_each_robot_kind_gets_its_own_defaults(arm3, go2):
    arm = session_ranges(arm3, 30.0)
    assert arm.sensors == sensor_ranges(arm3) and arm.dynamics == DynamicsRanges()
    assert arm.faults == fault_ranges(arm3, 30.0) and arm.faults.mean_interval == 30.0
    assert arm.imu is None and arm.floor_friction is None  # an arm draws neither
    legged = session_ranges(go2)
    assert (legged.dynamics, legged.sensors) == (LEGGED_DYNAMICS, LEGGED_SENSORS)
    assert legged.imu == ImuRanges() and legged.floor_friction == FLOOR_FRICTION


def test_the_example_file_overrides_only_what_it_sets(arm3):
    ranges = load_ranges(EXAMPLE, arm3)
    default = session_ranges(arm3)
    assert ranges.dynamics.mass == 0.3 and ranges.dynamics.friction == 0.6
    assert ranges.dynamics.link_length == default.dynamics.link_length
    assert ranges.sensors.noise_sigma == (0.004, 0.04) and ranges.sensors.latency_ticks == (0, 3)
    assert ranges.drift.friction_rate == (0.02, 0.08)
    assert ranges.faults.mean_interval == 90.0 and ranges.faults.push_force == (5.0, 20.0)
    assert ranges.faults.weights == (1.0, 1.0, 1.0, 1.0, 2.0, 1.0)
    assert ranges.faults.cable_force == default.faults.cable_force
    assert (ranges.imu, ranges.floor_friction) == (None, None)
    # the file wins over the fault interval given with it; without the key, the interval holds
    assert load_ranges(EXAMPLE, arm3, mean_interval=10.0).faults.mean_interval == 90.0


def test_a_value_in_the_file_reaches_the_sessions_draw(tmp_path, arm3, go2):
    arm = write(tmp_path, "[sensors]\nnoise_sigma = [0.05, 0.05]\n[dynamics]\nmass = 0\n")
    draw = sample_session(arm3, 4, 60.0, load_ranges(arm, arm3), faults=False)
    assert draw.sensors.noise_sigma == 0.05
    assert draw.dynamics.mass == (1.0,) * arm3.n_joints
    assert sample_session(arm3, 4, 60.0, session_ranges(arm3), faults=False).sensors != (
        draw.sensors
    )
    legged = write(
        tmp_path,
        "floor_friction = [0.9, 0.9]\n[imu]\ngyro_noise_sigma = [0.07, 0.07]\n"
        "[faults]\nkinds = ['push']\nmean_interval = 20.0\n",
    )
    draw = sample_session(go2, 4, 300.0, load_ranges(legged, go2, mean_interval=100.0))
    assert draw.floor_friction == 0.9 and draw.imu.gyro_noise_sigma == 0.07
    assert draw.faults and {f.kind for f in draw.faults} == {"push"}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[sensors]\nnoise = [0.01, 0.02]\n", "sensors.noise: unknown key; expected one of"),
        ("[sensor]\nnoise_sigma = [0.01, 0.02]\n", "unknown key 'sensor'; expected one of"),
        (
            "[sensors]\nnoise_sigma = [0.02, 0.01]\n",
            "sensors.noise_sigma: expected a range (low, high) with 0.0 <= low <= high, got "
            "(0.02, 0.01)",
        ),
        ("floor_friction = [1.0, 0.5]\n", "floor_friction: expected a range (low, high)"),
        ("[dynamics]\nmass = 'high'\n", "dynamics.mass: expected a number, got 'high'"),
        ("[dynamics]\nmass = 1.5\n", "dynamics.mass: expected a value in [0, 1), got 1.5"),
        (
            "[sensors]\nlatency_ticks = [0, 1.5]\n",
            "sensors.latency_ticks: expected a range [low, high] of two integers, got [0, 1.5]",
        ),
        (
            "[faults]\nkinds = 'push'\n",
            "faults.kinds: expected a list of strings, got 'push'",
        ),
        ("[faults]\nkinds = ['sneeze']\n", "faults.kinds: 'sneeze' is unknown"),
        ("drift = 0.1\n", "drift: expected a table [drift], got 0.1"),
        ("[sensors\n", "not valid TOML"),
    ],
)
def test_a_bad_file_names_the_file_the_key_and_the_value_expected(tmp_path, go2, text, message):
    path = write(tmp_path, text)
    with pytest.raises(RangesError) as info:
        load_ranges(path, go2)
    assert str(info.value).startswith(f"{path}: ")
    assert message in str(info.value)


@pytest.mark.parametrize(
    "text",
    ["floor_friction = [0.6, 1.0]\n", "[imu]\nbias_scale = [1, 2]\n", "[commands]\nvx = [0, 1]\n"],
)
def test_an_arm_refuses_the_floating_base_ranges(tmp_path, arm3, text):
    path = write(tmp_path, text)
    with pytest.raises(RangesError, match=f"{path}: .*robot arm3 has a fixed base"):
        load_ranges(path, arm3)


def test_the_velocity_commands_come_from_the_file_or_the_policys_contract(tmp_path, go2):
    """A legged soak draws its commands from a ranges file's ``[commands]``; without one,
    ``soak-test`` takes a policy's training ranges from the contract its stack wrote (Unitree's
    deploy.yaml ``commands.base_velocity.ranges``): the published G1 policy stands still below
    0.35 m/s and was trained on -0.5..1.0, so the default 0..0.5 judged it on commands it never
    learned. The soak's schedule draws from them."""
    from sim2real.deploy.tasks.commands import CommandRanges
    from sim2real.deploy.tasks.task import task_for
    from sim2real.eval.world.domain import contract_commands
    from tests import foreign_stacks as fs

    path = write(
        tmp_path, "[commands]\nvx = [-0.5, 1.0]\nyaw_rate = [-1, 1]\nzero_fraction = 0.1\n"
    )
    ranges = load_ranges(path, go2)
    assert ranges.commands == CommandRanges(vx=(-0.5, 1.0), yaw_rate=(-1.0, 1.0), zero_fraction=0.1)
    assert session_ranges(go2).commands is None  # the soak's default: the contract's, or ours
    streams = [np.random.default_rng(s) for s in (1, 2)]
    task = task_for(go2, 2, None, period=4.0, rng=streams, ranges=ranges.commands)
    assert task.schedule.ranges is ranges.commands
    default = [fs.mjlab_pose(n) for n in fs.MJLAB_ORDER]
    policy = fs.write_unitree_policy(tmp_path / "v0", fs.unitree_deploy(range(12), default), 45)
    commands, where = contract_commands(policy)
    assert commands == CommandRanges(vx=(-0.5, 1.0), vy=(-0.5, 0.5), yaw_rate=(-1.0, 1.0))
    assert where.endswith("deploy.yaml")


def test_a_missing_file_is_named(tmp_path, arm3):
    with pytest.raises(RangesError, match="nothing.toml: cannot read the ranges file"):
        load_ranges(tmp_path / "nothing.toml", arm3)


def test_every_range_class_field_can_be_set_from_a_file():
    """The file's schema is the classes': every field of every table is a key of it, directly or
    through an inline table (``[dynamics] com_offset``, ``[pushes] velocity``)."""
    from sim2real.eval.world.ranges_file import FIELDS, SUBTABLES, TABLES, TOP_LEVEL

    assert set(FIELDS) | set(TOP_LEVEL) == {f.name for f in fields(SessionRanges)}
    assert set(FIELDS) - set(TABLES) == {field for field, _ in SUBTABLES.values()} - set(TABLES)
    for field, cls in FIELDS.items():
        inner = {k for f, keys in SUBTABLES.values() if f == field for k in keys}
        if field not in TABLES:  # an inline table only: it sets every field of its class
            assert inner == {f.name for f in fields(cls)}


# ====================================================================== training
def test_so101_training_draws_the_encoder_noise_of_its_soak(so101):
    """The SO-101's reach task draws its encoder noise from the range its soak draws from (0.4-2
    counts of its encoders), not from the seed's absolute range (4-20 counts)."""
    from sim2real.policies.envs import ReachConfig, ReachTask

    soak = session_ranges(so101).sensors
    task = ReachTask(so101, 8, ReachConfig(dynamics=DynamicsRanges.none(), mode="position"))
    assert task.config.sensors == soak
    low, high = soak.noise_sigma
    assert np.all((task.backend.noise_sigma >= low) & (task.backend.noise_sigma <= high))


def test_arm3_training_draws_what_it_drew_before(arm3):
    """arm3's soak ranges are the seed's absolute ones: its training world is unchanged."""
    from sim2real.eval.world.sensors import SensorRanges
    from sim2real.policies.envs import ReachConfig, ReachTask

    task = ReachTask(arm3, 2, ReachConfig())
    assert task.config.sensors == SensorRanges() and task.config.dynamics == DynamicsRanges()


def test_the_training_recipe_draws_from_the_ranges_file(tmp_path, so101, monkeypatch):
    """``python -m sim2real.policies.train --ranges FILE``: the task draws from the file's ranges (over
    the robot's defaults), and the checkpoint records the file."""
    pytest.importorskip("stable_baselines3")
    import sim2real.policies.train as train
    from sim2real.deploy.policy.mlp_checkpoint import read_checkpoint

    seen = []

    class Spy(train.ReachTask):
        def __init__(self, robot, envs, config, seed=0):
            super().__init__(robot, envs, config, seed=seed)
            seen.append(self)

    monkeypatch.setattr(train, "ReachTask", Spy)
    path = write(tmp_path, "[sensors]\nnoise_sigma = [0.002, 0.003]\n[dynamics]\nmass = 0.25\n")
    args = ["--robot", "so101", "--mode", "position", "--steps", "64", "--envs", "2"]
    args += ["--n-steps", "32", "--batch-size", "32", "--anneal-steps", "0", "--gate-hours", "0"]
    args += ["--logdir", str(tmp_path), "--out", str(tmp_path / "ship.pt"), "--no-progress"]
    assert train.main([*args, "--ranges", str(path)]) == 0
    (task,) = seen
    assert task.config.sensors.noise_sigma == (0.002, 0.003)
    assert task.config.sensors.latency_ticks == session_ranges(so101).sensors.latency_ticks
    assert task.config.dynamics.mass == 0.25
    assert np.all((task.backend.noise_sigma >= 0.002) & (task.backend.noise_sigma <= 0.003))
    assert read_checkpoint(tmp_path / "ship.pt").info["ranges"] == str(path)


def test_every_unknown_key_is_named_in_one_refusal(tmp_path, go2):
    """Unknown keys at the top level, in a table and in an inline sub-table, with a wrong type
    beside them: one refusal names the three unknown keys, each with what the place takes, so
    one round of fixes does (before: only the first, 'unknown key 'sensor'', then the next
    after each fix)."""
    path = write(
        tmp_path,
        "[sensor]\nnoise_sigma = [0.01, 0.02]\n"
        "[dynamics]\nmass = 'high'\nmas = [0, 0.1]\ncom_offset = {x = [0, 0.01], w = [0, 1]}\n",
    )
    with pytest.raises(RangesError) as info:
        load_ranges(path, go2)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    assert "unknown key 'sensor'; expected one of" in message
    assert "dynamics.mas: unknown key; expected one of" in message
    assert "dynamics.com_offset.w: unknown key; expected one of body, x, y, z" in message
