"""A legged soak's command schedule: the period between velocity commands and their share of zero
(standing) commands, from a ranges file's ``[commands]`` (over the policy contract's ranges,
refused with ``--goal-period``) or from each stack's own training config, read as it writes it:
Isaac Lab's and mjlab's ``env.yaml`` (``resampling_time_range``, ``rel_standing_envs``; the
values of unitree_rl_lab's ``tasks/locomotion/robots/g1/29dof/velocity_env_cfg.py`` and
unitree_rl_mjlab's ``mjlab/tasks/velocity/velocity_env_cfg.py``), legged_gym's and humanoid-gym's
config classes (``commands.resampling_time``), holosoma's ``experiment_config`` (the command
manager's ``locomotion_command_resampling_time``, ``stand_prob``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
import yaml

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.tasks.commands import CommandRanges, CommandSchedule
from sim2real.eval import cli
from sim2real.eval.world.command_schedule import command_schedule
from sim2real.eval.world.domain import contract_commands, domain_toml, legged_gym_domain
from sim2real.eval.world.ranges_file import RangesError, load_ranges, load_ranges_text
from sim2real.eval.world.session_draw import session_rng
from sim2real.robots import load_robot
from tests import foreign_stacks as fs

WORLD = Path(__file__).parents[1] / "sim2real" / "eval" / "world"
DATA = Path(__file__).parent / "data" / "unitree_rl_gym"


def test_the_shipped_domains_carry_their_stacks_schedules(go2):
    """unitree_rl_lab's G1 task: a new command every 10 s, 2 % of them zero; unitree_rl_mjlab's:
    every U(3, 8) s, 5 % zero (the toml's comments cite the keys)."""
    rl_lab = (
        (WORLD / "unitree_rl_lab_velocity_ranges.toml").read_text().replace("torso_link", "pelvis")
    )
    commands = load_ranges_text(rl_lab, "rl_lab.toml", load_robot("h1")).commands
    assert (commands.period, commands.zero_fraction) == ((10.0, 10.0), 0.02)
    mjlab = (WORLD / "mjlab_velocity_ranges.toml").read_text().replace("torso_link", "base")
    commands = load_ranges_text(mjlab, "mjlab.toml", go2).commands
    assert (commands.period, commands.zero_fraction) == ((3.0, 8.0), 0.05)


@pytest.mark.parametrize(
    ("table", "key", "expected"),
    [
        ("period = -1.0", "commands.period", "expected s > 0"),
        ("period = [8.0, 3.0]", "commands.period", "0 < low <= high"),
        ('period = "10"', "commands.period", "expected a number or a range [low, high]"),
        ("zero_fraction = 1.5", "commands.zero_fraction", "expected a probability"),
        ("zero_fraction = -0.1", "commands.zero_fraction", "expected a probability"),
        ("resampling_time = 10.0", "commands.resampling_time", "unknown key"),
    ],
)
def test_a_bad_schedule_is_refused_naming_the_file_and_the_field(
    tmp_path, go2, table, key, expected
):
    path = tmp_path / "bad.toml"
    path.write_text(f"[commands]\n{table}\n")
    with pytest.raises(RangesError) as refused:
        load_ranges(path, go2)
    message = str(refused.value)
    assert message.startswith(f"{path}: {key}") and expected in message
    assert "\n" not in message


def test_the_files_schedule_goes_over_the_contracts_ranges(tmp_path):
    """A Unitree deploy.yaml contract gives the ranges; the file's period and zero share go
    over them, each part's source named; a file range replaces the contract's one range."""
    cfg = fs.unitree_deploy(range(12), [0.0] * 12)
    policy = fs.write_unitree_policy(tmp_path / "v0", cfg, 45)
    contract = contract_commands(policy)
    assert contract[0].vx == (-0.5, 1.0)
    file = CommandRanges(zero_fraction=0.02, period=10.0, vy=(0.0, 0.0))
    given = {"zero_fraction": 0.02, "period": 10.0}
    commands, account = command_schedule(file, given, "g1.toml", contract, None)
    assert (commands.vx, commands.vy, commands.yaw_rate) == ((-0.5, 1.0), (-0.5, 0.5), (-1.0, 1.0))
    assert (commands.period, commands.zero_fraction) == ((10.0, 10.0), 0.02)
    assert account["sources"]["period"] == "g1.toml [commands] period"
    assert account["sources"]["zero_fraction"] == "g1.toml [commands]"
    assert "deploy.yaml" in account["sources"]["vx"] and account["period_s"] == 10.0
    given["vy"] = (0.0, 0.0)
    commands, account = command_schedule(file, given, "g1.toml", contract, None)
    assert commands.vy == (0.0, 0.0) and commands.vx == (-0.5, 1.0)
    assert account["sources"]["vy"] == "g1.toml [commands]"
    # without a file period: --goal-period, else the soak's 4 s
    commands, account = command_schedule(None, {}, None, contract, 6.0)
    assert commands.period == (6.0, 6.0) and account["sources"]["period"] == "--goal-period"
    assert command_schedule(None, {}, None, contract, None)[0].period == (4.0, 4.0)
    with pytest.raises(ValueError, match="--goal-period: g1.toml sets commands.period too"):
        command_schedule(file, {"period": 10.0}, "g1.toml", contract, 6.0)


class _Runtime:
    def __init__(self, envs: int):
        self.mode = np.full(envs, RUNNING)
        self.time = 0.0
        self.velocity_command = np.zeros((envs, 3))


def _run(schedule: CommandSchedule, seconds: float, dt: float = 0.02) -> list[float]:
    """The times env 0 got a new command over ``seconds``."""
    rt, times = _Runtime(schedule.envs), []
    for tick in range(int(round(seconds / dt))):
        rt.time = tick * dt
        before = int(schedule.issued[0])
        schedule(rt)
        if schedule.issued[0] > before:
            times.append(rt.time)
    return times


def test_a_fixed_period_draws_the_commands_alone_and_a_range_draws_each_length():
    """A fixed period: commands every period s, the stream's draws the commands' only (as
    before a range could be given); a range: each command lasts U(low, high) s, the same for
    the same seed, and a checkpoint in the middle resumes the same lengths."""
    ranges = CommandRanges(zero_fraction=0.3)
    fixed = CommandSchedule(1, 10.0, [session_rng(7, "goals")], ranges)
    times = _run(fixed, 100.0)
    assert np.allclose(np.diff(times), 10.0)
    stream = session_rng(7, "goals")
    assert np.array_equal(fixed.command[0], [ranges.sample(stream) for _ in times][-1])

    drawn = CommandSchedule(1, (3.0, 8.0), [session_rng(7, "goals")], ranges)
    lengths = np.diff(_run(drawn, 600.0))
    assert lengths.min() >= 3.0 - 1e-9 and lengths.max() <= 8.0 + 0.02 + 1e-9
    assert lengths.std() > 0.5  # drawn, not one length
    again = CommandSchedule(1, (3.0, 8.0), [session_rng(7, "goals")], ranges)
    assert np.array_equal(np.diff(_run(again, 600.0)), lengths)

    first = CommandSchedule(1, (3.0, 8.0), [session_rng(7, "goals")], ranges)
    _run(first, 50.0)
    state = first.state_dict()
    resumed = CommandSchedule(1, (3.0, 8.0), [session_rng(0, "goals")], ranges)
    resumed.load_state_dict(json.loads(json.dumps(state, default=lambda a: a.tolist())))
    assert resumed.wait[0] == first.wait[0] and resumed.issued[0] == first.issued[0]


def test_goal_period_with_a_file_period_is_one_line_exit_3(go2_onnx, tmp_path, capsys):
    path = tmp_path / "g.toml"
    path.write_text("[commands]\nperiod = 10.0\n")
    argv = ["--robot", "go2", "--policy", str(go2_onnx), "--hours", "0.001", "--out",
            str(tmp_path / "run"), "--ranges", str(path), "--no-progress", "--no-film"]  # fmt: skip
    assert cli.main([*argv, "--goal-period", "3"]) == cli.EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip()
    assert (
        err == f"soak-test: error: --goal-period: {path} sets commands.period too; give one of them"
    )


def test_a_soak_runs_the_files_schedule_and_reports_it(go2_onnx, tmp_path, capsys):
    """Every command zero, one every 2 s: the session's commands are all zero, as many as its
    RUNNING time holds, and the report and the console say the period and the share and where
    they came from."""
    path = tmp_path / "stand.toml"
    path.write_text("[commands]\nperiod = 2.0\nzero_fraction = 1.0\n")
    out = tmp_path / "run"
    argv = ["--robot", "go2", "--policy", str(go2_onnx), "--hours", "0.004", "--out", str(out),
            "--ranges", str(path), "--no-progress", "--no-film", "--no-faults",
            "--checkpoint-minutes", "0"]  # fmt: skip
    cli.main(argv)
    report = json.loads((out / "report.json").read_text())
    schedule = report["campaign"]["commands"]
    assert (schedule["period_s"], schedule["zero_fraction"]) == (2.0, 1.0)
    assert schedule["sources"]["period"] == f"{path} [commands] period"
    loco = report["sessions"][0]["locomotion"]
    assert loco["command_period_s"] == 2.0 and loco["final_command"] == [0.0, 0.0, 0.0]
    assert loco["commands_issued"] == pytest.approx(loco["running_s"] / 2.0, abs=1)
    printed = capsys.readouterr().out
    assert f"a new command every 2 s ({path} [commands] period), zero (standing) 1" in printed


# ------------------------------------------------------------------ each stack's own config
def test_isaac_lab_env_yaml_gives_the_period_and_the_standing_share(tmp_path):
    """unitree_rl_lab's G1 CommandsCfg as Isaac Lab dumps it: resampling_time_range (10, 10),
    rel_standing_envs 0.02."""
    env = fs.isaaclab_env()
    env["events"] = {}
    command = env["commands"]["base_velocity"]
    command.update(resampling_time_range=(10.0, 10.0), rel_standing_envs=0.02)
    fs.write_isaaclab_run(tmp_path / "run", env, 48, 12)
    text = domain_toml(tmp_path / "run" / "params" / "env.yaml")
    commands = load_ranges_text(text, "env.yaml", load_robot("h1")).commands
    assert (commands.period, commands.zero_fraction) == ((10.0, 10.0), 0.02)
    command["rel_standing_envs"] = 2.0
    fs.write_isaaclab_run(tmp_path / "bad", env, 48, 12)
    with pytest.raises(ValueError, match="commands.base_velocity.rel_standing_envs: expected"):
        domain_toml(tmp_path / "bad" / "params" / "env.yaml")


def test_isaac_lab_heading_commands_are_read_as_the_command_manager_gives_them(tmp_path):
    """Isaac Lab's UniformVelocityCommandCfg with heading_command on: the soak draws headings
    for rel_heading_envs of its commands and gives the policy clip(stiffness x error) within
    ranges.ang_vel_z, as ``_update_command`` does; an asymmetric clip is refused by name."""
    env = fs.isaaclab_env()
    env["events"] = {}
    command = env["commands"]["base_velocity"]
    command.update(heading_command=True, heading_control_stiffness=0.5, rel_heading_envs=0.25)
    command["ranges"].update(ang_vel_z=(-1.0, 1.0), heading=(-3.14, 3.14))
    fs.write_isaaclab_run(tmp_path / "run", env, 48, 12)
    text = domain_toml(tmp_path / "run" / "params" / "env.yaml")
    commands = load_ranges_text(text, "env.yaml", load_robot("h1")).commands
    assert commands.heading_command and commands.heading == (-3.14, 3.14)
    assert (commands.heading_stiffness, commands.max_yaw_rate) == (0.5, 1.0)
    assert commands.heading_fraction == 0.25
    command["ranges"]["ang_vel_z"] = (-0.5, 1.0)
    fs.write_isaaclab_run(tmp_path / "bad", env, 48, 12)
    with pytest.raises(ValueError, match=r"ranges.ang_vel_z: a heading command's yaw-rate clip"):
        domain_toml(tmp_path / "bad" / "params" / "env.yaml")


@dataclass
class UniformVelocityCommandCfg:
    """mjlab's command term config, as far as the dump shows it."""

    entity_name: str
    resampling_time_range: tuple
    rel_standing_envs: float
    ranges: dict


@dataclass
class EnvCfg:
    commands: dict
    events: dict = field(default_factory=dict)


def test_mjlab_env_yaml_gives_a_drawn_period(tmp_path):
    """unitree_rl_mjlab's twist command dumped as mjlab dumps its dataclasses: each command lasts
    U(3, 8) s, 5 % are zero."""
    ranges = {"lin_vel_x": (-0.5, 1.0), "lin_vel_y": (-0.5, 0.5), "ang_vel_z": (-1.0, 1.0)}
    cfg = EnvCfg(commands={"twist": UniformVelocityCommandCfg("robot", (3.0, 8.0), 0.05, ranges)})
    path = tmp_path / "env.yaml"
    path.write_text(yaml.dump(cfg, sort_keys=False))
    commands = load_ranges_text(domain_toml(path), "env.yaml", load_robot("h1")).commands
    assert (commands.period, commands.zero_fraction, commands.vy) == ((3.0, 8.0), 0.05, (-0.5, 0.5))


def test_legged_gym_configs_give_their_resampling_time(tmp_path):
    """unitree_rl_gym's h1_config.py keeps LeggedRobotCfg's 10 s; humanoid-gym's XBot sets 8 s
    (humanoid/envs/custom/humanoid_config.py); a non-positive time is refused by name."""
    h1 = load_robot("h1")
    text = legged_gym_domain(DATA / "h1" / "h1_config.py")
    assert load_ranges_text(text, "h1_config.py", h1).commands.period == (10.0, 10.0)
    config = """
from humanoid.envs.base.legged_robot_config import LeggedRobotCfg

class XBotLCfg(LeggedRobotCfg):
    class commands(LeggedRobotCfg.commands):
        num_commands = 4
        resampling_time = {t}
        heading_command = True
        class ranges:
            lin_vel_x = [-0.3, 0.6]
            lin_vel_y = [-0.3, 0.3]
            ang_vel_yaw = [-0.3, 0.3]
            heading = [-3.14, 3.14]
"""
    from tests.legged_gym_trees import write_task

    path = write_task(tmp_path, config.format(t="8."), "humanoid_config.py", "humanoid")
    commands = load_ranges_text(legged_gym_domain(path), "humanoid_config.py", h1).commands
    assert (commands.period, commands.vx) == ((8.0, 8.0), (-0.3, 0.6))
    path.write_text(config.format(t="0."))
    with pytest.raises(ValueError, match="commands.resampling_time: expected s > 0, got 0.0"):
        legged_gym_domain(path)


def test_holosomas_command_manager_gives_the_period_and_the_standing_share(tmp_path, go2):
    """holosoma's G1 command preset (config_values/loco/g1/command.py): a new command every
    10 s, each zero with probability 0.2."""
    from sim2real.eval.world.domain import training_domain

    experiment = fs.holosoma_experiment(fs.HOLOSOMA_ORDER)
    command = experiment["command"]
    command["params"] = {"locomotion_command_resampling_time": 10.0}
    command["setup_terms"]["locomotion_command"]["params"]["stand_prob"] = 0.2
    path = fs.write_holosoma(tmp_path / "policy.onnx", experiment, 45)
    commands = load_ranges_text(training_domain(path), "holosoma", go2).commands
    assert (commands.period, commands.zero_fraction) == ((10.0, 10.0), 0.2)
