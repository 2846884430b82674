"""A legged robot on a floating base (go2, H1, G1): what its shape does, in one place.

Its state carries the base and the feet (:meth:`RobotState.legged`), its sensor frame an IMU and
the feet's contacts; the tick adds a base estimator and a fall check
(:class:`~sim2real.deploy.estimation.base.BaseStateEstimator`,
:class:`~sim2real.deploy.estimation.fall.FallDetector`); it follows velocity commands
(:class:`sim2real.deploy.tasks.velocity.VelocityTask`). Its policy's position targets drive
low-gain PD loops (torque requests): the joint filters run the constant-velocity model, the
guard clamps a target to the soft limit instead of stopping and keeps no motion envelope, a hard
limit stops it only when the estimate stays past, the guard does not hold legs predicted to
touch (unitree_rl_gym's H1 walked through pushes in its own loop and fell in ours while the
guard held them), every stop lays it down (an operator stands it up first) and the soak pushes
it instead of pulling a cable.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.kinds.targets import DriveTargets, uniform_targets
from sim2real.deploy.robot_kind import RobotKind, register_kind


def sends_attitude(robot) -> bool:
    """Whether ``robot``'s IMU sends its own attitude (robot.toml ``[sensors.imu]
    orientation_sigma`` set: an AHRS, as Unitree's G1 and H1 ``imu_state.quaternion``)."""
    imu = robot.config.sensors.imu
    return imu is not None and imu.orientation_sigma is not None


@dataclass(frozen=True)
class Legged(RobotKind):
    """:class:`~sim2real.deploy.robot_kind.RobotKind` of a legged robot (module docstring); a
    variant is ``Legged(name=..., <choice>=...)`` or a subclass
    (:class:`sim2real.deploy.kinds.wheel_legged.WheelLegged`)."""

    name: str = "legged"
    floating_base: bool = True
    task: str = "locomotion"
    joint_input: bool = False
    holds_self_collision: bool = False
    pd_targets: bool | None = True
    hard_limit_bounce: bool | None = True

    def state(self, robot, envs: int) -> RobotState:
        """:meth:`RobotState.legged` (joints, base, feet) at the robot's ambient temperature;
        its ``sensed_orientation`` (upright until the IMU's first attitude) where robot.toml
        says the IMU sends its own attitude (``[sensors.imu] orientation_sigma``)."""
        ambient = robot.config.sensors.ambient_temperature
        state = RobotState.legged(envs, robot.n_joints, robot.n_feet, ambient)
        if sends_attitude(robot):
            state.sensed_orientation = state.base.orientation.copy()
        return state

    def targets(self, robot) -> DriveTargets:
        """:func:`~sim2real.deploy.kinds.targets.uniform_targets`: the kind's choices, every
        joint alike."""
        return uniform_targets(self, robot)

    def sensor_frame(self, robot, envs: int):
        """An empty :class:`~sim2real.deploy.core.backend.SensorFrame`: joints, an IMU, the
        feet's contacts."""
        from sim2real.deploy.core.backend import SensorFrame

        return SensorFrame.empty(envs, robot.n_joints, robot.n_feet)

    def base_stages(self, robot, envs: int) -> tuple:
        """``(BaseStateEstimator, FallDetector)`` of ``envs`` robots."""
        from sim2real.deploy.estimation.base import BaseStateEstimator
        from sim2real.deploy.estimation.fall import FallDetector

        return BaseStateEstimator(robot, envs), FallDetector(robot, envs)

    def tick_stage(self, runtime):
        """:class:`~sim2real.deploy.kinds.legged_tick.LeggedTick` over :meth:`base_stages`:
        the base estimate, contacts, gait clock, stale IMU and fall checks, damped stops."""
        from sim2real.deploy.kinds.legged_tick import LeggedTick

        return LeggedTick(runtime, *self.base_stages(runtime.robot, runtime.envs))


#: A legged robot: follow velocity commands.
LEGGED = register_kind(Legged())
