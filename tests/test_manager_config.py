"""An Isaac Lab or mjlab config in Python given as a training domain is refused in one line
naming the file, its config class and the run folder's ``params/env.yaml`` (never read as a
legged_gym config, never dropped); a legged_gym config is still read, and a key of its classes
the soak does not model is named in one line. The files are written the way Isaac Lab's
velocity task, unitree_rl_lab and mjlab write their configs."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from sim2real.eval.world.domain import DomainError, domain_account, domain_toml
from sim2real.eval.world.manager_config import refuse_manager_config
from tests.test_legged_gym_tree import himloco_tree

#: Isaac Lab's Go2 rough task (isaaclab_tasks/.../config/go2/rough_env_cfg.py): inherits the
#: velocity task's config and edits it in __post_init__.
ISAACLAB_GO2 = """
from isaaclab.utils import configclass

from isaaclab_tasks.manager_based.locomotion.velocity.velocity_env_cfg import LocomotionVelocityRoughEnvCfg

from isaaclab_assets.robots.unitree import UNITREE_GO2_CFG  # isort: skip


@configclass
class UnitreeGo2RoughEnvCfg(LocomotionVelocityRoughEnvCfg):
    def __post_init__(self):
        super().__post_init__()
        self.scene.robot = UNITREE_GO2_CFG.replace(prim_path="{ENV_REGEX_NS}/Robot")
        self.events.push_robot = None
        self.events.add_base_mass.params["mass_distribution_params"] = (-1.0, 3.0)


@configclass
class UnitreeGo2RoughEnvCfg_PLAY(UnitreeGo2RoughEnvCfg):
    def __post_init__(self):
        super().__post_init__()
        self.scene.num_envs = 50
"""

#: unitree_rl_lab's task (source/unitree_rl_lab/.../velocity_env_cfg.py): the whole config in
#: one file, nested @configclass classes, event terms built by calls.
RL_LAB = """
import math

import isaaclab.sim as sim_utils
from isaaclab.envs import ManagerBasedRLEnvCfg
from isaaclab.managers import EventTermCfg as EventTerm
from isaaclab.utils import configclass

from unitree_rl_lab.tasks.locomotion import mdp


@configclass
class EventCfg:
    push_robot = EventTerm(
        func=mdp.push_by_setting_velocity,
        mode="interval",
        interval_range_s=(5.0, 10.0),
        params={"velocity_range": {"x": (-0.5, 0.5), "y": (-0.5, 0.5)}},
    )


@configclass
class RobotEnvCfg(ManagerBasedRLEnvCfg):
    events: EventCfg = EventCfg()

    def __post_init__(self):
        self.decimation = 4
        self.episode_length_s = 20.0
"""

#: mjlab's task as a dataclass (mjlab/tasks/velocity/config/go1/rough_env_cfg.py, 2025).
MJLAB_CLASS = """
from dataclasses import dataclass, replace

from mjlab.asset_zoo.robots.unitree_go1.go1_constants import GO1_ROBOT_CFG
from mjlab.tasks.velocity.velocity_env_cfg import LocomotionVelocityEnvCfg


@dataclass
class UnitreeGo1RoughEnvCfg(LocomotionVelocityEnvCfg):
    def __post_init__(self):
        super().__post_init__()
        self.scene.entities = {"robot": replace(GO1_ROBOT_CFG)}
        self.events.push_robot.params["velocity_range"] = {"x": (-0.5, 0.5)}
"""

#: mjlab's task as a function building its config (later mjlab).
MJLAB_FUNCTION = """
from mjlab.envs import ManagerBasedRlEnvCfg
from mjlab.tasks.velocity.velocity_env_cfg import make_velocity_env_cfg


def unitree_go1_rough_env_cfg(play: bool = False) -> ManagerBasedRlEnvCfg:
    cfg = make_velocity_env_cfg()
    cfg.events["push_robot"].params["velocity_range"] = {"x": (-0.5, 0.5)}
    return cfg
