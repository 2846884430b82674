"""The robot kinds' record type (:class:`RobotKind`) and their registry (:data:`KIND_REGISTRY`,
:func:`register_kind`, :func:`robot_kind`): robot.toml ``kind = "<name>"`` chooses one, else the
robot's description (a fixed base: ``arm``, a floating base: ``legged``, one with
velocity-driven joints: ``wheel_legged``).

Each kind is one module of :mod:`sim2real.deploy.kinds` (``arm``, ``legged``, ``wheel_legged``,
registered when that package is imported: the rooms that ask a robot's kind import
:func:`sim2real.deploy.kinds.robot_kind`), the one place that says what its shape does: the state
layout and sensor frame (:meth:`RobotKind.state`, :meth:`RobotKind.sensor_frame`), the base
stages (:meth:`RobotKind.base_stages`; the rig judges their estimate against the truth), the task
(:func:`sim2real.deploy.tasks.task.task_for`), how its velocity-driven joints brake in a safe
stop (:meth:`RobotKind.wheel_drives`), what a command means to each drive
(:meth:`RobotKind.targets`: the object the guard and the runtime ask, made of
:attr:`RobotKind.pd_targets`, :attr:`RobotKind.hard_limit_bounce` and the rest) and which robots
fit it (:meth:`RobotKind.check`); whether a stop lays it down is its tick stage's
(:meth:`RobotKind.tick_stage`, ``lying``). What a higher floor does per kind (the soak's range
defaults, its world's pushes and faults, its operator's stand-up, the plant's extras, the film)
is a face registered under the kind's name in that floor's room
(:class:`sim2real.deploy.core.registry.Faces`).
The boolean ``robot.floating_base`` itself is asked by :func:`robot_kind`, by the Robot's
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
    """What the assembly of a robot depends on: a record of its choices and the stages its shape
    adds. A kind subclasses it (:class:`sim2real.deploy.kinds.arm.Arm`,
    :class:`sim2real.deploy.kinds.legged.Legged`) and says what :meth:`state`,
    :meth:`sensor_frame` and :meth:`base_stages` are.

    Attributes:
        name: The name robot.toml's ``kind`` gives (``"arm"``, ``"legged"``, ``"wheel_legged"``).
        floating_base: The robot's base moves freely (robot.toml's ``[base]``, a free joint in
            its MJCF); :meth:`check` holds the robot to it.
        task: The task's name (:data:`sim2real.deploy.tasks.task.TASKS`): ``"goals"`` or
            ``"locomotion"``.
        joint_input: The joint estimator takes the smoother's commanded acceleration as its
            control input (:meth:`SafetyGuard.estimator_input
            <sim2real.deploy.safety.guard.SafetyGuard.estimator_input>`): drives that follow
            their command. Low-gain PD targets lead the joints and may step from tick to tick:
            their filter runs the constant-velocity model instead.
        holds_self_collision: The guard holds a target predicted to bring two links into
            contact (:mod:`sim2real.deploy.safety.predicted`).
        pd_targets: Its position targets drive low-gain PD loops and act as torques: no hard
            bound on a target (clamped to the soft limit, :mod:`sim2real.deploy.safety.limits`),
            no motion envelope, no tracking tolerance, RAMP_IN in position mode ending on the
            commanded pose. None (the default): as ``floating_base``.
        hard_limit_bounce: The guard stops for an estimate past a hard limit only when it stays
            past (``LEGGED_HARD_LIMIT_*`` of :mod:`sim2real.deploy.safety.limits`). None (the
            default): as ``floating_base``.
    """

    name: str
    floating_base: bool
    task: str
    joint_input: bool
    holds_self_collision: bool = True
    pd_targets: bool | None = None
    hard_limit_bounce: bool | None = None

    def __post_init__(self):
        for name in ("pd_targets", "hard_limit_bounce"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, self.floating_base)

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
        """The runtime's state layout for ``envs`` robots at the robot's ambient temperature.

        Raises:
            NotImplementedError: a kind that does not say (subclass a built-in kind)."""
        raise NotImplementedError(f"robot kind '{self.name}': state")

    def sensor_frame(self, robot, envs: int):
        """An empty :class:`~sim2real.deploy.core.backend.SensorFrame` of a backend reading
        ``envs`` robots. Raises NotImplementedError: a kind that does not say."""
        raise NotImplementedError(f"robot kind '{self.name}': sensor_frame")

    def base_stages(self, robot, envs: int) -> tuple:
        """``(base_estimator, fall_detector)`` the kind's base adds to the tick, or ``(None,
        None)``. Raises NotImplementedError: a kind that does not say."""
        raise NotImplementedError(f"robot kind '{self.name}': base_stages")

    def tick_stage(self, runtime):
        """The part of ``runtime``'s tick this kind's base adds: ``stages`` (``(base_estimator,
        fall_detector)`` or ``(None, None)``), ``fusable``, ``bind()``, ``start(frame)``,
        ``restart(t, envs)``, ``update(frame, state)``, ``damp(cmd, state)``,
        ``damping(mode)``, ``lying(mode)`` (the envs lying down after a stop, or None: it
        never lies down), ``parts()`` (:class:`sim2real.deploy.kinds.legged_tick.LeggedTick`,
        :class:`sim2real.deploy.kinds.arm.FixedBase`). Raises NotImplementedError: a kind
        that does not say."""
        raise NotImplementedError(f"robot kind '{self.name}': tick_stage")

    def targets(self, robot):
        """What a command means to each of ``robot``'s drives
        (:class:`sim2real.deploy.kinds.targets.DriveTargets`): the object the guard, the smoother
        and the runtime ask for target bounds, their checks' rows, the joint filters' input and
        the tolerances. Raises NotImplementedError: a kind that does not say."""
        raise NotImplementedError(f"robot kind '{self.name}': targets")

    def lineage(self) -> tuple[str, ...]:
        """The kinds whose faces this kind takes, nearest first (a face registered under a
        higher room's name is inherited, :class:`sim2real.deploy.core.registry.Faces`): its own
        name, then for its class and each base class in method resolution order the first other
        registered kind of exactly that class (a wheel-legged robot's
        ``("wheel_legged", "legged")``, a contributor's ``Arm(name="compliant_arm")``'s
        ``("compliant_arm", "arm")``)."""
        entries = KIND_REGISTRY.entries()
        out = [self.name]
        for cls in type(self).__mro__:
            same = [n for n, k in entries.items() if type(k) is cls and n not in out]
            out += same[:1]
        return tuple(out)

    def wheel_drives(self, robot, envs: int, mode: str):
        """The command stage of the robot's velocity-driven joints (their speed targets, and
        what a safe stop brakes them to:
        :class:`~sim2real.deploy.core.velocity_drive.VelocityDrives`), or None: this kind has
        none (:meth:`check` refuses a robot with any)."""
        return None


#: The tasks a robot kind may have as its own (:attr:`RobotKind.task`), each a task registered
#: in :data:`sim2real.deploy.tasks.task.TASKS` (a room above: ``tests/test_seams.py`` holds the
#: two to agree); a motion-tracking policy's ``tracking`` task is its policy's choice, not a
#: kind's.
KIND_TASKS = ("goals", "locomotion")

#: The registered robot kinds (:class:`sim2real.deploy.core.registry.Registry`); the built-in
#: ones register when :mod:`sim2real.deploy.kinds` is imported, a kind kept outside the tree when
#: its module, an entry point of the group ``sim2real.kinds``, is imported by the registry.
KIND_REGISTRY: Registry[RobotKind] = Registry("robot kind", group="sim2real.kinds")


def register_kind(kind: RobotKind) -> RobotKind:
    """Register ``kind`` under its name: robot.toml's ``kind = "<name>"`` chooses it.

    Raises:
        ValueError: the name is registered already, or the kind's task is not one of
            :data:`KIND_TASKS`.
    """
    if kind.task not in KIND_TASKS:
        raise ValueError(
            f"robot kind '{kind.name}': task '{kind.task}' is not one of {', '.join(KIND_TASKS)}"
        )
    return KIND_REGISTRY.register(kind.name, kind)


def kinds() -> dict[str, RobotKind]:
    """The registered robot kinds by name."""
    return KIND_REGISTRY.entries()


#: The kind of a robot whose robot.toml names none, by its description: (floating base,
#: velocity-driven joints) -> the kind's name.
DEFAULT_KINDS = {
    (False, False): "arm",
    (False, True): "arm",
    (True, False): "legged",
    (True, True): "wheel_legged",
}


def robot_kind(robot) -> RobotKind:
    """The kind of ``robot``: robot.toml's ``kind``, else what its description makes it
    (:data:`DEFAULT_KINDS`: ``arm`` without a floating base, ``legged`` with one (``[base]``, a
    free joint in its MJCF), ``wheel_legged`` with one and velocity-driven joints).

    Raises:
        ValueError: robot.toml names a kind nobody registered (or its description one not
            registered: :mod:`sim2real.deploy.kinds` not imported), or a kind that does not
            fit the robot (:meth:`RobotKind.check`).
    """
    name = getattr(robot.config, "kind", None)
    where = f"{robot.directory / 'robot.toml'}: kind"
    given = name is not None
    if not given:  # what the robot's description makes it
        name = DEFAULT_KINDS.get((robot.floating_base, bool(robot.velocity_driven.any())))
    kind = kinds().get(name)
    if kind is None:
        raise ValueError(f"{where} = '{name}': expected one of {sorted(kinds())}")
    if given:
        kind.check(robot, where)
    return kind
