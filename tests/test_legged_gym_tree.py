"""A legged_gym config read with everything it inherits from its own tree (HIMLoco's layout:
``legged_gym/envs/base/legged_robot_config.py`` and a task module importing it), every value of
the stored domain naming its file and line, a base the tree lacks refused in one line, what the
soak does not model named in one line; and, on HIMLoco's own files (its checkout under
``SIM2REAL_STACKS``, :mod:`tests.stacks`), the stored domain equal to
``sim2real/eval/world/himloco_rough_ranges.toml`` key by key."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from sim2real.eval.world.domain import DomainError, domain_account, legged_gym_domain
from sim2real.eval.world.ranges_file import load_ranges_text, parse_overrides
from sim2real.robots import load_robot

#: HIMLoco's LeggedRobotCfg as its legged_robot_config.py writes it (the classes read; values
#: as published at ef289ac).
HIMLOCO_BASE = """
from .base_config import BaseConfig

class LeggedRobotCfg(BaseConfig):
    class terrain:
        mesh_type = 'trimesh'
        horizontal_scale = 0.1 # [m]
        vertical_scale = 0.005 # [m]
        border_size = 25 # [m]
        curriculum = True
        static_friction = 1.0
        dynamic_friction = 1.0
        restitution = 0.
        max_init_terrain_level = 5
        terrain_length = 8.
        terrain_width = 8.
        num_rows= 10
        num_cols = 20
        terrain_proportions = [0.1, 0.2, 0.3, 0.3, 0.1]
        slope_treshold = 0.75

    class commands:
        curriculum = True
        max_curriculum = 3.0
        num_commands = 4
        resampling_time = 10.
        heading_command = True
        class ranges:
            lin_vel_x = [-1.0, 1.0]
            lin_vel_y = [-1.0, 1.0]
            ang_vel_yaw = [-3.14, 3.14]
            heading = [-3.14, 3.14]

    class control:
        decimation = 4

    class domain_rand:
        randomize_payload_mass = True
        payload_mass_range = [-1, 2]

        randomize_com_displacement = True
        com_displacement_range = [-0.05, 0.05]

        randomize_link_mass = False
        link_mass_range = [0.9, 1.1]

        randomize_friction = True
        friction_range = [0.2, 1.25]

        randomize_motor_strength = True
        motor_strength_range = [0.9, 1.1]

        randomize_kp = True
        kp_range = [0.9, 1.1]

        randomize_kd = True
        kd_range = [0.9, 1.1]

        disturbance = True
        disturbance_range = [-30.0, 30.0]
        disturbance_interval = 8

        push_robots = True
        push_interval_s = 16
        max_push_vel_xy = 1.

        delay = True

    class noise:
        add_noise = True
        noise_level = 1.0
        class noise_scales:
            dof_pos = 0.01
            dof_vel = 1.5
            ang_vel = 0.2
            gravity = 0.05
"""

#: go1_config.py's shape: commands and ranges that inherit their base's nested classes (max
#: curriculum 2, one range set), no terrain or domain_rand of its own.
GO1 = """
from legged_gym.envs.base.legged_robot_config import LeggedRobotCfg, LeggedRobotCfgPPO

class Go1RoughCfg( LeggedRobotCfg ):
    class commands( LeggedRobotCfg.commands ):
            max_curriculum = 2.0
            class ranges( LeggedRobotCfg.commands.ranges):
                lin_vel_y = [-0.5, 0.5]

class Go1RoughCfgPPO( LeggedRobotCfgPPO ):
    pass
"""

#: HIMLoco's legged_robot.py, the heading command's line (its yaw rate clipped to +-2 rad/s).
ENV = """
class LeggedRobot:
    def _post_physics_step_callback(self):
        if self.cfg.commands.heading_command:
            heading = torch.atan2(forward[:, 1], forward[:, 0])
            self.commands[:, 2] = torch.clip(0.5*wrap_to_pi(self.commands[:, 3] - heading), -2., 2.)
