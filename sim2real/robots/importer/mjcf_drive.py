"""What an MJCF says of its own drive, read before the importer drops its actuators and keyframes
(:func:`read_drive`), and the contact bits of a scene file's floor (:func:`floor_bits`).

- ``<position>`` actuators: MuJoCo's position servo is an actuator on a joint with a fixed gain
  ``kp`` and the affine bias ``-kp * length - kv * velocity`` (``gaintype="fixed"``,
  ``biastype="affine"``, ``biasprm = (0, -kp, -kv)``), whatever wrote it (``<position kp kv>``,
  ``dampratio``, default classes, ``<general>``): read from the compiled model, so classes and
  ``dampratio`` (MuJoCo turns it into ``kv`` at compile time, with the file's own inertias and
  armature) are resolved. Through a gear ``g`` the joint sees ``g^2 kp`` and ``g^2 kv``. Its
  ``ctrlrange`` (``inheritrange``: the joint's range) is the range the training simulator clamped
  the targets into.
- ``<keyframe>``: the home pose is the key named by ``--keyframe``, else the key named ``home``,
  else the first key (MuJoCo fills a key's missing entries with the model's reference pose).

:mod:`sim2real.robots.importer.legged` uses them when neither a flag nor a policy's contract gives
a joint's gains or home pose, and prints where each value came from.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from sim2real.robots.importer.source import RobotImportError

#: The key taken for the home pose when ``--keyframe`` names none and the file has one so named.
HOME_KEY = "home"


@dataclass(frozen=True)
class SourceDrive:
    """An MJCF's own drive, per hinge joint name.

    Attributes:
        kp, kd: joint -> (N m/rad or N m s/rad, the element it came from).
        ctrlrange: joint -> (low, high) rad, the targets' range in the file's simulator.
        home: joint -> rad, the keyframe's pose; empty without a keyframe.
        home_source: ``"MJCF <key name='home'>"``, or "" without a keyframe.
        keys: Every key's name, in file order.
        notes: What was read and what was not, one line each.
    """

    kp: dict[str, tuple[float, str]] = field(default_factory=dict)
    kd: dict[str, tuple[float, str]] = field(default_factory=dict)
    ctrlrange: dict[str, tuple[float, float]] = field(default_factory=dict)
    home: dict[str, float] = field(default_factory=dict)
    home_source: str = ""
    keys: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()


def _position_servo(model: mujoco.MjModel, a: int) -> tuple[float, float] | None:
    """(kp, kv) of actuator ``a`` when it is a position servo on a hinge, else None."""
    if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
        return None
    if model.jnt_type[model.actuator_trnid[a, 0]] != mujoco.mjtJoint.mjJNT_HINGE:
        return None
    if (
        model.actuator_gaintype[a] != mujoco.mjtGain.mjGAIN_FIXED
        or model.actuator_biastype[a] != mujoco.mjtBias.mjBIAS_AFFINE
    ):
        return None
    kp = float(model.actuator_gainprm[a, 0])
    bias = model.actuator_biasprm[a]
    if not kp > 0 or abs(float(bias[1]) + kp) > 1e-9 * kp or float(bias[0]) != 0.0:
        return None
    return kp, 0.0 - float(bias[2])  # 0.0 -: no kv reads 0.0, not -0.0


def read_drive(model: mujoco.MjModel, path: Path, keyframe: str | None = None) -> SourceDrive:
    """The drive of the compiled MJCF ``model`` read from ``path`` (module docstring).

    Args:
        model: The file compiled as it is (actuators and keyframes still in it).
        path: The file, for messages. keyframe: The key whose pose is home (None: ``home``,
            else the first key).

    Raises:
        RobotImportError: ``keyframe`` names no key of the file (naming its keys).
    """
    kp: dict[str, tuple[float, str]] = {}
    kd: dict[str, tuple[float, str]] = {}
    ctrl: dict[str, tuple[float, float]] = {}
    notes = []
    for a in range(model.nu):
        servo = _position_servo(model, a)
        if servo is None:
            continue
        joint = model.joint(model.actuator_trnid[a, 0]).name
        gear = float(model.actuator_gear[a, 0])
        name = model.actuator(a).name or f"#{a}"
        where = f"MJCF <position name='{name}'>"
        geared = f" x gear {gear:g}^2" if gear != 1.0 else ""
        kp[joint] = (gear**2 * servo[0], f"{where} kp{geared}")
        kd[joint] = (gear**2 * servo[1], f"{where} kv{geared}")
        if model.actuator_ctrllimited[a]:
            ctrl[joint] = tuple(float(x) / gear for x in sorted(model.actuator_ctrlrange[a]))
    narrow = [
        j
        for j, (lo, hi) in ctrl.items()
        if model.jnt_limited[model.joint(j).id]
        and (lo > model.jnt_range[model.joint(j).id][0] + 1e-9
             or hi < model.jnt_range[model.joint(j).id][1] - 1e-9)
    ]  # fmt: skip
    if narrow:
        notes.append(
            f"<position> ctrlrange narrower than the joint's range for {narrow}: the file's "
            "simulator clamped those targets (the robot.toml limits are the joints')"
        )
    at_range = [
        j
        for j, (lo, hi) in ctrl.items()
        if j not in narrow
        and model.jnt_limited[model.joint(j).id]
        and np.allclose((lo, hi), model.jnt_range[model.joint(j).id], rtol=0.0, atol=1e-9)
    ]
    if at_range:
        shown = at_range if len(at_range) <= 4 else [*at_range[:4], f"{len(at_range) - 4} more"]
        notes.append(
            f"<position> ctrlrange equal to the joint's range for {shown}: the file's simulator "
            "clamped the targets at the range; the plant here clamps a target only where the "
            "joint's motor file says [position_target] clamped = true"
        )
    keys = tuple(model.key(k).name for k in range(model.nkey))
    home, home_source = {}, ""
    if keyframe is not None and keyframe not in keys:
        raise RobotImportError(
            f"{path}: --keyframe {keyframe}: no <key name='{keyframe}'> in the file (its keys: "
            f"{list(keys)})"
        )
    if keys:
        k = keys.index(keyframe) if keyframe else (keys.index(HOME_KEY) if HOME_KEY in keys else 0)
        qpos = np.asarray(model.key_qpos[k], dtype=np.float64)
        for j in range(model.njnt):
            if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
                home[model.joint(j).name] = float(qpos[model.jnt_qposadr[j]])
        home_source = f"MJCF <key name='{keys[k]}'>" if keys[k] else f"MJCF <key> #{k}"
        if len(keys) > 1:
            notes.append(
                f"home pose from {home_source} of keys {list(keys)} (--keyframe NAME takes another)"
            )
    return SourceDrive(kp, kd, ctrl, home, home_source, keys, tuple(notes))


def floor_bits(model: mujoco.MjModel) -> tuple[int, int] | None:
    """``(contype, conaffinity)`` of the first plane of ``model``'s world body (a scene file's
    floor, its defaults resolved), None without one."""
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == 0 and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            return int(model.geom_contype[g]), int(model.geom_conaffinity[g])
    return None
