"""A legged robot carrying an arm (a quadruped with a manipulator on its back: Unitree B2 + Z1,
Go2 + D1): PD legs, a servo arm, one policy.

Its legs are a legged robot's (:class:`~sim2real.deploy.kinds.legged.Legged`: the base and feet
in its state, the base estimate and fall check, velocity commands, every stop laying it down);
its arm's joints are an arm's servos, whose drives follow their command. So what a command
means differs per joint (:meth:`LeggedArm.targets`, a
:class:`~sim2real.deploy.kinds.targets.DriveTargets` with PD legs and a commanded arm):

- a leg's position target is a low-gain PD loop's torque request: unbounded, judged by its
  predicted motion (:mod:`sim2real.deploy.safety.pd_barrier`);
- an arm joint's target is bounded by its hard limits and clamped to its soft ones
  (:mod:`sim2real.deploy.safety.limits`), never passed on past them, and the PD barrier leaves it
  alone; the smoother bounds its command by the hard limits.

Which joints are legs is the robot's kinematics: those on the chain from the base to a foot
(Pinocchio's ``supports`` of each foot frame's parent joint, robot.toml ``[base] feet``); the
rest are the arm. :meth:`LeggedArm.check` refuses a robot without both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.deploy.kinds.legged import Legged
from sim2real.deploy.kinds.targets import DriveTargets
from sim2real.deploy.robot_kind import register_kind


def leg_joints(robot) -> np.ndarray:
    """(n_joints,) bool: the joints on the chain from the base to a foot of ``robot`` (its
    ``[base] feet``, Pinocchio's ``supports`` of each foot frame's parent joint)."""
    model = robot.pin_model
    index = {name: j for j, name in enumerate(robot.joint_names)}
    legs = np.zeros(robot.n_joints, dtype=bool)
    for frame in robot.foot_frame_ids:
        for joint in model.supports[model.frames[frame].parentJoint]:
            j = index.get(model.names[joint])
            if j is not None:
                legs[j] = True
    return legs


@dataclass(frozen=True)
class LeggedArm(Legged):
    """:class:`~sim2real.deploy.kinds.legged.Legged` with an arm (module docstring)."""

    name: str = "legged_arm"

    def check(self, robot, where: str) -> None:
        """As a legged robot's, and the arm: at least one joint on no foot's chain.

        Raises:
            ValueError: ``where`` (robot.toml's ``kind`` field) and what the kind needs.
        """
        super().check(robot, where)
        if leg_joints(robot).all():
            raise ValueError(
                f"{where} = '{self.name}' needs an arm: expected a joint on no foot's chain "
                "([base] feet)"
            )

    def targets(self, robot) -> DriveTargets:
        """PD targets on the legs (:func:`leg_joints`), commanded targets on the arm; the legs'
        choices otherwise (hard-limit bounce, no self-collision hold, the joint filters'
        constant-velocity model: the legs' PD targets step)."""
        legs = leg_joints(robot)
        return DriveTargets(legs, self.hard_limit_bounce, self.holds_self_collision, False)


#: A legged robot with an arm: PD legs, a servo arm.
LEGGED_ARM = register_kind(LeggedArm())