"""


def himloco_tree(root: Path, env: bool = True) -> Path:
    """HIMLoco's layout in ``root``: ``legged_gym/legged_gym/envs/{base,go1}``; returns the task
    file."""
    pkg = root / "legged_gym" / "legged_gym" / "envs"
    (pkg / "base").mkdir(parents=True)
    (pkg / "go1").mkdir()
    (pkg / "base" / "base_config.py").write_text("class BaseConfig:\n    pass\n")
    base = HIMLOCO_BASE + "\nclass LeggedRobotCfgPPO(BaseConfig):\n    seed = 1\n"
    (pkg / "base" / "legged_robot_config.py").write_text(textwrap.dedent(base))
    if env:
        (pkg / "base" / "legged_robot.py").write_text(textwrap.dedent(ENV))
    task = pkg / "go1" / "go1_config.py"
    task.write_text(textwrap.dedent(GO1))
    return task


def _line(text: str, needle: str) -> int:
    """The 1-based line of ``needle`` in ``text`` as written to a file (dedented)."""
    lines = textwrap.dedent(text).splitlines()
    return next(i for i, line in enumerate(lines, 1) if needle in line)


def test_a_task_reads_its_bases_and_their_nested_classes_with_file_and_line(tmp_path, go2):
    """The go1-like task sets no terrain and no domain_rand: both come whole from its base in
    the other module (payload, centre of mass, strength, kp, kd, friction with the terrain's,
    pushes, trimesh tiles); its commands class inherits the base's and its ranges class the
    base's ranges (lin_vel_y its own, the rest inherited), the curriculum's final lin_vel_x
    +-2 (its own max_curriculum over the base's 3), the heading command with the tree's clip of
    2 rad/s; every value names its file and line."""
    text = legged_gym_domain(himloco_tree(tmp_path))
    ranges = load_ranges_text(text, "himloco", go2)
    assert ranges.floor_friction == pytest.approx((0.6, 1.125))
    assert ranges.added_base_mass == (-1.0, 2.0)
    d = ranges.dynamics
    assert (d.actuator_strength, d.kp, d.kd, d.mass) == pytest.approx((0.1, 0.1, 0.1, 0.0))
    assert ranges.com_offset.x == (-0.05, 0.05) and ranges.com_offset.body == ""
    assert (ranges.pushes.interval, ranges.pushes.max_velocity) == (16.0, 1.0)
    t = ranges.terrain
    assert (t.mesh_type, t.terrain_proportions, t.levels) == (
        "trimesh",
        (0.1, 0.2, 0.3, 0.3, 0.1),
        (0, 9),
    )
    c = ranges.commands
    assert (c.vx, c.vy, c.period) == ((-2.0, 2.0), (-0.5, 0.5), (10.0, 10.0))
    assert (c.heading_command, c.heading, c.heading_stiffness, c.max_yaw_rate) == (
        True,
        (-3.14, 3.14),
        0.5,
        2.0,
    )
    base = "legged_gym/envs/base/legged_robot_config.py"
    task = "legged_gym/envs/go1/go1_config.py"
    account = domain_account(text)
    payload = _line(HIMLOCO_BASE, "payload_mass_range")
    assert (
        f"# from: added_base_mass = [-1, 2] <- domain_rand.payload_mass_range [-1, 2] "
        f"({base}:{payload})" in "\n".join(account)
    )
    assert any(
        line.startswith("# from: commands.vy = [-0.5, 0.5] <- commands.ranges.lin_vel_y")
        and f"({task}:{_line(GO1, 'lin_vel_y')})" in line
        for line in account
    )
    vx = next(line for line in account if line.startswith("# from: commands.vx"))
    assert f"({base}:{_line(HIMLOCO_BASE, 'lin_vel_x')})" in vx
    assert f"max_curriculum 2.0 ({task}:{_line(GO1, 'max_curriculum')})" in vx
    assert "(legged_gym/envs/base/legged_robot.py:6)" in "\n".join(account)
    # every value line of the TOML has its "from" line
    tables = parse_overrides(text, "himloco")
    assert {"floor_friction", "added_base_mass", "dynamics", "pushes", "commands"} <= set(tables)
    for key in ("floor_friction", "added_base_mass", "dynamics.com_offset", "pushes.interval",
                "terrain.terrain_proportions", "commands.heading_stiffness", "sensors.noise_sigma",
                "imu.gyro_noise_sigma"):  # fmt: skip
        assert any(line.startswith(f"# from: {key}") for line in account), key


def test_what_the_soak_does_not_model_is_named_in_one_line_each(tmp_path):
    """HIMLoco's disturbance (+-30 N every 8 ticks) and action delay, its drawn-but-unused yaw
    rate range and its terrain's keys the soak does not build are each named in one line with
    file and line; a randomization that is off is named as off."""
    text = legged_gym_domain(himloco_tree(tmp_path))
    base = "legged_gym/envs/base/legged_robot_config.py"
    apart = [line for line in domain_account(text) if line.startswith("# not modelled: ")]
    disturbance = [line for line in apart if "domain_rand.disturbance True" in line]
    assert len(disturbance) == 1
    assert f"domain_rand.disturbance_range [-30.0, 30.0] ({base}:" in disturbance[0]
    assert sum("domain_rand.delay True" in line for line in apart) == 1
    assert sum("commands.ranges.ang_vel_yaw [-3.14, 3.14]" in line for line in apart) == 1
    for key in ("border_size", "max_init_terrain_level", "dynamic_friction"):
        assert sum(f"terrain.{key} " in line for line in apart) == 1, key
    assert any(line.startswith("# off: domain_rand.randomize_link_mass False") for line in
               domain_account(text))  # fmt: skip
    # the same keys given in the base's file itself: the same lines, not a refusal
    direct = legged_gym_domain(tmp_path / "legged_gym" / "legged_gym" / "envs" / "base" /
                               "legged_robot_config.py", "LeggedRobotCfg")  # fmt: skip
    assert sum("domain_rand.disturbance True" in line for line in domain_account(direct)) == 1


def test_a_base_missing_from_the_tree_is_refused_in_one_line(tmp_path):
    """The go1-like task alone, without HIMLoco's base module: one line naming the class and
    the module it imports its base from; the tree without legged_robot.py: the heading clip is
    upstream legged_gym's, named as its documented default."""
    task = himloco_tree(tmp_path, env=False)
    text = legged_gym_domain(task)
    heading = next(line for line in domain_account(text) if "max_yaw_rate" in line)
    assert "max_yaw_rate = 1 <- upstream legged_gym's documented default" in heading
    alone = tmp_path / "alone" / "go1_config.py"
    alone.parent.mkdir()
    alone.write_text(textwrap.dedent(GO1))
    with pytest.raises(DomainError) as refused:
        legged_gym_domain(alone)
    message = str(refused.value)
    assert "\n" not in message
    assert message.startswith(f"{alone}: class Go1RoughCfg: its base comes from ")
    assert "legged_gym.envs.base.legged_robot_config" in message
    assert "not in the tree" in message


HAND = Path(__file__).parents[1] / "sim2real" / "eval" / "world" / "himloco_rough_ranges.toml"


def test_himlocos_own_config_gives_the_domain_it_trains_with_key_by_key(stacks):
    """HIMLoco's go1_config.py read in its own tree: every key of the stored domain equals the
    hand-written himloco_rough_ranges.toml's, which states HIMLoco's training domain from its
    source (the file's comments), apart from one: the file's pushes are set velocities the IMU
    does not feel (``apply``), the reader leaves the soak's pushes as forces."""
    config = stacks.root("HIMLoco") / "legged_gym" / "legged_gym" / "envs" / "go1" / "go1_config.py"
    ours = parse_overrides(legged_gym_domain(config), "go1_config.py")
    hand = parse_overrides(HAND.read_text(), HAND.name)
    keys = {(t, k) for src in (ours, hand) for t, v in src.items()
            for k in (v if isinstance(v, dict) else [None])}  # fmt: skip
    differ = sorted(
        (t, k) for t, k in keys
        if (ours.get(t) if k is None else ours.get(t, {}).get(k))
        != (hand.get(t) if k is None else hand.get(t, {}).get(k))
    )  # fmt: skip
    assert differ == [("pushes", "apply")]
    go2 = load_robot("go2")
    assert load_ranges_text(HAND.read_text(), HAND.name, go2).terrain is not None


def test_inspect_and_the_soak_report_print_the_domains_account(tmp_path, capsys):
    """``policy-export --inspect`` prints a policy's stored domain whole (the shipped H1's: its
    friction from h1_config.py's line 37 over the terrain's of unitree_rl_gym's base); the
    soak's report.html has a row per account line and its summary names the keys not
    modelled."""
    from sim2real.deploy.cli.policy_export import main as export_main
    from sim2real.eval.report.domain_account import domain_summary, domain_table

    h1 = Path(__file__).parent / "data" / "unitree_rl_gym" / "h1" / "h1.onnx"
    assert export_main(["--inspect", str(h1)]) == 0
    out = capsys.readouterr().out
    assert (
        "    # from: floor_friction = [0.55, 1.125] <- domain_rand.friction_range [0.1, 1.25] "
        "(h1/h1_config.py:37) and terrain.static_friction 1 "
        "(legged_gym/envs/base/legged_robot_config.py:20)" in out
    )
    text = legged_gym_domain(himloco_tree(tmp_path))
    table = domain_table({"campaign": {"training_domain": text}}, lambda h, r: {"rows": r})
    assert len(table["rows"]) == len(domain_account(text))
    assert ["not modelled", next(line[16:] for line in domain_account(text)
                                 if line.startswith("# not modelled: domain_rand.delay"))] in (
        table["rows"]
    )  # fmt: skip
    (line,) = domain_summary(text)
    assert "domain_rand.disturbance, domain_rand.delay" in line
    assert domain_summary("floor_friction = [0.5, 1.0]\n") == []


def test_relative_and_module_imports_of_the_base_are_followed(tmp_path):
    """``from ..base.legged_robot_config import LeggedRobotCfg as Base`` and ``import
    legged_gym.envs.base.legged_robot_config as lrc`` reach the same base as the absolute
    import: its pushes every 16 s, the task's own interval over it where it sets one."""
    himloco_tree(tmp_path)
    go1 = tmp_path / "legged_gym" / "legged_gym" / "envs" / "go1"
    relative = go1 / "relative_config.py"
    relative.write_text(
        "from ..base.legged_robot_config import LeggedRobotCfg as Base\n"
        "class RelCfg(Base):\n    class domain_rand(Base.domain_rand):\n        push_interval_s = 7\n"
    )
    module = go1 / "module_config.py"
    module.write_text(
        "import legged_gym.envs.base.legged_robot_config as lrc\n"
        "class ModCfg(lrc.LeggedRobotCfg):\n    pass\n"
    )
    rel = load_ranges_text(legged_gym_domain(relative), "rel", load_robot("go2"))
    mod = load_ranges_text(legged_gym_domain(module), "mod", load_robot("go2"))
    assert (rel.pushes.interval, mod.pushes.interval) == (7.0, 16.0)
    assert rel.added_base_mass == mod.added_base_mass == (-1.0, 2.0)
