"""A :class:`~sim2real.deploy.spec.foreign.contract.ForeignContract` onto a robot: the PolicySpec.

:func:`to_spec` maps the policy's joints onto the robot's by name, its observation terms onto our
blocks, its scales (multipliers) onto our divisors, its action scale and default pose onto the
action mapping, and its PD gains and default pose onto the spec's
:class:`~sim2real.deploy.spec.drive.DriveSpec`, all in the robot's joint order. The graph's outputs stay in
the policy's order: the spec's ``action.joints`` says which joint each drives. Terms that read past
ticks (a ``history_length``) give the spec its per-term history (:func:`term_history`).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.spec.drive import DriveSpec
from sim2real.deploy.spec.foreign.contract import JOINT_KINDS, ForeignContract, Term, per_joint
from sim2real.deploy.spec.history import ObservationHistory, stacked_dim
from sim2real.deploy.spec.policy_spec import UNCLIPPED, ActionSpec, ObservationBlock, PolicySpec
from sim2real.robots import Robot


def breadth_first_order(robot: Robot) -> tuple[str, ...]:
    """The robot's joints breadth first over its kinematic tree, siblings in description order:
    the order of a PhysX articulation (Isaac Sim, Isaac Lab), e.g. a quadruped's four hips, then
    its four thighs, then its four calves."""
    model = robot.pin_model
    depth = [0] * model.njoints
    for j in range(1, model.njoints):
        depth[j] = depth[model.parents[j]] + 1
    first = 1 + model.njoints - 1 - robot.n_joints  # after the universe and a free flyer
    ids = range(first, model.njoints)
    return tuple(model.names[j] for j in sorted(ids, key=lambda j: depth[j]))


#: Names other stacks give a joint of the same description: ``(their suffix, the
#: description's)``, tried only when a contract's name is no joint of the robot. rl_sar's Go2-W
#: (``policy/go2w/base.yaml`` ``joint_names``) calls its wheels ``<LEG>_foot_joint`` where
#: unitree_mujoco's ``unitree_robots/go2w/go2w.xml`` and go2w_description say ``<LEG>_wheel_joint``.
JOINT_NAME_ALIASES = (("_foot_joint", "_wheel_joint"),)


def robot_joint_named(name: str, robot_names: tuple[str, ...]) -> str | None:
    """The robot joint a contract's joint ``name`` is: the same name, else a known alias
    (:data:`JOINT_NAME_ALIASES`); None: neither is a joint of the robot."""
    if name in robot_names:
        return name
    for theirs, ours in JOINT_NAME_ALIASES:
        if name.endswith(theirs) and (alias := name[: -len(theirs)] + ours) in robot_names:
            return alias
    return None


def slot_order(
    contract: ForeignContract,
    robot_names: tuple[str, ...],
    slots: list[int] | None,
    robot: str,
) -> tuple[str, ...]:
    """The policy's joints, as joints of the robot, of a contract whose joint map is motor slots
    (``joint_slots``: the slot of each policy joint, rl_sar's ``joint_mapping``, Unitree's
    ``joint_ids_map``).

    The names decide where the contract has them (``slot_names``, rl_sar's ``joint_names``:
    policy joint ``i`` is ``slot_names[joint_slots[i]]``, as rl_sar's Gazebo loop reads
    ``joint_controller_names[joint_mapping[i]]``), each matched to a robot joint by name or a
    known alias; where the robot has motor slots too, both must give the same joints. Without
    names, the robot's motor slots give the order. Nothing falls back to the robot's joint order.

    Args:
        contract: The foreign contract (``joint_slots`` set).
        robot_names: The robot's joints, in its order.
        slots: The motor slot of each robot joint (robot.toml ``[unitree] motor_index``, or
            what ``robot-import --unitree`` numbers); None: the robot has none.
        robot: The robot's name or description, for the messages.

    Raises:
        ForeignFormatError: a name that is no joint of the robot, a slot no joint's of the
            robot, names and slots that give different joints (both orders
            named), or neither names nor slots (what to add named).
    """
    wanted = contract.joint_slots or ()
    by_name = None
    if contract.slot_names is not None:
        theirs = [contract.slot_names[s] for s in wanted]
        by_name = tuple(robot_joint_named(n, robot_names) for n in theirs)
        unknown = [n for n, r in zip(theirs, by_name, strict=True) if r is None]
        if unknown:
            raise contract.error(
                f"joints {unknown} of its joint names are no joints of '{robot}' (known "
                f"aliases: {', '.join(f'*{a} = *{b}' for a, b in JOINT_NAME_ALIASES)}); its "
                f"joints: {list(robot_names)}"
            )
    by_slot = None
    if slots is not None:
        missing = [s for s in wanted if s not in slots]
        if missing:
            raise contract.error(
                f"motor slots {missing} of its joint map are no joint's of '{robot}' (its "
                f"slots, in joint order: {slots})"
            )
        by_slot = tuple(robot_names[slots.index(s)] for s in wanted)
    if by_name is not None and by_slot is not None and by_name != by_slot:
        raise contract.error(
            f"its joint names and the robot's motor slots disagree: by name the policy's "
            f"joints are {list(by_name)}, by '{robot}''s motor slots {list(by_slot)}; mend "
            "the contract's joint_names or the robot's [unitree] motor_index"
        )
    if by_name is None and by_slot is None:
        raise contract.error(
            f"its joint map is motor slots {list(wanted)} and it names no joints, but "
            f"'{robot}' has no motor slots: import it with robot-import --unitree FAMILY "
            "(robot.toml [unitree] motor_index) so the slots name its joints"
        )
    return by_name if by_name is not None else by_slot


def motor_slot_order(robot: Robot, contract: ForeignContract) -> tuple[str, ...]:
    """The robot's joints in the policy's order for a contract with motor slots
    (:func:`slot_order`: the contract's joint names, checked against robot.toml's ``[unitree]
    motor_index`` where the robot has one).

    Raises:
        ForeignFormatError: as :func:`slot_order`.
    """
    unitree = getattr(robot.config, "unitree", None)
    slots = list(unitree.motor_index) if unitree is not None else None
    return slot_order(contract, robot.joint_names, slots, robot.name)


#: Rules giving a policy's joint order from the robot when its stack records no joint names.
JOINT_ORDER_RULES = {
    "breadth_first": lambda robot, contract: breadth_first_order(robot),
    "motor_slots": motor_slot_order,
}


def policy_joint_names(contract: ForeignContract, robot: Robot) -> tuple[str, ...]:
    """The policy's joint order: recorded, or the contract's rule applied to ``robot``."""
    if contract.joint_names is not None:
        return contract.joint_names
    return JOINT_ORDER_RULES[contract.joint_order_rule](robot, contract)


def joint_permutation(contract: ForeignContract, robot: Robot) -> tuple[int, ...]:
    """For each policy joint, in the policy's order, the index of the robot joint of that name.

    Raises:
        ForeignFormatError: policy joints the robot does not have, or robot joints the policy
            does not drive (both named).
    """
    names = policy_joint_names(contract, robot)
    robot_names = robot.joint_names
    missing = [n for n in names if n not in robot_names]
    undriven = [n for n in robot_names if n not in names]
    if missing or len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise contract.error(
            f"joints {missing or dup} {'are not joints of' if missing else 'repeat in'} the "
            f"robot '{robot.name}' (its joints: {list(robot_names)})"
        )
    if undriven:
        raise contract.error(
            f"the robot '{robot.name}' has joints the policy does not drive: {undriven}"
        )
    return tuple(robot_names.index(n) for n in names)


def _entries(term: Term, value, size: int, contract: ForeignContract) -> np.ndarray:
    """A term's multiplier, one per entry (one number: the same for every entry)."""
    v = np.asarray(value, dtype=float)
    if v.ndim == 0:
        return np.full(size, float(v))
    if v.shape != (size,):
        raise contract.error(
            f"observation term '{term.name}': {v.size} scale entries, the term has {size}"
        )
    return v


