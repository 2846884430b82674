"""The registry of observation block kinds: one :class:`ObservationKind` entry per kind.

An entry holds everything about a kind: its name, its size (fixed, per joint read, per foot), its
raw quantity with units and the physical scale it is divided by, its numpy writer
(:mod:`sim2real.deploy.spec.reference`) and its branch code in the compiled kernel
(:mod:`sim2real.deploy.spec.kernel`). The spec's validation and JSON shorthands
(:mod:`sim2real.deploy.spec.policy_spec`, :mod:`sim2real.deploy.spec.schema`), the standard spec of a robot
(:mod:`sim2real.deploy.spec.defaults`) and the observation plan (:mod:`sim2real.deploy.spec.observation_plan`)
read it. :func:`register_kind` refuses a kind without a kernel branch unless it states why it has none
(``numpy_only``: ``height_scan``, whose terrain heights the kernel takes no input for).

A block may read some ``components`` of its kind's raw vector, in any order: a vector kind's
3-vector (holosoma's velocity command split into its linear and yaw entries), or ``gait_phase``'s
``sin p, cos p, sin(p + pi), cos(p + pi)`` (two feet half a period apart, in the order a policy
reads them). The kernel runs them; only a spec that was never validated (a joint block whose size
does not follow from its joints) runs the numpy writers (:func:`numpy_reason`, kept in
``ObservationPlan.numpy_reason``). The numbers are the same either way.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from sim2real.deploy.spec import height_scan, kernel, motion_blocks, reference
from sim2real.robots.errors import Sim2RealError


class KindError(Sim2RealError, ValueError):
    """An observation kind cannot be registered; the message names the kind and the field."""


@dataclass(frozen=True)
class ObservationKind:
    """One block kind of the observation vector.

    Attributes:
        name: The kind's name in a spec (``ObservationBlock.name``).
        units: The raw quantity, its SI unit and frame, and the physical scale a standard spec
            divides it by (documentation).
        numpy: The reference writer ``(state, goal, raw, block, vec, rot) -> None``
            (:mod:`sim2real.deploy.spec.reference`).
        kernel_code: The kernel's branch code for it (one of ``sim2real.deploy.spec.kernel.BRANCHES``).
        size: Entries of a kind that reads no joints (a per-foot kind: the default count, a
            quadruped's four); 0 for joint kinds.
        per_joint: Entries per joint read (1; 2 for sin and cos); 0: reads no joints.
        every_joint: Reads every joint once (``joints`` a permutation of all joints).
        per_foot: One entry per foot (checked against the robot's feet).
        needs_base: Needs a floating-base robot's state (the base estimate, command, clock),
            which a floating-base robot kind provides
            (:meth:`sim2real.deploy.robot_kind.RobotKind.provides`).
        vector: A 3-vector (x, y, z; a command's vx, vy, yaw rate) whose blocks may read some of
            its entries (``ObservationBlock.components``).
        raw_entries: Entries of the raw vector a block may pick ``components`` from (3 for a
            vector kind, 4 for ``gait_phase``); 0: none.
        periodic: Needs the block's ``period`` (s, > 0).
        scan: Reads a terrain height pattern (the block's ``scan``,
            :class:`sim2real.deploy.spec.height_scan.HeightScanPattern`), its size the pattern's.
        numpy_only: Why the kind has no kernel branch and runs in numpy (``kernel_code`` None:
            the motion-tracking blocks, :mod:`sim2real.deploy.spec.motion_blocks`, and the height
            scan); empty: it runs in the kernel.
    """

    name: str
    units: str
    numpy: Callable[..., None] | None
    kernel_code: int | None
    size: int = 0
    per_joint: int = 0
    every_joint: bool = False
    per_foot: bool = False
    needs_base: bool = False
    vector: bool = False
    periodic: bool = False
    raw_entries: int = 0
    scan: bool = False
    numpy_only: str = ""

    def block_size(self, joints: int) -> int:
        """Entries of a block of this kind reading ``joints`` joints (all its components)."""
        return self.per_joint * joints if self.per_joint else self.size


#: The registered kinds by name, in registration order.
KINDS: dict[str, ObservationKind] = {}


def register_kind(kind: ObservationKind) -> ObservationKind:
    """Add ``kind`` to the registry; returns it.

    Raises:
        KindError: a name already registered, no numpy writer, inconsistent sizes, no kernel
            code (every kind runs in the compiled kernel but one whose ``numpy_only`` says why
            it cannot), or a code the kernel has no branch for
            or another kind's.
    """
    where = f"observation kind '{kind.name}'"
    if not kind.name or kind.name in KINDS:
        raise KindError(f"{where}: the name is empty or already registered")
    if kind.numpy is None:
        raise KindError(f"{where}: no numpy writer (the reference the kernel is tested against)")
    if (kind.per_joint > 0) == (kind.size > 0):
        raise KindError(f"{where}: give either a fixed size or entries per joint, not both")
    if kind.every_joint and not kind.per_joint:
        raise KindError(f"{where}: every_joint is for joint kinds")
    if kind.vector and (kind.size != 3 or kind.raw_entries != 3):
        raise KindError(f"{where}: a vector kind has 3 entries (size and raw_entries)")
    if kind.kernel_code is None and kind.numpy_only:
        KINDS[kind.name] = kind  # a stated reason: the plan runs the numpy writers
        return kind
    if kind.kernel_code is None:
        raise KindError(
            f"{where}: no kernel_code: every kind runs in the compiled kernel; add its branch to "
            "sim2real/deploy/spec/kernel.py and register its code, or state numpy_only (why it has none)"
        )
    if kind.kernel_code not in kernel.BRANCHES:
        raise KindError(
            f"{where}: kernel_code {kind.kernel_code} has no branch in sim2real/deploy/spec/kernel.py "
            f"(its codes: {sorted(kernel.BRANCHES)})"
        )
    taken = [k.name for k in KINDS.values() if k.kernel_code == kind.kernel_code]
    if taken:
        raise KindError(f"{where}: kernel_code {kind.kernel_code} is the code of '{taken[0]}'")
    KINDS[kind.name] = kind
    return kind


def kind_names(needs_base: bool | None = None) -> tuple[str, ...]:
    """The registered kinds' names in registration order (``needs_base`` given: only the kinds
    that need, or only those that do not need, a floating-base robot's state)."""
    return tuple(k.name for k in KINDS.values() if needs_base is None or k.needs_base == needs_base)


def vector_kind_names() -> tuple[str, ...]:
    """The kinds whose blocks may read some ``components`` (the vector kinds, ``gait_phase``)."""
    return tuple(k.name for k in KINDS.values() if k.raw_entries)


def numpy_reason(block) -> str | None:
    """Why a block (:class:`sim2real.deploy.spec.policy_spec.ObservationBlock` of a registered kind) cannot
    run in the kernel, or None: its size does not follow from its joints (a spec not validated)."""
    kind = KINDS[block.name]
    if kind.numpy_only:
        return f"block '{block.name}': {kind.numpy_only}"
    if kind.per_joint and block.size != kind.per_joint * len(block.joints):
        return f"block '{block.name}' has {block.size} entries for {len(block.joints)} joints"
    return None


#: Blocks published policies read that no robot here provides, by the names legged_gym and Isaac
#: Lab use; where this toolkit has the quantity, the name it has here.
UNPROVIDED_KINDS = {
    "base_lin_vel": "base_linear_velocity",
    "base_ang_vel": "base_angular_velocity",
    "commands": "velocity_command",
    "velocity_commands": "velocity_command",
    "base_euler_xyz": "base_euler_angles",
    "base_height": None,
}


# The built-in kinds' numpy writers are the functions of the same name in sim2real.deploy.spec.reference.
def _joint(name: str, units: str, code: int, per_joint: int = 1, every: bool = False) -> None:
    register_kind(ObservationKind(name, units, getattr(reference, name), code, 0, per_joint, every))


def _fixed(name: str, units: str, code: int, size: int = 3, **flags: bool) -> None:
    register_kind(ObservationKind(name, units, getattr(reference, name), code, size, **flags))


# ---------------------------------------------------------------------- the built-in kinds
# An arm's (n = joints, k = joints read; base frame unless stated).
_joint(
    "joint_position",
    "q (k), rad; offset = centre of the limits, scale = half range",
    kernel.JOINT_POSITION,
)
_joint("joint_velocity", "dq (k), rad/s; scale = velocity limit", kernel.JOINT_VELOCITY)
_joint(
    "joint_position_zero",
    "0 (k) in a joint position's place: a joint whose angle the policy never sees (a wheel's; "
    "rl_sar's wheel_indices in dof_pos); offset 0",
    kernel.JOINT_POSITION_ZERO,
)
_joint(
    "joint_position_sincos",
    "sin q, cos q (2k) of wrapping joints; unscaled",
    kernel.JOINT_POSITION_SINCOS,
    per_joint=2,
)
_fixed("ee_position", "end-effector position (3), m; scale = reach", kernel.EE_POSITION)
_fixed("goal_position", "goal position (3), m; scale = reach", kernel.GOAL_POSITION)
_fixed(
    "goal_in_ee",
    "goal - end effector (3) in the end-effector frame, m; scale = reach",
    kernel.GOAL_IN_EE,
)
_joint("last_action", "the previous action (n), in [-1, 1]", kernel.LAST_ACTION, every=True)
_joint(
    "winding_temperature",
    "winding temperature (n), degC; offset = ambient, scale = max winding - ambient",
    kernel.WINDING_TEMPERATURE,
    every=True,
)
# A floating-base (legged) robot's: the base's own motion and the command, never its absolute
# world position or yaw. Joint positions about the default pose are a joint_position block with
# offset = the home pose.
_base = {"needs_base": True}
_fixed(
    "base_linear_velocity",
    "base linear velocity (3), m/s, estimated; scale = 1 / legged_gym's lin_vel 2.0",
    kernel.BASE_LINEAR_VELOCITY,
    vector=True,
    raw_entries=3,
    **_base,
)
_fixed(
    "base_angular_velocity",
    "base angular velocity (3), rad/s; scale = 1 / legged_gym's ang_vel 0.25",
    kernel.BASE_ANGULAR_VELOCITY,
    vector=True,
    raw_entries=3,
    **_base,
)
_fixed(
    "projected_gravity",
    "gravity's direction in the base frame (3), unit vector; unscaled",
    kernel.PROJECTED_GRAVITY,
    vector=True,
    raw_entries=3,
    **_base,
)
_fixed(
    "velocity_command",
    "velocity command (3): vx, vy m/s, yaw rate rad/s; scaled like the velocities it commands",
    kernel.VELOCITY_COMMAND,
    vector=True,
    raw_entries=3,
    **_base,
)
_fixed(
    "gait_phase",
    "sin p, cos p (2) of p = 2 pi t / period, t the runtime's clock, s; unscaled; components "
    "pick from sin p, cos p, sin(p + pi), cos(p + pi) (a second foot half a period later); "
    "a clock that stops (stand_below) holds every foot at stand_phase while standing",
    kernel.GAIT_PHASE,
    size=2,
    periodic=True,
    raw_entries=4,
    **_base,
)
_fixed(
    "foot_contact",
    "foot contact (one per foot), 0 or 1; unscaled",
    kernel.FOOT_CONTACT,
    size=4,
    per_foot=True,
    **_base,
)
_fixed(
    "heading_sincos",
    "sin, cos (2) of the yaw the attitude filter has turned since the start; unscaled",
    kernel.HEADING_SINCOS,
    size=2,
    **_base,
)
_fixed(
    "base_euler_angles",
    "roll, pitch, yaw (3) of the base, rad, yaw the attitude filter's since the start (humanoid-gym's "
    "base_euler_xyz, each in [-pi, pi]); unscaled",
    kernel.BASE_EULER_ANGLES,
    vector=True,
    raw_entries=3,
    **_base,
)
# A whole-body motion-tracking policy's (rl_sar's whole_body_tracking terms): the reference clip
# the motion task writes into RobotState.motion; numpy only (motion_blocks.NUMPY_REASON).
register_kind(
    ObservationKind(
        "motion_command",
        "the clip's joint angles (k), rad, then velocities (k), rad/s, at the motion clock's time; "
        "unscaled",
        motion_blocks.motion_command,
        None,
        per_joint=2,
        needs_base=True,
        numpy_only=motion_blocks.NUMPY_REASON,
    )
)
register_kind(
    ObservationKind(
        "motion_anchor_ori_b",
        "the anchor's (torso's) orientation error against the yaw-aligned clip's, first two "
        "columns of its rotation matrix row by row (6); joints: the waist's yaw, roll, pitch",
        motion_blocks.motion_anchor_ori_b,
        None,
        size=6,
        needs_base=True,
        numpy_only=motion_blocks.NUMPY_REASON,
    )
)
register_kind(
    ObservationKind(
        "motion_phase",
        "t / T (1): t the time since the motion started (the runtime's motion clock), s, T the "
        "block's period (the motion's length), s; unscaled, not clamped",
        motion_blocks.motion_phase,
        None,
        size=1,
        periodic=True,
        needs_base=True,
        numpy_only=motion_blocks.PHASE_REASON,
    )
)
_scan_reason = (
    "the terrain heights are an input the compiled kernel does not take; the plan runs the numpy "
    "writers (the same arithmetic)"
)
register_kind(
    ObservationKind(
        "height_scan",
        "the sensor's height above the terrain at each point of the block's scan (one per point), "
        "m; offset 0.5, scale 0.2, clip 5 as legged_gym's measured_heights "
        "(sim2real.deploy.spec.height_scan)",
        height_scan.height_scan,
        None,
        size=len(height_scan.LEGGED_GYM_X) * len(height_scan.LEGGED_GYM_Y),
        scan=True,
        numpy_only=_scan_reason,
        **_base,
    )
)
