"""The robot kinds, one module each (:mod:`~sim2real.deploy.kinds.arm`,
:mod:`~sim2real.deploy.kinds.legged`, :mod:`~sim2real.deploy.kinds.wheel_legged`,
:mod:`~sim2real.deploy.kinds.legged_arm`), registered
in :data:`sim2real.deploy.robot_kind.KIND_REGISTRY` by importing this package: a room that asks
a robot's kind imports :func:`robot_kind` from here (the floors see the import). A kind of
one's own registers in its module (:func:`register_kind`); the registry's ``builtin`` names
modules to import first.
"""

from sim2real.deploy.kinds import arm, legged, legged_arm, wheel_legged
from sim2real.deploy.kinds.arm import ARM, Arm
from sim2real.deploy.kinds.legged import LEGGED, Legged
from sim2real.deploy.kinds.legged_arm import LEGGED_ARM, LeggedArm
from sim2real.deploy.kinds.wheel_legged import WHEEL_LEGGED, WheelLegged
from sim2real.deploy.robot_kind import KIND_REGISTRY, RobotKind, register_kind, robot_kind

__all__ = [
    "ARM", "Arm", "KIND_REGISTRY", "LEGGED", "LEGGED_ARM", "Legged", "LeggedArm", "RobotKind",
    "WHEEL_LEGGED", "WheelLegged", "arm", "legged", "legged_arm", "register_kind", "robot_kind",
    "wheel_legged",
]  # fmt: skip
