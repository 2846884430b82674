"""A robot's kind, decided in one place (:func:`robot_kind`): a fixed-base arm or a floating-base
(legged) robot, and what the assembly around it takes from that.

The kind chooses which stages the runtime builds (a legged robot's base estimator and fall check,
and its state layout: :meth:`RobotKind.state`, :meth:`RobotKind.base_stages`), whether the joint
estimator takes the commanded acceleration as its control input, the task
(:func:`sim2real.deploy.tasks.task.task_for`: goals or velocity commands), what an operator does
before clearing a latched fault (a legged robot lies damped after every stop: it is stood up
first), how the guard and the runtime treat position targets that act as torques through a
low-gain PD (:attr:`RobotKind.pd_targets`) and whether the guard lets an estimate bounce off a hard
limit (:attr:`RobotKind.hard_limit_bounce`). Code outside the physics asks the kind. The boolean
``robot.floating_base`` itself is asked by :func:`robot_kind`, by the Robot's kinematics
and, beneath this module, by the estimation's and the spec's checks of their robot
(``tests/test_seams.py`` counts the places).
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
        pd_targets: Its position targets drive low-gain PD loops and act as torques (``kp
            (target - q)``): they lead the joints by design, and legged policies command past the
            joint range (legged_gym trains without bounds on them). The guard has no hard bound on
            a target (it clamps one to the soft limit instead of stopping,
            :mod:`sim2real.deploy.safety.limits`) and no motion envelope
            (:mod:`sim2real.deploy.safety.envelope`); the runtime re-anchors no command at the
            measured pose (no tracking tolerance,
            :func:`sim2real.deploy.runtime.anchoring.tracking_tolerance`) and ends RAMP_IN in
            position mode on the commanded pose (the PD holds the robot's weight short of home).
            None (the default): as ``legged``.
        hard_limit_bounce: The guard stops for an estimate past a hard limit only when it stays
            past (``LEGGED_HARD_LIMIT_*`` of :mod:`sim2real.deploy.safety.limits`): every stop of a
            walking robot is a fall. None (the default): as ``legged``.
    """

    name: str
    legged: bool
    task: str
    joint_input: bool
    stand_up_on_reset: bool
    holds_self_collision: bool = True
    cable_faults: bool = True
    pd_targets: bool | None = None
    hard_limit_bounce: bool | None = None

    def __post_init__(self):
        for name in ("pd_targets", "hard_limit_bounce"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, self.legged)

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
    pd_targets=True,
    hard_limit_bounce=True,
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
    shape = LEGGED if robot.floating_base else ARM  # what the robot's description makes it
    name = getattr(robot.config, "kind", None)
    if name is None:
        return shape
    kind = kinds().get(name)
    where = f"{robot.directory / 'robot.toml'}: kind"
    if kind is None:
        raise ValueError(f"{where} = '{name}': expected one of {sorted(kinds())}")
    if kind.legged != shape.legged:
        need = "a [base] table (a floating base)" if kind.legged else "no [base] table"
        raise ValueError(f"{where} = '{name}' needs {need}")
    return kind
