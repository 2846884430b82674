"""Robot descriptions (MJCF plus robot.toml) and their loader.

>>> from robots import load_robot
>>> arm = load_robot("arm3")
>>> arm.joint_names
('shoulder', 'elbow', 'wrist')
"""

from robots.loading import load_robot, resolve_robot_toml
from robots.robot import Robot, RobotSpecError
from robots.schema import CONTROL_MODES, MotorConfig, RobotConfig

__all__ = [
    "CONTROL_MODES",
    "MotorConfig",
    "Robot",
    "RobotConfig",
    "RobotSpecError",
    "load_robot",
    "resolve_robot_toml",
]