def _blocks(
    term: Term, contract: ForeignContract, perm: tuple[int, ...], default: tuple[float, ...]
) -> tuple[ObservationBlock, ...]:
    """Our block for one mappable term, or, for a joint position term with ``zero_joints``, one
    block per run of read and zeroed entries (``joint_position_zero`` for the zeroed)."""
    block = _block(term, contract, perm, default)
    if not term.zero_joints:
        return (block,)
    zero = set(term.zero_joints)
    runs: list[list[int]] = []
    for i in range(block.size):
        if runs and (i in zero) == (runs[-1][0] in zero):
            runs[-1].append(i)
        else:
            runs.append([i])
    return tuple(
        ObservationBlock(
            name="joint_position_zero" if run[0] in zero else block.name,
            size=len(run),
            scale=tuple(1.0 if run[0] in zero else block.scale[i] for i in run),
            offset=tuple(0.0 if run[0] in zero else block.offset[i] for i in run),
            clip=block.clip,
            joints=tuple(block.joints[i] for i in run),
        )
        for run in runs
    )


def _block(
    term: Term, contract: ForeignContract, perm: tuple[int, ...], default: tuple[float, ...]
) -> ObservationBlock:
    """Our block for one mappable term (``obs = (raw - offset) * s`` is ``scale = 1 / s``)."""
    size = contract.term_size(term)
    s = _entries(term, term.scale, size, contract)
    if not (np.all(np.isfinite(s)) and np.all(s > 0)):
        raise contract.error(
            f"observation term '{term.name}': scale {s.tolist()} cannot be mapped (a block's "
            "divisor must be finite and positive)"
        )
    offset = np.full(size, float(term.offset))
    joints: tuple[int, ...] = ()
    if term.kind in JOINT_KINDS:
        joints = perm
        if term.kind == "joint_position" and term.relative:
            offset = np.asarray(default, dtype=float)
    elif term.joints:
        joints = tuple(perm[i] for i in term.joints)
    return ObservationBlock(
        name=term.kind,
        size=size,
        scale=tuple(float(x) for x in 1.0 / s),
        offset=tuple(float(x) for x in offset),
        clip=UNCLIPPED if term.clip is None else float(term.clip),
        joints=joints,
        period=term.period,
        components=term.components,
        stand_below=term.stand_below,
        stand_phase=term.stand_phase,
        scan=term.scan,
    )


