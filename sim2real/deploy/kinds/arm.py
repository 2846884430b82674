"""A fixed-base arm (arm3, arm6, SO-101, UR5): what its shape does, in one place.

Its drives follow their command (the joint filters take the smoother's commanded acceleration),
it reaches goals (:class:`sim2real.deploy.tasks.goals.GoalTask`), its state has no base and its
sensor frame no IMU or feet, no stage estimates a base, the guard holds a target predicted to
bring two links into contact, its targets are bounded by the hard limits and its commanded
motion certified (:mod:`sim2real.deploy.safety.envelope`), and the soak pulls its cable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.kinds.targets import DriveTargets, uniform_targets
from sim2real.deploy.robot_kind import RobotKind, register_kind


class FixedBase:
    """A fixed base's part of the tick: none (the runtime's estimate and observation run as
    one compiled call, ``fusable``); no stop damps (:meth:`damping` all False), none lays it
    down (:meth:`lying` None)."""

    stages = (None, None)
    fusable = True

    def __init__(self, envs: int):
        self.envs = envs

    def bind(self) -> None:
        """Nothing to compile."""

    def start(self, frame) -> None:
        """Nothing to anchor."""

    def restart(self, t, envs: np.ndarray) -> None:
        """Nothing to anchor."""

    def parts(self) -> dict:
        """No stage state."""
        return {}

    def damping(self, mode: np.ndarray) -> np.ndarray:
        """(envs,) bool, all False: an arm's stop holds its pose."""
        return np.zeros(self.envs, dtype=bool)

    def lying(self, mode: np.ndarray) -> None:
        """None: an arm never lies down (a stop holds its pose)."""
        return None

    def damp(self, cmd: np.ndarray, state: RobotState) -> None:
        """An arm's safe stop brakes along the smoother's path: nothing damps."""

    def update(self, frame, state: RobotState) -> None:
        """No base to estimate, nothing to fall."""


@dataclass(frozen=True)
class Arm(RobotKind):
    """:class:`~sim2real.deploy.robot_kind.RobotKind` of a fixed-base arm (module docstring); a
    variant is ``Arm(name=..., <choice>=...)``."""

    name: str = "arm"
    floating_base: bool = False
    task: str = "goals"
    joint_input: bool = True
    holds_self_collision: bool = True
    pd_targets: bool | None = False
    hard_limit_bounce: bool | None = False

    def state(self, robot, envs: int) -> RobotState:
        """:meth:`RobotState.zeros` for ``envs`` robots at the robot's ambient temperature."""
        return RobotState.zeros(envs, robot.n_joints, robot.config.sensors.ambient_temperature)

    def targets(self, robot) -> DriveTargets:
        """:func:`~sim2real.deploy.kinds.targets.uniform_targets`: the kind's choices, every
        joint alike."""
        return uniform_targets(self, robot)

    def sensor_frame(self, robot, envs: int):
        """An empty :class:`~sim2real.deploy.core.backend.SensorFrame` of the joints alone."""
        from sim2real.deploy.core.backend import SensorFrame

        return SensorFrame.empty(envs, robot.n_joints, None)

    def base_stages(self, robot, envs: int) -> tuple:
        """``(None, None)``: no base to estimate, nothing to fall."""
        return None, None

    def tick_stage(self, runtime) -> FixedBase:
        """:class:`FixedBase`: no part of the tick."""
        return FixedBase(runtime.envs)


#: A fixed-base arm: reach goals.
ARM = register_kind(Arm())
