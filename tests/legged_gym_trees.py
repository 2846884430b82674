"""legged_gym-style trees written in ``tmp_path`` the way the stacks lay them out: a package
``<name>/envs/base/legged_robot_config.py`` (with ``base_config.py``) whose ``LeggedRobotCfg`` is
upstream legged_gym's (leggedrobotics/legged_gym ``legged_robot_config.py``: trimesh terrain, friction
0.5-1.25, pushes of 1 m/s every 15 s, a heading command), and a task module in
``<name>/envs/<task>/``, which imports its base as the stacks' tasks do. The domain reader
(:mod:`sim2real.eval.world.legged_gym_tree`) follows those imports; CI has no stack's checkout.
"""

from __future__ import annotations

import textwrap
from pathlib import Path

#: upstream legged_gym's LeggedRobotCfg, the classes the domain reader reads (values as published).
UPSTREAM_BASE = """
from .base_config import BaseConfig

class LeggedRobotCfg(BaseConfig):
    class env:
        num_envs = 4096
    class terrain:
        mesh_type = 'trimesh' # "heightfield" # none, plane, heightfield or trimesh
        horizontal_scale = 0.1 # [m]
        vertical_scale = 0.005 # [m]
        border_size = 25 # [m]
        curriculum = True
        static_friction = 1.0
        dynamic_friction = 1.0
        restitution = 0.
        measure_heights = True
        max_init_terrain_level = 5 # starting curriculum state
        terrain_length = 8.
        terrain_width = 8.
        num_rows= 10 # number of terrain rows (levels)
        num_cols = 20 # number of terrain cols (types)
        terrain_proportions = [0.1, 0.1, 0.35, 0.25, 0.2]
        slope_treshold = 0.75
    class commands:
        curriculum = False
        max_curriculum = 1.
        num_commands = 4
        resampling_time = 10. # time before command are changed[s]
        heading_command = True # if true: compute ang vel command from heading error
        class ranges:
            lin_vel_x = [-1.0, 1.0] # min max [m/s]
            lin_vel_y = [-1.0, 1.0]   # min max [m/s]
            ang_vel_yaw = [-1, 1]    # min max [rad/s]
            heading = [-3.14, 3.14]
    class control:
        control_type = 'P'
        stiffness = {'joint_a': 10.0, 'joint_b': 15.}  # [N*m/rad]
        damping = {'joint_a': 1.0, 'joint_b': 1.5}     # [N*m*s/rad]
        action_scale = 0.5
        decimation = 4
    class domain_rand:
        randomize_friction = True
        friction_range = [0.5, 1.25]
        randomize_base_mass = False
        added_mass_range = [-1., 1.]
        push_robots = True
        push_interval_s = 15
        max_push_vel_xy = 1.
    class noise:
        add_noise = True
        noise_level = 1.0 # scales other values
        class noise_scales:
            dof_pos = 0.01
            dof_vel = 1.5
            lin_vel = 0.1
            ang_vel = 0.2
            gravity = 0.05
            height_measurements = 0.1

class LeggedRobotCfgPPO(BaseConfig):
    seed = 1
"""

BASE_CONFIG = """
class BaseConfig:
    def __init__(self) -> None:
        self.init_member_classes(self)
"""


def write_base(root: Path, package: str = "legged_gym", base: str = UPSTREAM_BASE) -> Path:
    """``root/<package>/envs/base/legged_robot_config.py`` (and ``base_config.py``); returns the
    config file."""
    folder = root / package / "envs" / "base"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "base_config.py").write_text(textwrap.dedent(BASE_CONFIG))
    path = folder / "legged_robot_config.py"
    path.write_text(textwrap.dedent(base))
    return path


def write_task(
    root: Path, text: str, name: str = "config.py", package: str = "legged_gym", base: bool = True
) -> Path:
    """The task module ``root/<package>/envs/task/<name>`` (``text`` dedented), over the base
    tree (:func:`write_base`) unless ``base`` is False; returns its path."""
    if base:
        write_base(root, package)
    folder = root / package / "envs" / "task"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(textwrap.dedent(text))
    return path