def term_history(contract: ForeignContract) -> ObservationHistory | None:
    """The spec's history of a contract whose terms read past ticks: each term's ticks in turn,
    the oldest first (Isaac Lab's ``CircularBuffer.buffer`` flattened, as mjlab, holosoma and
    Unitree's deployment lay them out), filled as the contract says; None: no term does."""
    if contract.history_layout == "per_frame":
        if contract.history_length <= 1:
            return None
        return ObservationHistory(
            length=contract.history_length,
            order=contract.history_order,
            layout="per_frame",
            fill=contract.history_fill,
        )
    ticks = tuple(max(1, t.history) for t in contract.terms)
    if max(ticks, default=1) == 1:
        return None
    if any(t.zero_joints for t in contract.terms):
        raise contract.error(
            "a per-term history of a joint position term with zeroed joints is not mapped "
            "(its term becomes several blocks)"
        )
    uniform = len(set(ticks)) == 1
    return ObservationHistory(
        length=max(ticks),
        order=contract.history_order,
        layout="per_term",
        fill=contract.history_fill,
        lengths=() if uniform else ticks,
    )


def _observation(contract: ForeignContract, perm, default) -> tuple[tuple, object]:
    """The observation blocks of every term, in the graph's order, and the history.

    Raises:
        ForeignFormatError: a term that cannot be mapped (named), or terms whose sizes do not
            add up to the graph's input.
    """
    fail = contract.error
    for term in contract.terms:
        if term.kind is None:
            raise fail(
                f"observation term '{term.name}' cannot be mapped onto an observation block of "
                f"this toolkit: {term.reason}"
            )
    blocks = tuple(b for t in contract.terms for b in _blocks(t, contract, perm, default))
    history = term_history(contract)
    total = stacked_dim(history, tuple(b.size for b in blocks))
    if contract.obs_dim is not None and total != contract.obs_dim:
        parts = " + ".join(
            f"{t.name} {contract.term_size(t)}" + (f" x {t.history}" if t.history > 1 else "")
            for t in contract.terms
        )
        raise fail(
            f"the observation terms add up to {total} entries ({parts}), the graph's input has "
            f"{contract.obs_dim}"
        )
    return blocks, history


