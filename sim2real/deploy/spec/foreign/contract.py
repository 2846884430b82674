"""What a training stack records about its policy, in its own words (:class:`ForeignContract`).

A format reader (:mod:`sim2real.deploy.spec.foreign.mjlab`, ``holosoma``, ``isaaclab``) fills one from an
ONNX file's metadata (or the run folder beside it); :mod:`sim2real.deploy.spec.foreign.mapping` turns it
into a :class:`~sim2real.deploy.spec.policy_spec.PolicySpec` for a robot. Quantities stay in the stack's
convention here: an observation term is ``obs = (raw - offset) * scale`` with ``scale`` a
multiplier (legged_gym, Isaac Lab, mjlab and holosoma all multiply), a per-joint quantity is
in the policy's joint order, a regular-expression table, or one number for every joint.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from sim2real.deploy.spec.policy_spec import SpecError


def positive_number(value, kind) -> bool:
    """Whether ``value`` is a number of ``kind`` (``(int, float)`` or ``(int,)``), finite and above
    0, not a bool: a control rate's factors (``dt``, ``fps``, a decimation), whose product or ratio
    a reader divides by."""
    import math

    return (
        not isinstance(value, bool)
        and isinstance(value, kind)
        and math.isfinite(value)
        and value > 0
    )


#: A per-joint quantity: one number for every joint, one per joint in the policy's joint order, or
#: a table of regular expressions (matched whole, as Isaac Lab's ``resolve_matching_names_values``
#: matches them) to values.
PerJoint = float | tuple[float, ...] | dict[str, float]

#: Our blocks that read one entry per joint, in the policy's joint order.
JOINT_KINDS = ("joint_position", "joint_velocity", "last_action", "motion_command")


class ForeignFormatError(SpecError):
    """A training stack's contract cannot be read or mapped; the message starts with the file and
    names the format and the key, term or joint."""


@dataclass(frozen=True)
class Term:
    """One observation term of a foreign policy.

    Attributes:
        name: The stack's name of the term (``base_lin_vel``, ``dof_pos``, ...).
        kind: Our observation block kind it maps onto; None: it cannot be mapped (``reason``).
        size: Entries it contributes (per-joint terms: -1, one per joint).
        scale: The stack's multiplier: one number, or one per entry.
        clip: Symmetric clip of the scaled value (``|obs| <= clip``); None: unclipped.
        components: Vector kinds: the entries of the 3-vector read (empty: all three).
        relative: ``joint_position`` only: relative to the default pose (else absolute).
        reason: Why ``kind`` is None, in one phrase.
        source: Where the stack computes it (a function path), for the report; may be empty.
        period: ``gait_phase`` only: the gait clock's period, s.
        stand_below, stand_phase: ``gait_phase`` only: the command (m/s, rad/s) below which the
            clock stands, every foot held at ``stand_phase`` (rad); 0: it never stops
            (:class:`~sim2real.deploy.spec.policy_spec.ObservationBlock`).
        history: Ticks of history the graph reads of it, the present one included (0 or 1:
            the present only), each tick's entries in turn, the oldest first.
        zero_joints: ``joint_position`` only: the policy joints (indices in its order) whose
            entry reads 0 (rl_sar's ``wheel_indices``: a wheel's angle is never observed).
        joints: A fixed-size term that reads some joints (``motion_anchor_ori_b``: the waist's
            yaw, roll, pitch): the policy joints (indices in its order) it reads, in order.
        offset: Subtracted from the raw value before scaling (``height_scan``'s 0.5 m); 0: none.
        scan: ``height_scan`` only: its pattern
            (:class:`~sim2real.deploy.spec.height_scan.HeightScanPattern`); None otherwise.
    """

    name: str
    kind: str | None
    size: int
    scale: float | tuple[float, ...] = 1.0
    clip: float | None = None
    components: tuple[int, ...] = ()
    relative: bool = True
    reason: str = ""
    source: str = ""
    period: float = 0.0
    stand_below: float = 0.0
    stand_phase: float = 0.0
    history: int = 0
    zero_joints: tuple[int, ...] = ()
    joints: tuple[int, ...] = ()
    offset: float = 0.0
    scan: object = None


@dataclass(frozen=True)
class MotionSource:
    """The reference clip a motion-tracking contract names (rl_sar's ``motion_file``).

    Attributes:
        file: The clip's path (beside the policy, as the stack finds it).
        fps: The rate the stack plays its frames at, Hz (rl_sar: the control rate
            ``1 / (dt x decimation)``, its fsm's ``MotionLoader(motion_file, fps)``).
        columns: The joint of each joint column of the clip, by the contract's names (rl_sar's
            CSV: the SDK's motor order, ``joint_names``).
        timing: The stack's rule from time to frame (``rl_sar``:
            :class:`sim2real.deploy.tasks.motion.clock.MotionClock`; ``holosoma_onnx``: the
            clip baked in the ONNX ``file``, :mod:`sim2real.deploy.tasks.motion.onnx_holosoma`).
        note: Where each came from, one line for the report.
    """

    file: str
    fps: float
    columns: tuple[str, ...]
    timing: str = "rl_sar"
    note: str = ""


@dataclass(frozen=True)
class ForeignContract:
    """A foreign policy's contract as its training stack recorded it.

    Attributes:
        format: The stack (``"mjlab"``, ``"holosoma"``, ``"isaaclab"``).
        source: What was read (``"ONNX metadata"`` or the run file's path).
        path: The ONNX file.
        obs_dim, act_dim: The graph's observation and action sizes (None: not fixed).
        joint_names: The policy's joint order; None: not recorded (``joint_order_note`` says
            what is assumed instead).
        terms: Observation terms, in the order the graph reads them.
        default_pose: Default joint positions, rad (:data:`PerJoint`); None: not recorded.
        action_scale: Action multiplier per joint (:data:`PerJoint`): ``target = default +
            scale * action``; None: not recorded.
        action_offset: Action offset per joint, rad, when it is not the default pose; None: the
            default pose.
        action_clip: Symmetric clip of the raw action; None: unclipped.
        kp, kd: PD gains, N m/rad and N m s/rad (:data:`PerJoint`); None: not recorded.
        control_rate: Hz; None: not recorded.
        found: ``(key, value summary)`` of what was read, for the report.
        missing: What the contract lacks and what stands in for it, one line each.
        notes: Assumptions the reader made, one line each.
        joint_order_note: How the joint order is found when it is not recorded.
        joint_order_rule: A rule of :mod:`sim2real.deploy.spec.foreign.mapping` (``JOINT_ORDER_RULES``)
            that gives the joint order from the robot when ``joint_names`` is None.
        joint_slots: The motor slot of each policy joint, in the policy's order (rule
            ``motor_slots``); None: not recorded.
        slot_names: The joint name of each motor slot, in the slots' order (rl_sar's
            ``joint_names``: policy joint ``i`` is ``slot_names[joint_slots[i]]``; a reader
            refuses names that do not cover every slot); None: the contract names no joints.
            Where given, the names decide the joint order
            (:func:`sim2real.deploy.spec.foreign.mapping.slot_order`).
        command_ranges: The velocity command's training ranges, ``{"vx": (low, high), "vy":
            ..., "yaw_rate": ...}`` (m/s, m/s, rad/s); None: not recorded.
        history_fill: What a term's history reads before the policy's reset
            (:data:`sim2real.deploy.spec.history.FILLS`): ``first`` (Isaac Lab's
            ``CircularBuffer`` fills itself with its first entry) or ``zeros`` (holosoma).
        history_order: ``oldest_first`` or ``newest_first`` (:data:`sim2real.deploy.spec.history.ORDERS`).
        history_layout: ``per_term`` (each term's ticks in turn) or ``per_frame``.
        history_length: Ticks of a ``per_frame`` history (0: the terms' ``history`` say).
        velocity_joints: The policy joints (indices in its order) whose action is a speed target
            (rad/s, ``scale * action``, kp 0: a wheel); the others take position targets.
        motion: The reference clip of a motion-tracking policy (:class:`MotionSource`); None.
        constant_inputs: Graph inputs besides the observation fed a constant every tick (name
            -> value; holosoma WBT's ``time_step``, which feeds only the baked clip's outputs).
    """

    format: str
    source: str
    path: str
    obs_dim: int | None
    act_dim: int | None
    joint_names: tuple[str, ...] | None
    terms: tuple[Term, ...]
    default_pose: PerJoint | None = None
    action_scale: PerJoint | None = None
    action_offset: PerJoint | None = None
    action_clip: float | None = None
    kp: PerJoint | None = None
    kd: PerJoint | None = None
    control_rate: float | None = None
    found: tuple[tuple[str, str], ...] = ()
    missing: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    joint_order_note: str = ""
    joint_order_rule: str = ""
    joint_slots: tuple[int, ...] | None = None
    slot_names: tuple[str, ...] | None = None
    command_ranges: dict[str, tuple[float, float]] | None = None
    history_fill: str = "first"
    history_order: str = "oldest_first"
    history_layout: str = "per_term"
    history_length: int = 0
    velocity_joints: tuple[int, ...] = ()
    motion: MotionSource | None = None
    constant_inputs: dict[str, float] | None = None

    @property
    def n_joints(self) -> int | None:
        """Joints the policy drives: its joint names, else the graph's action size."""
        return len(self.joint_names) if self.joint_names is not None else self.act_dim

    def term_size(self, term: Term) -> int | None:
        """Entries of ``term`` (per-joint terms: :attr:`n_joints`; None: unknown)."""
        return self.n_joints if term.size < 0 else term.size

    def error(self, message: str) -> ForeignFormatError:
        """A :class:`ForeignFormatError` ``"<path>: <format> policy: <message>"``."""
        return ForeignFormatError(f"{self.path}: {self.format} policy: {message}")

    def base_velocity_terms(self) -> list[str]:
        """Names of the terms that read the base's linear velocity."""
        return [t.name for t in self.terms if t.kind == "base_linear_velocity"]


def per_joint(
    value: PerJoint | None,
    names: tuple[str, ...],
    what: str,
    fail,
    default: float | None = None,
) -> tuple[float, ...] | None:
    """A :data:`PerJoint` quantity as one float per joint of ``names`` (None stays None).

    Args:
        value: The quantity. names: The policy's joint order. what: Its name, for messages.
        fail: ``fail(message) -> Exception`` (the contract's :meth:`ForeignContract.error`).
        default: For a regular-expression table: the value of a joint no expression matches
            (None: such a joint is an error).

    Raises:
        ForeignFormatError (through ``fail``): a per-joint tuple of the wrong length, a joint no
            expression matches (without ``default``), a joint two expressions give different
            values, an expression that is not a regular expression.
    """
    if value is None:
        return None
    if isinstance(value, int | float):
        return (float(value),) * len(names)
    if isinstance(value, tuple):
        if len(value) != len(names):
            raise fail(f"{what}: {len(value)} entries, the policy has {len(names)} joints")
        return tuple(float(v) for v in value)
    out, unmatched = [], []
    for name in names:
        hits = set()
        for pattern, v in value.items():
            try:
                if re.fullmatch(pattern, name):
                    hits.add(float(v))
            except re.error as exc:
                raise fail(f"{what}: '{pattern}' is not a regular expression ({exc})") from None
        if len(hits) > 1:
            raise fail(f"{what}: joint '{name}' matches expressions of different values {hits}")
        if not hits and default is None:
            unmatched.append(name)
        out.append(hits.pop() if hits else float(default or 0.0))
    if unmatched:
        raise fail(f"{what}: no expression of {list(value)} matches the joints {unmatched}")
    return tuple(out)


#: Our names of a velocity command's ranges and the names training stacks give them
#: (Isaac Lab / mjlab ``lin_vel_x``, ``lin_vel_y``, ``ang_vel_z``; holosoma ``ang_vel_yaw``).
COMMAND_RANGE_NAMES = {
    "vx": ("lin_vel_x",),
    "vy": ("lin_vel_y",),
    "yaw_rate": ("ang_vel_z", "ang_vel_yaw"),
}


def command_ranges(table) -> dict[str, tuple[float, float]] | None:
    """A stack's velocity-command ranges table as :attr:`ForeignContract.command_ranges`; None
    when ``table`` is not a mapping holding all three as ``[low, high]`` numbers."""
    if not isinstance(table, dict):
        return None
    out = {}
    for ours, theirs in COMMAND_RANGE_NAMES.items():
        value = next((table[k] for k in theirs if k in table), None)
        if not (isinstance(value, list | tuple) and len(value) == 2):
            return None
        try:
            low, high = float(value[0]), float(value[1])
        except (TypeError, ValueError):
            return None
        if not low <= high:
            return None
        out[ours] = (low, high)
    return out


#: Isaac Lab's observation functions (``isaaclab.envs.mdp.observations``) that Unitree's C++
#: deployment also registers, under the same names -> (our kind, size (-1: one per joint),
#: relative to the default pose). ``joint_pos`` reads absolute positions.
ISAACLAB_TERMS = {
    "base_lin_vel": ("base_linear_velocity", 3, True),
    "base_ang_vel": ("base_angular_velocity", 3, True),
    "projected_gravity": ("projected_gravity", 3, True),
    "joint_pos_rel": ("joint_position", -1, True),
    "joint_pos": ("joint_position", -1, False),
    "joint_vel_rel": ("joint_velocity", -1, True),
    "last_action": ("last_action", -1, True),
}


def clip_before_scaling(lo: float, hi: float, scale: float | tuple[float, ...]):
    """Our clip of a term that its stack clips to ``[lo, hi]`` before scaling by ``scale``:
    ``(hi * |scale|, "")``, or ``(None, why)`` when one symmetric clip of the scaled value cannot
    say it (an asymmetric clip, or per-entry scales)."""
    if lo != -hi or not hi > 0:
        return None, f"an asymmetric clip [{lo:g}, {hi:g}] (blocks clip symmetrically)"
    if not isinstance(scale, float):
        return None, "a clip with per-entry scales (a block's clip is one number)"
    return hi * abs(scale), ""
