"""Heading commands as legged_gym's command manager gives them: a heading drawn
in its range in place of the yaw rate, and every tick the yaw-rate command
``clip(stiffness * wrap_to_pi(heading - yaw), -max, max)`` of legged_gym's
``_post_physics_step_callback`` (``legged_gym/envs/base/legged_robot.py``; HIMLoco's fork clips
to +-2), the yaw the base estimate's; the ranges file's keys, the schedule's account and its
checkpoint."""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from sim2real.deploy.core.modes import RUNNING, SAFE_STOP
from sim2real.deploy.tasks.commands import CommandRanges, CommandSchedule
from sim2real.eval.world.command_schedule import command_schedule, schedule_text
from sim2real.eval.world.ranges_file import RangesError, load_ranges
from sim2real.eval.world.session_draw import session_rng


def _quat(yaw, roll=0.0, pitch=0.0):
    """(n, 4) w, x, y, z of Z-Y-X Euler angles (rad)."""
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def _legged_gym_rate(heading, q_wxyz, stiffness, clip):
    """legged_gym's expression, in its own steps: ``forward = quat_apply(base_quat,
    forward_vec)``, ``heading = atan2(forward[:, 1], forward[:, 0])``,
    ``clip(0.5 * wrap_to_pi(commands[:, 3] - heading), -1, 1)`` (isaacgym's ``quat_apply`` of
    x, y, z, w quaternions; ``wrap_to_pi``: ``angles %= 2*pi; angles -= 2*pi * (angles > pi)``)."""
    xyz, w = q_wxyz[:, 1:], q_wxyz[:, :1]
    v = np.tile([1.0, 0.0, 0.0], (len(q_wxyz), 1))
    t = 2.0 * np.cross(xyz, v)
    forward = v + w * t + np.cross(xyz, t)
    yaw = np.arctan2(forward[:, 1], forward[:, 0])
    angles = (heading - yaw) % (2 * np.pi)
    angles -= 2 * np.pi * (angles > np.pi)
    return np.clip(stiffness * angles, -clip, clip)


def _runtime(envs, orientation):
    return SimpleNamespace(
        mode=np.full(envs, RUNNING, dtype=np.int8),
        time=0.0,
        velocity_command=np.zeros((envs, 3)),
        state=SimpleNamespace(base=SimpleNamespace(orientation=orientation)),
    )


def _streams(envs, seed=3):
    return [session_rng(seed + e, "goals") for e in range(envs)]


@pytest.mark.parametrize(("stiffness", "clip"), [(0.5, 1.0), (0.5, 2.0), (2.0, 1.0)])
def test_heading_is_drawn_in_its_range_and_turned_into_legged_gyms_yaw_rate(stiffness, clip):
    envs = 64
    rng = np.random.default_rng(0)
    ranges = CommandRanges(
        vx=(-1.0, 1.0), heading_command=True, heading=(-3.14, 3.14), zero_fraction=0.0,
        heading_stiffness=stiffness, max_yaw_rate=clip,
    )  # fmt: skip
    q = _quat(
        rng.uniform(-np.pi, np.pi, envs), rng.uniform(-0.3, 0.3, envs), rng.uniform(-0.3, 0.3, envs)
    )
    rt = _runtime(envs, np.ascontiguousarray(q))
    schedule = CommandSchedule(envs, 10.0, _streams(envs), ranges)
    schedule(rt)
    # the heading is the stream's fourth draw (standing or not, vx, vy, heading)
    for e, stream in enumerate(_streams(envs)):
        stream.random(), stream.uniform(-1, 1), stream.uniform(0, 0)
        assert schedule.heading[e] == stream.uniform(-3.14, 3.14)
    assert (np.abs(schedule.heading) <= 3.14).all()
    expected = _legged_gym_rate(schedule.heading, q, stiffness, clip)
    assert np.allclose(rt.velocity_command[:, 2], expected, rtol=0, atol=1e-12)
    assert (np.abs(rt.velocity_command[:, 2]) <= clip).all()
    if stiffness * np.pi > clip:  # some headings far enough to be clipped
        assert (np.abs(rt.velocity_command[:, 2]) == clip).any()
    # the next tick: the robot has turned; the same heading, the new error (a stopped env: held)
    q2 = _quat(rng.uniform(-np.pi, np.pi, envs))
    rt.state.base.orientation[:] = q2
    rt.mode[0], before = SAFE_STOP, rt.velocity_command[0, 2]
    rt.time = 0.02
    schedule(rt)
    expected = _legged_gym_rate(schedule.heading, q2, stiffness, clip)
    assert np.allclose(rt.velocity_command[1:, 2], expected[1:], rtol=0, atol=1e-12)
    assert rt.velocity_command[0, 2] == before


