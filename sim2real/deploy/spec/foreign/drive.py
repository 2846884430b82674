"""A foreign policy's drive for a robot that is not imported yet: its PD gains, default pose and
control rate, per joint of a description (``robot-import --drive-from POLICY``).

``deploy-run`` runs a policy with the gains and default pose its contract records
(:mod:`sim2real.deploy.spec.drive`), whatever robot.toml says; but the importer derives more from the
gains than the plant's servos: a legged robot's PD-target limits (``--target-limits pd``:
``2 x effort / kp / control_period``) and the home pose the bring-up ramps to. Importing with the
policy's drive writes those from the gains the policy was trained with, instead of the
importer's stiff rule (590 N m/rad on a G1 hip whose policy uses 40.2). :func:`policy_drive`
reads the contract as ``deploy-run`` does (:mod:`sim2real.deploy.spec.foreign.registry`) and resolves
each per-joint quantity onto the description's joints: by the policy's joint names, by its motor
slots (Unitree's deploy.yaml ``joint_ids_map``, rl_sar's ``joint_mapping``: the slots
``robot-import --unitree`` numbers, ``unitree_go`` from the joint names, ``unitree_hg`` in the
description's joint order; rl_sar's ``joint_names`` decide where it has them,
:func:`sim2real.deploy.spec.foreign.mapping.slot_order`), or, for Isaac Lab, by regular
expression (a per-joint list in the articulation's breadth-first order).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from sim2real.deploy.spec.foreign.contract import ForeignContract, ForeignFormatError, per_joint
from sim2real.deploy.spec.foreign.mapping import slot_order
from sim2real.deploy.spec.foreign.registry import (
    OnnxFacts,
    known_formats,
    read_contract,
    read_folder_contract,
)


@dataclass(frozen=True)
class PolicyDrive:
    """What a foreign policy's contract says about the drive, per joint of a description.

    Attributes:
        kp, kd: N m/rad and N m s/rad, one per joint in the description's order; None: not
            recorded.
        home: The default pose, rad, one per joint; None: not recorded.
        control_rate: Hz; None: not recorded.
        source: What was read, for the import's notes (``"unitree_deploy contract .../
            deploy.yaml"``).
        missing: What the contract lacks, one line each (its ``missing``).
    """

    kp: tuple[float, ...] | None
    kd: tuple[float, ...] | None
    home: tuple[float, ...] | None
    control_rate: float | None
    source: str
    missing: tuple[str, ...] = ()


def read_policy_contract(path: str | Path) -> ForeignContract:
    """The foreign contract of the ONNX file at ``path`` (external weights are not read), or of a
    file that is not ONNX (rl_sar's TorchScript ``policy.pt``) in a folder whose contract files
    say the drive without a graph (:func:`~sim2real.deploy.spec.foreign.registry.read_folder_contract`).

    Raises:
        ForeignFormatError: the file is missing or not an ONNX model (the message of
            :func:`sim2real.deploy.spec.onnx_checks.read_model`), no format recognises it
            (naming the formats), or its contract cannot be read (naming the file, format, key).
    """
    from sim2real.deploy.spec.onnx_checks import PolicyLoadError, read_model

    path = Path(path)
    try:
        model = read_model(path)
    except PolicyLoadError as exc:  # missing, empty, a torch file, not ONNX
        contract = read_folder_contract(path) if _torch_file(path) else None
        if contract is None:
            raise ForeignFormatError(str(exc)) from None
        return contract  # a torch file in a folder whose contract is read (rl_sar's policy.pt)
    contract = read_contract(OnnxFacts.of(path, model))
    if contract is None:
        raise ForeignFormatError(
            f"{path}: no training stack's contract found (metadata or a contract file beside it; "
            f"formats read: {known_formats()})"
        )
    return contract


def _torch_file(path: Path) -> bool:
    """A zip archive or a pickle (a torch file: TorchScript, a checkpoint), not a broken ONNX."""
    try:
        with open(path, "rb") as f:
            head = f.read(4)
    except OSError:
        return False
    return head.startswith(b"PK\x03\x04") or head[:1] == b"\x80"


def policy_drive(
    path: str | Path,
    joints: Sequence[str],
    depth: Sequence[int],
    slots: Sequence[int] | None = None,
) -> PolicyDrive:
    """The drive the policy at ``path`` records, per joint of a description.

    Args:
        path: The policy's ONNX file.
        joints: The description's joints, in its order.
        depth: Each joint's depth in the kinematic tree (1 for a joint of the root's child), for
            a contract in the breadth-first order of a PhysX articulation.
        slots: The motor slot of each joint (``robot-import --unitree``); None: the
            description has none (a contract in motor slots must then name its joints).

    Raises:
        ForeignFormatError: the contract cannot be read, or its joints are not the
            description's (naming the joints of each).
    """
    contract = read_policy_contract(path)
    names = tuple(joints)
    order = _policy_order(contract, names, depth, slots)

    def resolve(value, what: str) -> tuple[float, ...] | None:
        if value is None:
            return None
        if isinstance(value, tuple):
            if order is None:
                raise contract.error(
                    f"{what}: one value per joint, in an order the contract does not record"
                )
            by_name = dict(zip(order, per_joint(value, order, what, contract.error), strict=True))
            return tuple(by_name[n] for n in names)
        return per_joint(value, names, what, contract.error)

    return PolicyDrive(
        kp=resolve(contract.kp, "stiffness"),
        kd=resolve(contract.kd, "damping"),
        home=resolve(contract.default_pose, "default joint positions"),
        control_rate=contract.control_rate,
        source=f"{contract.format} contract ({contract.source})",
        missing=contract.missing,
    )


def _policy_order(
    contract: ForeignContract,
    names: tuple[str, ...],
    depth: Sequence[int],
    slots: Sequence[int] | None,
) -> tuple[str, ...] | None:
    """The policy's joint order as joints of the description (None: not recorded and no rule)."""
    if contract.joint_names is not None:
        order = contract.joint_names
    elif contract.joint_order_rule == "motor_slots" and contract.joint_slots is not None:
        order = slot_order(
            contract, names, None if slots is None else list(slots), "the description"
        )
    elif contract.joint_order_rule == "breadth_first":
        order = tuple(n for _, n in sorted(zip(depth, names, strict=True), key=lambda x: x[0]))
    else:
        return None
    missing = [n for n in order if n not in names]
    undriven = [n for n in names if n not in order]
    if missing or undriven:
        raise contract.error(
            "its joints are not the description's: "
            + (f"{missing} are not joints of it" if missing else "")
            + ("; " if missing and undriven else "")
            + (f"it does not drive {undriven}" if undriven else "")
            + f" (the description's joints: {list(names)})"
        )
    return order