def to_spec(contract: ForeignContract, robot: Robot) -> PolicySpec:
    """The PolicySpec of a foreign policy on ``robot``: blocks in the graph's order, the action
    mapping (position, absolute: ``target = offset + scale * action``; a velocity joint's
    target ``scale * action``, rad/s, its drive kind ``velocity``) and the drive in the
    robot's joint order, ``action.joints`` the robot joint of each graph output. Not recorded:
    the default pose is the robot's home, the gains the robot's, the control rate the robot's
    (each listed in ``contract.missing``).

    Raises:
        ForeignFormatError: no observation terms recorded (naming what the contract lacks), a
            term that cannot be mapped (naming it and the format), joints that
            do not match the robot, terms whose sizes do not add up to the graph's input, an
            invalid scale.
    """
    if not contract.terms:
        raise contract.error(
            "its observation terms are not recorded, so no spec can be built from it: "
            + ("; ".join(contract.missing) or "the contract names none")
        )
    perm = joint_permutation(contract, robot)
    names = policy_joint_names(contract, robot)
    n = len(names)
    home = tuple(float(robot.home[i]) for i in perm)
    fail = contract.error
    default = per_joint(contract.default_pose, names, "default joint pose", fail) or home
    blocks, history = _observation(contract, perm, default)
    if contract.act_dim is not None and contract.act_dim != n:
        raise fail(f"the graph has {contract.act_dim} actions, the policy {n} joints")
    scale = per_joint(contract.action_scale, names, "action scale", fail)
    if scale is None:
        raise fail("the action scale is not recorded")
    offset = per_joint(contract.action_offset, names, "action offset", fail) or default
    speed = set(contract.velocity_joints)
    offset = tuple(0.0 if i in speed else v for i, v in enumerate(offset))  # a speed about 0
    kinds = tuple("velocity" if i in speed else "position" for i in range(n)) if speed else ()
    kp = per_joint(contract.kp, names, "kp", fail)
    kd = per_joint(contract.kd, names, "kd", fail)
    to_robot = np.argsort(perm)  # robot joint i is policy joint to_robot[i]

    def robot_order(values):
        return () if values is None else tuple(float(values[k]) for k in to_robot)

    spec = PolicySpec(
        robot=robot.name,
        joint_names=robot.joint_names,
        robot_hash="",
        observation_blocks=blocks,
        action=ActionSpec(
            mode="position",
            size=n,
            scale=robot_order(scale),
            offset=robot_order(offset),
            clip=UNCLIPPED if contract.action_clip is None else float(contract.action_clip),
            reference="absolute",
            joints=() if perm == tuple(range(n)) else perm,
        ),
        control_rate=contract.control_rate or 1.0 / robot.control_period,
        drive=DriveSpec(
            kp=robot_order(kp),
            kd=robot_order(kd),
            default_pose=robot_order(default),
            kinds=tuple(kinds[k] for k in to_robot) if kinds else (),
        ),
        history=history,
        constant_inputs=dict(contract.constant_inputs or {}),
    )
    try:
        spec.validate()
    except Exception as exc:  # noqa: BLE001 - SpecError: named for the format
        raise fail(f"the spec built from its contract is invalid: {exc}") from None
    return spec