def test_with_heading_commands_the_raw_yaw_rate_range_is_not_drawn():
    """legged_gym draws the heading ``else`` the yaw rate; Isaac Lab's ``rel_heading_envs``
    (``heading_fraction``) leaves the rest of the commands to the raw range."""
    envs = 200
    q = _quat(np.zeros(envs))
    ranges = CommandRanges(
        yaw_rate=(5.0, 6.0), heading_command=True, zero_fraction=0.0, max_yaw_rate=2.0
    )
    rt = _runtime(envs, q)
    schedule = CommandSchedule(envs, 10.0, _streams(envs), ranges)
    schedule(rt)
    assert np.isfinite(schedule.heading).all() and (rt.velocity_command[:, 2] < 5.0).all()
    half = CommandRanges(
        yaw_rate=(5.0, 6.0), heading_command=True, zero_fraction=0.0, heading_fraction=0.5
    )
    rt = _runtime(envs, q.copy())
    schedule = CommandSchedule(envs, 10.0, _streams(envs), half)
    schedule(rt)
    raw = rt.velocity_command[:, 2] >= 5.0
    assert np.array_equal(raw, np.isnan(schedule.heading)) and 0.35 < raw.mean() < 0.65
    with pytest.raises(ValueError, match="heading_command"):
        ranges.sample(np.random.default_rng(0))  # training's episodes: no heading there


def _walk(schedule, rt, seconds, dt=0.02, gain=0.8):
    """Ticks of a robot that turns ``gain`` of its yaw-rate command; the commands given."""
    out = []
    for _ in range(int(round(seconds / dt))):
        rt.time += dt
        schedule(rt)
        out.append(rt.velocity_command.copy())
        rt.yaw = rt.yaw + gain * rt.velocity_command[:, 2] * dt
        rt.state.base.orientation[:] = _quat(rt.yaw)
    return np.array(out)


def test_a_checkpoint_resumes_the_same_heading_commands():
    envs = 3
    ranges = CommandRanges(heading_command=True, period=(3.0, 6.0), max_yaw_rate=2.0)
    rt = _runtime(envs, _quat(np.zeros(envs)))
    rt.yaw = np.zeros(envs)
    whole = CommandSchedule(envs, (3.0, 6.0), _streams(envs), ranges)
    commands = _walk(whole, rt, 40.0)
    assert whole.heading_ended.sum() > 5 and np.ptp(commands[:, :, 2]) > 1.0

    rt = _runtime(envs, _quat(np.zeros(envs)))
    rt.yaw = np.zeros(envs)
    first = CommandSchedule(envs, (3.0, 6.0), _streams(envs), ranges)
    head = _walk(first, rt, 20.0)
    state = json.loads(json.dumps(first.state_dict(), default=lambda a: a.tolist()))
    resumed = CommandSchedule(envs, (3.0, 6.0), _streams(envs, seed=99), ranges)
    resumed.load_state_dict(state)
    tail = _walk(resumed, rt, 20.0)
    both = np.concatenate([head, tail])
    assert np.allclose(both, commands, rtol=0, atol=1e-9)
    assert np.array_equal(resumed.heading_ended, whole.heading_ended)
    assert resumed.heading_figures() == pytest.approx(whole.heading_figures())
    # a checkpoint written before heading commands: none, and no figures
    old = {k: v for k, v in state.items() if not k.startswith("heading")}
    resumed.load_state_dict(old)
    assert (
        np.isnan(resumed.heading).all() and resumed.heading_figures()["heading_commands_ended"] == 0
    )


@pytest.mark.parametrize(
    ("line", "key", "expected"),
    [
        ("heading_command = 1", "commands.heading_command", "expected true or false"),
        ("heading = [1.0, -1.0]", "commands.heading", "expected (low, high)"),
        ("heading = 3.14", "commands.heading", "expected a range [low, high]"),
        ("heading_stiffness = 0.0", "commands.heading_stiffness", "expected a number > 0"),
        ("max_yaw_rate = -2.0", "commands.max_yaw_rate", "expected a number > 0"),
        ("heading_fraction = 1.5", "commands.heading_fraction", "expected a probability"),
        ("heading_commands = true", "commands.heading_commands", "unknown key"),
    ],
)
def test_a_bad_heading_key_is_refused_in_one_line_naming_file_and_key(
    tmp_path, go2, line, key, expected
):
    path = tmp_path / "bad.toml"
    head = "" if line.startswith("heading_command ") else "heading_command = true\n"
    path.write_text(f"[commands]\n{head}{line}\n")
    with pytest.raises(RangesError) as refused:
        load_ranges(path, go2)
    message = str(refused.value)
    assert message.startswith(f"{path}: {key}") and expected in message
    assert "\n" not in message


def test_every_heading_setting_says_where_it_came_from(tmp_path, go2):
    path = tmp_path / "h.toml"
    path.write_text(
        "[commands]\nheading_command = true\nheading = [-3.14, 3.14]\nmax_yaw_rate = 2.0\n"
        "yaw_rate = [-3.14, 3.14]\nperiod = 10.0\n"
    )
    ranges = load_ranges(path, go2)
    given = {"heading_command": True, "heading": 0, "max_yaw_rate": 0, "yaw_rate": 0, "period": 0}
    commands, account = command_schedule(ranges.commands, given, "h.toml", (None, None), None)
    assert commands.heading_command and commands.max_yaw_rate == 2.0
    assert commands.heading == (-3.14, 3.14) and commands.heading_stiffness == 0.5
    s = account["sources"]
    assert s["heading_command"] == s["heading"] == s["max_yaw_rate"] == "h.toml [commands]"
    assert "legged_gym's 0.5" in s["heading_stiffness"]
    text = schedule_text(account)
    assert "no raw yaw rate drawn" in text and "yaw rate [" not in text
    assert "yaw-rate clip +-2 rad/s" in text and "estimated yaw" in text
    # heading keys with heading commands off: said, not silently dropped
    off = {"heading_command": False, "heading": 0}
    plain = CommandRanges(heading=(-1.0, 1.0))
    _, account = command_schedule(plain, off, "h.toml", (None, None), None)
    assert not account["heading_command"] and "heading" not in account
    assert "set but not used (heading_command off)" in schedule_text(account)
    assert math.isclose(CommandRanges().heading[1], math.pi)


