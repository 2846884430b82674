"""The MJCF's hinges for the importer: the free joint's checks, the ``--limit`` flags, each
hinge's range and effort limit (:func:`hinge_limits`) and where the effort came from
(:func:`joint_efforts`). Used by :func:`sim2real.robots.importer.mjcf.prepare_mjcf`.
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from sim2real.robots.importer.source import (
    FLOATING_BASE,
    MIN_INERTIA,
    MIN_MASS,
    JointInfo,
    RobotImportError,
)


def check_free_joints(model: mujoco.MjModel, path: Path, floating_base: bool) -> None:
    """Refuse a free joint without ``floating_base``, or one not on the robot's root body (a
    body of the world body), or more than one.

    Raises:
        RobotImportError: naming the file and the joint's element.
    """
    free = [j for j in range(model.njnt) if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    for j in free:
        body = model.body(model.jnt_bodyid[j]).name
        element = f"<body name='{body}'><joint name='{model.joint(j).name}' type='free'>"
        if not floating_base:
            raise RobotImportError(f"{path}: {element}: " + FLOATING_BASE)
        if model.body_parentid[model.jnt_bodyid[j]] != 0 or len(free) > 1:
            raise RobotImportError(
                f"{path}: {element}: expected one free joint, on the root body of the robot (a "
                f"body of the world body); free joints: {[model.joint(k).name for k in free]}"
            )


def set_limits(spec: mujoco.MjSpec, limit_flags: list[str], path: Path) -> None:
    """Set the ``--limit JOINT=LOWER:UPPER`` ranges (rad, shell patterns) on ``spec``'s joints.

    Raises:
        RobotImportError: a malformed flag or a pattern matching no joint (named).
    """
    from sim2real.robots.importer import flags

    limit_overrides = flags.per_joint(
        limit_flags,
        [j.name for j in spec.joints],
        "--limit",
        flags.position_range,
        "JOINT=LOWER:UPPER in rad with LOWER < UPPER (JOINT may be a pattern, e.g. "
        "'joint*=-3.14:3.14')",
        path.name,
    )
    for name, (lo, hi) in limit_overrides.items():
        spec.joint(name).range = [lo, hi]
        spec.joint(name).limited = mujoco.mjtLimited.mjLIMITED_TRUE


def joint_efforts(model: mujoco.MjModel) -> dict[str, tuple[float, str]]:
    """Hinge name -> (effort limit N m, where it came from) for hinges the file limits.

    ``actuatorfrcrange`` first (it caps the sum of the joint's actuators); else the sum over the
    joint's actuators of ``forcerange``, or of a direct motor's ``ctrlrange`` times its gain,
    times the gear. A range counts by its smaller magnitude.
    """
    out: dict[str, tuple[float, str]] = {}
    per_joint: dict[int, list[tuple[float, str]]] = {}
    for a in range(model.nu):
        if model.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            continue
        gear = abs(float(model.actuator_gear[a, 0]))
        name = model.actuator(a).name or f"#{a}"
        if model.actuator_forcelimited[a]:
            force = float(np.min(np.abs(model.actuator_forcerange[a])))
            found = (force * gear, f"MJCF <actuator name='{name}'> forcerange")
        elif (
            model.actuator_ctrllimited[a]
            and model.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
            and model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_NONE
            and model.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE
        ):
            ctrl = float(np.min(np.abs(model.actuator_ctrlrange[a])))
            gain = abs(float(model.actuator_gainprm[a, 0]))
            found = (ctrl * gain * gear, f"MJCF <motor name='{name}'> ctrlrange")
        else:
            continue
        per_joint.setdefault(int(model.actuator_trnid[a, 0]), []).append(found)
    for j in range(model.njnt):
        name = model.joint(j).name
        if model.jnt_actfrclimited[j]:
            value = float(np.min(np.abs(model.jnt_actfrcrange[j])))
            out[name] = (value, "MJCF actuatorfrcrange")
        elif j in per_joint:
            found = per_joint[j]
            out[name] = (sum(v for v, _ in found), " + ".join(s for _, s in found))
    return {k: v for k, v in out.items() if v[0] > 0}


def hinge_limits(
    model: mujoco.MjModel, path: Path, efforts, floating_base: bool = False
) -> dict[str, JointInfo]:
    """JointInfo of every hinge (rad, N m); an unlimited hinge of a floating-base robot is
    continuous (a wheel: -inf, inf); refuse an arm's unlimited hinges (its goals are drawn within
    the joint ranges) and massless moving bodies."""
    joints: dict[str, JointInfo] = {}
    for j in range(model.njnt):
        name = model.joint(j).name
        lo, hi = (float(x) for x in model.jnt_range[j])
        if not model.jnt_limited[j] and floating_base:  # continuous (a wheel): no limit
            lo, hi = -math.inf, math.inf
        elif not model.jnt_limited[j]:
            raise RobotImportError(
                f"{path}: <joint name='{name}'>: no position limits (limited=\"false\" or no "
                f'range); expected range="LOWER UPPER" or --limit {name}=LOWER:UPPER (rad): '
                "a continuous joint (a wheel) is taken on a floating-base robot only"
            )
        elif not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise RobotImportError(
                f"{path}: <joint name='{name}' range>: got {lo:g}, {hi:g} rad; expected lower < "
                f"upper (or --limit {name}=LOWER:UPPER)"
            )
        b = model.jnt_bodyid[j]
        child, par = model.body(b).name, model.body(model.body_parentid[b]).name
        mass, inertia = float(model.body_mass[b]), model.body_inertia[b]
        if mass <= MIN_MASS or float(np.min(inertia)) <= MIN_INERTIA:
            raise RobotImportError(
                f"{path}: <body name='{child}'> (moved by joint '{name}'): mass {mass:g} kg, "
                f"principal inertia {list(np.round(inertia, 12))}: zero inertia; expected mass "
                "> 0 and a positive-definite inertia (an <inertial>, or geoms with volume)"
            )
        effort, effort_from = efforts.get(name, (None, "MJCF"))
        joints[name] = JointInfo(
            name, "hinge", par, child, lo, hi, None, effort, "MJCF", effort_from
        )
    return joints
