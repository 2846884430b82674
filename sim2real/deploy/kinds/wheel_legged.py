"""A wheel-legged robot (Unitree Go2-W, B2-W): a legged robot whose feet are wheels.

Its policy drives the legs by PD position targets and the wheels by speed targets in one network
(fan-ziqi/rl_sar ``policy/go2w``: legs ``kp`` 20, wheels ``kp`` 0, ``kd`` 0.5, the wheel's action
a velocity target); the drive of each joint is robot.toml's or the policy's contract's
``drive``. Everything a legged robot is, it is too (a
:class:`~sim2real.deploy.kinds.legged.Legged`: its state, base stages, task, guard and soak
choices), plus what is its own:

- its wheels are continuous joints (robot.toml ``continuous = true``): no position limit, checked
  on speed and torque (:attr:`sim2real.robots.robot.Robot.position_lower` is -inf there);
  :meth:`WheelLegged.wheels` names them for the stages that need them;
- its velocity-driven wheels take their speed target through
  :class:`~sim2real.deploy.core.velocity_drive.VelocityDrives`, and a safe stop brakes them to
  0 rad/s (their ``kd``) while the legs are damped (:meth:`WheelLegged.wheel_drives`);
- a robot of this kind has at least one continuous joint, and every velocity-driven joint is one
  (:meth:`WheelLegged.check`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.deploy.core.velocity_drive import velocity_drives
from sim2real.deploy.kinds.legged import Legged
from sim2real.deploy.robot_kind import register_kind


@dataclass(frozen=True)
class WheelLegged(Legged):
    """:class:`~sim2real.deploy.kinds.legged.Legged` on wheels."""

    name: str = "wheel_legged"

    def wheels(self, robot) -> np.ndarray:
        """(n_joints,) bool: the robot's wheels, its continuous joints (no position limit)."""
        return np.array([bool(j.continuous) for j in robot.config.joints], dtype=bool)

    def check(self, robot, where: str) -> None:
        """As a legged robot's, and the wheels: at least one continuous joint, and every
        velocity-driven joint one of them.

        Raises:
            ValueError: ``where`` (robot.toml's ``kind`` field) and the joints at fault.
        """
        super().check(robot, where)
        wheels = self.wheels(robot)
        if not wheels.any():
            raise ValueError(
                f"{where} = '{self.name}' needs wheels: expected a joint with continuous = true"
            )
        names = robot.joint_names
        off = [names[i] for i in np.flatnonzero(robot.velocity_driven & ~wheels)]
        if off:
            raise ValueError(
                f"{where} = '{self.name}': {', '.join(off)} velocity-driven but not continuous "
                "(a wheel has no position limit): expected continuous = true"
            )

    def wheel_drives(self, robot, envs: int, mode: str):
        """:class:`~sim2real.deploy.core.velocity_drive.VelocityDrives` of the velocity-driven
        wheels in position mode (their speed targets clamped to the soft velocity limit, 0 rad/s
        in a safe stop), else None (:func:`~sim2real.deploy.core.velocity_drive.velocity_drives`)."""
        return velocity_drives(robot, envs, mode)


#: A wheel-legged robot: a legged robot's choices, its own wheels.
WHEEL_LEGGED = register_kind(WheelLegged())