class _Rt:
    """A runtime's arrays for the schedule and the tracker: ``envs`` RUNNING robots, the base
    estimate's attitude the truth's."""

    def __init__(self, envs):
        self.mode = np.full(envs, RUNNING, dtype=np.int8)
        self.time, self.ticks = 0.0, 0
        self.velocity_command = np.zeros((envs, 3))
        self.state = SimpleNamespace(base=SimpleNamespace(orientation=_quat(np.zeros(envs))))


class _Turner:
    """A plant whose base follows the planar command at once and turns ``gain`` times the
    yaw-rate command (0: a robot that does not turn)."""

    def __init__(self, rt, gain):
        self.rt, self.gain = rt, gain
        self.yaw = np.zeros(len(rt.mode))

    def true_base_state(self):
        s = np.zeros((len(self.yaw), 13))
        s[:, 3:7] = _quat(self.yaw)
        c, n = np.cos(self.yaw), np.sin(self.yaw)
        v = self.rt.velocity_command
        s[:, 7], s[:, 8] = c * v[:, 0] - n * v[:, 1], n * v[:, 0] + c * v[:, 1]
        s[:, 12] = self.gain * v[:, 2]
        return s

    def step(self, dt):
        self.yaw = self.yaw + self.gain * self.rt.velocity_command[:, 2] * dt
        self.rt.state.base.orientation[:] = _quat(self.yaw)


def _walk_judged(ranges, gain, compiled=True, seconds=120.0, dt=0.02):
    from sim2real.deploy.tasks.locomotion import CommandTracker

    rt = _Rt(2)
    plant = _Turner(rt, gain)
    schedule = CommandSchedule(2, 10.0, _streams(2, seed=5), ranges)
    tracker = CommandTracker(2, dt, plant)
    tracker.compiled = compiled
    for _ in range(int(round(seconds / dt))):
        rt.ticks += 1
        rt.time = rt.ticks * dt
        schedule(rt)
        tracker(rt)
        plant.step(dt)
    return schedule, tracker, tracker.summary(rt)


def test_yaw_rate_tracking_falls_when_the_robot_does_not_turn():
    """The planar figure alone reads a robot that never turns as tracking; the yaw-rate figure
    beside it does not (a policy turning half of its command read 'tracking 96 %' before). The
    compiled kernels and numpy give the same figures."""
    ranges = CommandRanges(vx=(0.0, 0.5), yaw_rate=(-1.5, 1.5), zero_fraction=0.0)
    _, turns, turning = _walk_judged(ranges, 1.0)
    _, stiff, still = _walk_judged(ranges, 0.0)
    assert turning["tracking_success"] > 0.95 and still["tracking_success"] > 0.95
    assert turning["yaw_tracking_success"] > 0.95
    assert still["yaw_tracking_success"] < 0.5  # only the commands within 0.2 rad/s of 0
    _, half, halved = _walk_judged(ranges, 0.5)
    assert halved["yaw_tracking_success"] < turning["yaw_tracking_success"] - 0.2
    _, slow, by_numpy = _walk_judged(ranges, 0.0, compiled=False)
    assert by_numpy == still
    for key, value in stiff.state_dict().items():
        np.testing.assert_array_equal(slow.state_dict()[key], value, err_msg=key)


def test_heading_commands_turn_a_robot_to_its_heading_and_judge_its_yaw_rate():
    """A robot that turns as commanded reaches each heading within its 10-s command; one that
    turns half the command closes on it more slowly (the loop is closed), and its yaw-rate
    figure says it does not follow the yaw rate it is given."""
    ranges = CommandRanges(heading_command=True, zero_fraction=0.0, max_yaw_rate=1.0)
    schedule, _, turning = _walk_judged(ranges, 1.0)
    figures = schedule.heading_figures()
    assert figures["heading_commands_ended"] == 2 * 11
    assert figures["mean_heading_error_deg"] < 5.0
    assert turning["yaw_tracking_success"] > 0.9
    schedule, _, halved = _walk_judged(ranges, 0.5)
    assert schedule.heading_figures()["mean_heading_error_deg"] > figures["mean_heading_error_deg"]
    # near its heading the yaw rate asked is small, and half of it within 0.2 rad/s: the figure
    # falls by the time spent turning (here about a fifth)
    assert halved["yaw_tracking_success"] < turning["yaw_tracking_success"] - 0.1