"""

#: Isaac Lab 1.x (Orbit's successor): the same config under omni.isaac.lab.
OMNI = ISAACLAB_GO2.replace("from isaaclab.", "from omni.isaac.lab.").replace(
    "from isaaclab_tasks.", "from omni.isaac.lab_tasks."
)


def _write(folder: Path, text: str, name: str = "rough_env_cfg.py") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(textwrap.dedent(text))
    return path


@pytest.mark.parametrize(
    "text, stack, config",
    [
        (ISAACLAB_GO2, "Isaac Lab", "class UnitreeGo2RoughEnvCfg(LocomotionVelocityRoughEnvCfg) "
         "with a __post_init__"),
        (OMNI, "Isaac Lab", "class UnitreeGo2RoughEnvCfg(LocomotionVelocityRoughEnvCfg)"),
        (RL_LAB, "Isaac Lab", "class RobotEnvCfg(ManagerBasedRLEnvCfg) with a __post_init__"),
        (MJLAB_CLASS, "mjlab", "class UnitreeGo1RoughEnvCfg(LocomotionVelocityEnvCfg)"),
        (MJLAB_FUNCTION, "mjlab", "function unitree_go1_rough_env_cfg()"),
    ],
    ids=["isaaclab", "omni.isaac.lab", "unitree_rl_lab", "mjlab-dataclass", "mjlab-function"],
)  # fmt: skip
def test_an_isaac_lab_or_mjlab_python_config_is_refused_naming_its_class_and_env_yaml(
    tmp_path, text, stack, config
):
    path = _write(tmp_path / "task", text)
    with pytest.raises(DomainError) as err:
        domain_toml(path)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: {config}")
    assert f"is an {stack} config in Python" in message
    assert "__post_init__" in message and "params/env.yaml" in message


def test_the_isaac_lab_config_in_its_own_tree_is_not_read_as_legged_gym(tmp_path):
    """Beside the velocity task's base file it inherits from (which the legged_gym reader would
    resolve), the refusal is the same: the class named, the env.yaml asked for; and a chosen
    class of the file is the one named."""
    root = tmp_path / "isaaclab_tasks" / "manager_based" / "locomotion" / "velocity"
    _write(root, RL_LAB.replace("RobotEnvCfg", "LocomotionVelocityRoughEnvCfg"),
           "velocity_env_cfg.py")  # fmt: skip
    path = _write(root / "config" / "go2", ISAACLAB_GO2)
    with pytest.raises(DomainError, match=r"class UnitreeGo2RoughEnvCfg\(Locomotion.*env\.yaml"):
        domain_toml(path)
    play = refuse_manager_config(path, "UnitreeGo2RoughEnvCfg_PLAY")
    assert play.startswith(f"{path}: class UnitreeGo2RoughEnvCfg_PLAY(UnitreeGo2RoughEnvCfg)")


def test_policy_export_refuses_it_in_one_line_with_exit_2_and_writes_nothing(tmp_path, capsys):
    """``policy-export POLICY --domain rough_env_cfg.py``: exit 2 (bad input), one stderr line
    naming ``--domain``, the file and its class; no file written (before this, a file alone
    was refused as a legged_gym config whose base was missing from its tree, and one in a tree
    holding its base would have been read as legged_gym's)."""
    from sim2real.deploy.cli.policy_export import EXIT_BAD_INPUT
    from sim2real.deploy.cli.policy_export import main as policy_export_main

    path = _write(tmp_path / "task", ISAACLAB_GO2)
    out = tmp_path / "out.onnx"
    policy = Path(__file__).resolve().parents[1] / "sim2real" / "policies" / "go2.pt"
    code = policy_export_main([str(policy), "--domain", str(path), "--out", str(out)])
    err = capsys.readouterr().err.splitlines()
    assert code == EXIT_BAD_INPUT and len(err) == 1, err
    assert err[0].startswith(f"policy-export: error: --domain: {path}: class UnitreeGo2RoughEnvCfg")
    assert not out.exists()


def test_a_legged_gym_config_is_still_read_and_its_unmodelled_keys_named(tmp_path):
    """HIMLoco's layout is not taken for a manager config; a key of ``terrain``, ``commands``,
    ``control`` or ``noise`` the soak does not model, added to the task, is named in one line
    with its file and line (not dropped)."""
    task = himloco_tree(tmp_path)
    assert refuse_manager_config(task) is None
    text = task.read_text()
    extra = (
        "\n    class terrain(LeggedRobotCfg.terrain):\n        hill_height = 0.4\n"
        "\n    class control(LeggedRobotCfg.control):\n        hip_reduction = 0.8\n"
    )
    anchor = "class Go1RoughCfg( LeggedRobotCfg ):\n"
    assert anchor in text
    task.write_text(text.replace(anchor, anchor + extra, 1))
    account = domain_account(domain_toml(task))
    rel = "legged_gym/envs/go1/go1_config.py"
    for key, value in (("terrain.hill_height", "0.4"), ("control.hip_reduction", "0.8")):
        lines = [a for a in account if a.startswith("# not modelled: ") and f"{key} {value}" in a]
        assert len(lines) == 1, (key, account)
        assert f"{key} {value} ({rel}:" in lines[0]
