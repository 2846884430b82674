"""A robot's kind, decided in one place (:func:`robot_kind`): a fixed-base arm or a floating-base
(legged) robot, and what the assembly around it takes from that.

The kind chooses which stages the runtime builds (a legged robot's base estimator and fall check,
and its state layout: :meth:`RobotKind.state`, :meth:`RobotKind.base_stages`), whether the joint
estimator takes the commanded acceleration as its control input, the task
(:func:`sim2real.deploy.tasks.task.task_for`: goals or velocity commands), and what an operator does
before clearing a latched fault (a legged robot lies damped after every stop: it is stood up
first). Branches that are a physics difference of a floating base (the plant's free joint, the
guard's unbounded PD targets, the re-anchoring's tolerance) ask ``robot.floating_base`` where
they are.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim2real.deploy.core.registry import Registry
from sim2real.deploy.core.state import RobotState


@dataclass(frozen=True)
class RobotKind:
    """What the assembly of a robot depends on.

    Attributes:
        name: ``"arm"`` (fixed base) or ``"legged"`` (floating base).
        legged: A floating base: IMU and feet in the state, a base estimator and a fall check.
        task: The task's name (:func:`sim2real.deploy.tasks.task.task_for`): ``"goals"`` or
            ``"locomotion"``.
        joint_input: The joint estimator (:class:`~sim2real.deploy.estimation.joints.JointStateEstimator`)
            takes the smoother's commanded acceleration as its control input, in its prediction
            and in the extrapolation that bridges latency (:meth:`SafetyGuard.estimator_input
            <sim2real.deploy.safety.guard.SafetyGuard.estimator_input>`). An arm's stiff drives follow
            their command. A floating base's low-gain PD targets lead its joints and may step
            from tick to tick (a legged policy's targets are torques): their acceleration is not
            the joints', so its filter runs the constant-velocity model instead.
        stand_up_on_reset: An operator stands the robot up before clearing a latched fault (the
            runtime lays a legged robot down, damped, at every stop).
        holds_self_collision: The guard holds a target predicted to bring two links into
            contact (:mod:`sim2real.deploy.safety.predicted`). Not for a legged robot: its legs held
            mid-stride lay it down (unitree_rl_gym's H1 walked through pushes in its own loop
            and fell in ours while the guard held them).
        cable_faults: The soak injects cable pulls (a fixed base's tether); a legged robot gets
            pushes instead.
    """

    name: str
    legged: bool
    task: str
    joint_input: bool
    stand_up_on_reset: bool
    holds_self_collision: bool = True
    cable_faults: bool = True

    def state(self, robot, envs: int) -> RobotState:
        """The runtime's state layout for ``envs`` robots at the robot's ambient temperature:
        :meth:`RobotState.zeros`, or :meth:`RobotState.legged` with the base and feet."""
        ambient = robot.config.sensors.ambient_temperature
        if self.legged:
            return RobotState.legged(envs, robot.n_joints, robot.n_feet, ambient)
        return RobotState.zeros(envs, robot.n_joints, ambient)

    def base_stages(self, robot, envs: int) -> tuple:
        """``(base_estimator, fall_detector)`` of a legged robot
        (:class:`~sim2real.deploy.estimation.base.BaseStateEstimator`,
        :class:`~sim2real.deploy.estimation.fall.FallDetector`); ``(None, None)`` for an arm."""
        if not self.legged:
            return None, None
        from sim2real.deploy.estimation.base import BaseStateEstimator
        from sim2real.deploy.estimation.fall import FallDetector

        return BaseStateEstimator(robot, envs), FallDetector(robot, envs)


#: A fixed-base arm: reach goals.
ARM = RobotKind(name="arm", legged=False, task="goals", joint_input=True, stand_up_on_reset=False)
#: A floating-base (legged) robot: follow velocity commands.
LEGGED = RobotKind(
    name="legged",
    legged=True,
    task="locomotion",
    joint_input=False,
    stand_up_on_reset=True,
    holds_self_collision=False,
    cable_faults=False,
)

#: The registered robot kinds (:class:`sim2real.deploy.core.registry.Registry`).
KIND_REGISTRY: Registry[RobotKind] = Registry("robot kind")


def register_kind(kind: RobotKind) -> RobotKind:
    """Register ``kind`` under its name: robot.toml's ``kind = "<name>"`` chooses it.

    Raises:
        ValueError: the name is registered already, or the kind's task is not one
            :func:`sim2real.deploy.tasks.task.task_for` builds (``goals``, ``locomotion``).
    """
    if kind.task not in ("goals", "locomotion"):
        raise ValueError(f"robot kind '{kind.name}': task '{kind.task}' is not goals or locomotion")
    return KIND_REGISTRY.register(kind.name, kind)


register_kind(ARM)
register_kind(LEGGED)


def kinds() -> dict[str, RobotKind]:
    """The registered robot kinds by name."""
    return KIND_REGISTRY.entries()


def robot_kind(robot) -> RobotKind:
    """The kind of ``robot``: robot.toml's ``kind``, else :data:`LEGGED` for a floating base
    (``[base]``, a free joint in its MJCF) and :data:`ARM` otherwise.

    Raises:
        ValueError: robot.toml names a kind nobody registered, or a legged kind for a robot
            without a floating base (its state has no base), or the reverse.
    """
    name = getattr(robot.config, "kind", None)
    if name is None:
        return LEGGED if robot.floating_base else ARM
    kind = kinds().get(name)
    where = f"{robot.directory / 'robot.toml'}: kind"
    if kind is None:
        raise ValueError(f"{where} = '{name}': expected one of {sorted(kinds())}")
    if kind.legged != robot.floating_base:
        need = "a [base] table (a floating base)" if kind.legged else "no [base] table"
        raise ValueError(f"{where} = '{name}' needs {need}")
    return kind
