"""A robot's kind, decided in one place (:func:`robot_kind`): a fixed-base arm, a floating-base
(legged) robot, a wheel-legged one (:mod:`sim2real.deploy.kinds.wheel_legged`) or a kind a
contributor registers (:func:`register_kind`, robot.toml ``kind = "<name>"``).

A :class:`RobotKind` is what the assembly around a robot asks instead of testing its shape: the
state layout and sensor frame (:meth:`RobotKind.state`, :meth:`RobotKind.sensor_frame`), the base
stages (:meth:`RobotKind.base_stages`; the rig judges their estimate against the truth),
the task
(:func:`sim2real.deploy.tasks.task.task_for`: goals or velocity commands), how its velocity-driven
joints brake in a safe stop (:meth:`RobotKind.wheel_drives`), the soak's disturbances
(:attr:`RobotKind.cable_faults`, :attr:`RobotKind.pushes`), what an operator does before clearing
a latched fault, how the guard and the runtime treat PD targets (:attr:`RobotKind.pd_targets`,
:attr:`RobotKind.hard_limit_bounce`) and which robots fit it (:meth:`RobotKind.check`). The
boolean ``robot.floating_base`` itself is asked by :func:`robot_kind`, by the Robot's
kinematics, by the physics and the soak's world beneath, and by the estimation's and the spec's
checks of their robot (``tests/test_seams.py`` counts the places, and the lines outside the
kinds that branch on a kind).
"""

from __future__ import annotations

from dataclasses import dataclass

from sim2real.deploy.core.registry import Registry
from sim2real.deploy.core.state import RobotState


@dataclass(frozen=True)
class RobotKind:
    """What the assembly of a robot depends on.

    Attributes:
        name: The name robot.toml's ``kind`` gives (``"arm"``, ``"legged"``, ``"wheel_legged"``).
        floating_base: The robot's base moves freely (robot.toml's ``[base]``, a free joint in
            its MJCF): an IMU and feet in the state, a base estimator and a fall check
            (:meth:`check` holds the robot to it).
        task: The task's name (:func:`sim2real.deploy.tasks.task.task_for`): ``"goals"`` or
            ``"locomotion"``.
        joint_input: The joint estimator (:class:`~sim2real.deploy.estimation.joints.JointStateEstimator`)
            takes the smoother's commanded acceleration as its control input, in its prediction
            and in the extrapolation that bridges latency (:meth:`SafetyGuard.estimator_input
            <sim2real.deploy.safety.guard.SafetyGuard.estimator_input>`). An arm's stiff drives follow
            their command. A floating base's low-gain PD targets lead its joints and may step
            from tick to tick (a legged policy's targets are torques): their acceleration is not
            the joints', so its filter runs the constant-velocity model instead.
        stand_up_on_reset: Every safe stop lays the robot down, damped (a walking robot's stop
            is a fall): an operator stands it up before clearing a latched fault, the violation
            monitor counts its ticks lying down apart, and the soak replays a hard-limit stop
            without it (:mod:`sim2real.eval.soak.counterfactual`).
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
            None (the default): as ``floating_base``.
        hard_limit_bounce: The guard stops for an estimate past a hard limit only when it stays
            past (``LEGGED_HARD_LIMIT_*`` of :mod:`sim2real.deploy.safety.limits`): every stop of a
            walking robot is a fall. None (the default): as ``floating_base``.
        pushes: The soak pushes the base as the policy's training domain did (the ranges'
            ``pushes``, legged_gym's ``push_robots``). None (the default): as ``floating_base``.
    """

    name: str
    floating_base: bool
    task: str
    joint_input: bool
    stand_up_on_reset: bool
    holds_self_collision: bool = True
    cable_faults: bool = True
    pd_targets: bool | None = None
    hard_limit_bounce: bool | None = None
    pushes: bool | None = None

    def __post_init__(self):
        for name in ("pd_targets", "hard_limit_bounce", "pushes"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, self.floating_base)

    @property
    def legged(self) -> bool:
        """:attr:`floating_base` (the name of older callers)."""
        return self.floating_base

    def check(self, robot, where: str) -> None:
        """Refuse a robot this kind does not fit: a floating-base kind for a robot without a
        floating base (its state has no base) or the reverse, or velocity-driven joints
        (robot.toml or the policy's ``drive``) on a kind whose :meth:`wheel_drives` has none.

        Raises:
            ValueError: ``where`` (robot.toml's ``kind`` field) and what the kind needs.
        """
        if self.floating_base != robot.floating_base:
            need = "a [base] table (a floating base)" if self.floating_base else "no [base] table"
            raise ValueError(f"{where} = '{self.name}' needs {need}")
        driven = [n for n, v in zip(robot.joint_names, robot.velocity_driven, strict=True) if v]
        if driven and type(self).wheel_drives is RobotKind.wheel_drives:
            raise ValueError(
                f"{where} = '{self.name}' drives no joint by velocity, but {', '.join(driven)} "
                "are (drive = \"velocity\"): expected kind = 'wheel_legged'"
            )

    def state(self, robot, envs: int) -> RobotState:
        """The runtime's state layout for ``envs`` robots at the robot's ambient temperature:
        :meth:`RobotState.zeros`, or :meth:`RobotState.legged` with the base and feet."""
        ambient = robot.config.sensors.ambient_temperature
        if self.floating_base:
            return RobotState.legged(envs, robot.n_joints, robot.n_feet, ambient)
        return RobotState.zeros(envs, robot.n_joints, ambient)

    def sensor_frame(self, robot, envs: int):
        """An empty :class:`~sim2real.deploy.core.backend.SensorFrame` of a backend reading
        ``envs`` robots: joints, plus an IMU and the feet's contacts for a floating base."""
        from sim2real.deploy.core.backend import SensorFrame

        feet = robot.n_feet if self.floating_base else None
        return SensorFrame.empty(envs, robot.n_joints, feet)

    def base_stages(self, robot, envs: int) -> tuple:
        """``(base_estimator, fall_detector)`` of a floating base
        (:class:`~sim2real.deploy.estimation.base.BaseStateEstimator`,
        :class:`~sim2real.deploy.estimation.fall.FallDetector`); ``(None, None)`` for an arm."""
        if not self.floating_base:
            return None, None
        from sim2real.deploy.estimation.base import BaseStateEstimator
        from sim2real.deploy.estimation.fall import FallDetector

        return BaseStateEstimator(robot, envs), FallDetector(robot, envs)

    def wheel_drives(self, robot, envs: int, mode: str):
        """The command stage of the robot's velocity-driven joints (their speed targets, and
        what a safe stop brakes them to:
        :class:`~sim2real.deploy.core.velocity_drive.VelocityDrives`), or None: this kind has
        none (:meth:`check` refuses a robot with any)."""
        return None


#: A fixed-base arm: reach goals.
ARM = RobotKind(
    name="arm", floating_base=False, task="goals", joint_input=True, stand_up_on_reset=False
)
#: A floating-base (legged) robot: follow velocity commands.
LEGGED = RobotKind(
    name="legged",
    floating_base=True,
    task="locomotion",
    joint_input=False,
    stand_up_on_reset=True,
    holds_self_collision=False,
    cable_faults=False,
    pd_targets=True,
    hard_limit_bounce=True,
)

#: The registered robot kinds (:class:`sim2real.deploy.core.registry.Registry`).
KIND_REGISTRY: Registry[RobotKind] = Registry(
    "robot kind", builtin=("sim2real.deploy.kinds.wheel_legged",)
)


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
    """The kind of ``robot``: robot.toml's ``kind``, else what its description makes it:
    :data:`ARM` without a floating base, :data:`LEGGED` with one (``[base]``, a free joint in its
    MJCF), ``wheel_legged`` (:mod:`sim2real.deploy.kinds.wheel_legged`) with one and
    velocity-driven joints.

    Raises:
        ValueError: robot.toml names a kind nobody registered, or a kind that does not fit the
            robot (:meth:`RobotKind.check`).
    """
    name = getattr(robot.config, "kind", None)
    where = f"{robot.directory / 'robot.toml'}: kind"
    if name is None:  # what the robot's description makes it
        if not robot.floating_base:
            return ARM
        return kinds()["wheel_legged"] if robot.velocity_driven.any() else LEGGED
    kind = kinds().get(name)
    if kind is None:
        raise ValueError(f"{where} = '{name}': expected one of {sorted(kinds())}")
    kind.check(robot, where)
    return kind
