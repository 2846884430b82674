"""Cross-checks of a robot description while it loads (:func:`sim2real.robots.loading.load_robot`).

The MJCF in radians, its free joint against robot.toml's ``[base]`` table, a floating base's IMU
and foot sites and their sensors (MuJoCo) and frames (Pinocchio), and MuJoCo and Pinocchio agreeing
on site positions (m) and gravity torques (N m) within ``AGREEMENT_TOLERANCE`` at
``AGREEMENT_SAMPLES`` seeded configurations. Each raises :class:`sim2real.robots.robot.RobotSpecError`
naming the file and the field.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from sim2real.robots.continuous import sampling_bounds
from sim2real.robots.robot import RobotSpecError

#: Tolerance of the MuJoCo/Pinocchio agreement check (m for positions, N m for torques).
AGREEMENT_TOLERANCE = 1e-9
#: Configurations drawn (seeded) within the joint limits for the agreement check.
AGREEMENT_SAMPLES = 100


def _check_mjcf_radians(mjcf: Path) -> None:
    try:
        root = ET.parse(mjcf).getroot()
    except ET.ParseError as exc:
        raise RobotSpecError(f"{mjcf}: not valid XML: {exc}") from exc
    compiler = root.find("compiler")
    angle = None if compiler is None else compiler.get("angle")
    if angle != "radian":
        raise RobotSpecError(
            f'{mjcf}: <compiler angle=...> is {angle!r}; expected angle="radian" '
            "(MJCF defaults to degrees, which would read +-1.57 as +-0.027 rad)"
        )


def _check_free_joint(toml_path: Path, mjcf: Path, mj_model: mujoco.MjModel, cfg) -> int:
    """Index of the first hinge joint: 1 when the MJCF's first joint is the free joint of the
    ``[base] body`` (floating base), 0 for a fixed-base arm.

    Raises:
        RobotSpecError: a free joint without ``[base]``, ``[base]`` without a free joint on its
            body, or a free joint elsewhere.
    """
    free = [i for i in range(mj_model.njnt) if mj_model.jnt_type[i] == mujoco.mjtJoint.mjJNT_FREE]
    if cfg.base is None:
        if free:
            raise RobotSpecError(
                f"{toml_path}: {mjcf.name} has a free joint "
                f"('{mj_model.joint(free[0]).name}'): a floating-base robot needs a [base] table "
                "(body, imu_site, feet, standing_height)"
            )
        return 0
    body = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, cfg.base.body)
    if free != [0] or mj_model.jnt_bodyid[0] != body:
        raise RobotSpecError(
            f"{toml_path}: field 'base.body' = '{cfg.base.body}': expected {mjcf.name}'s first "
            f"and only free joint (<freejoint/>) on that body (free joints: "
            f"{[mj_model.joint(i).name for i in free]})"
        )
    return 1


def _base_frames(toml_path, mjcf, mj_model, pin_model, cfg) -> dict:
    """The floating-base fields of :class:`Robot`: base, IMU and foot ids in MuJoCo and Pinocchio.

    Raises:
        RobotSpecError: a site or body that MuJoCo or Pinocchio does not have, or an IMU site
            without a ``gyro`` and an ``accelerometer`` sensor, or a foot site without a
            ``touch`` sensor.
    """
    base = cfg.base

    def site_id(name: str, field_name: str) -> int:
        sid = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_SITE, name)
        if sid < 0:
            raise RobotSpecError(
                f"{toml_path}: field 'base.{field_name}' = '{name}' is not a site of {mjcf.name}"
            )
        return sid

    def frame_id(name: str, kind=pin.FrameType.OP_FRAME) -> int:
        # MJCF sites are OP_FRAME frames, bodies BODY frames (a site may share a link's name)
        if not pin_model.existFrame(name, kind):
            raise RobotSpecError(f"{mjcf}: Pinocchio has no {kind} frame for '{name}'")
        return pin_model.getFrameId(name, kind)

    def sensors_at(sid: int) -> set:
        return {
            int(mj_model.sensor_type[k])
            for k in range(mj_model.nsensor)
            if mj_model.sensor_objtype[k] == mujoco.mjtObj.mjOBJ_SITE
            and mj_model.sensor_objid[k] == sid
        }

    imu = site_id(base.imu_site, "imu_site")
    want = {int(mujoco.mjtSensor.mjSENS_GYRO), int(mujoco.mjtSensor.mjSENS_ACCELEROMETER)}
    if not want <= sensors_at(imu):
        raise RobotSpecError(
            f"{mjcf}: site '{base.imu_site}' (field 'base.imu_site' of {toml_path.name}) needs "
            "a <gyro> and an <accelerometer> sensor"
        )
    feet = []
    for i, name in enumerate(base.feet):
        sid = site_id(name, f"feet[{i}]")
        if int(mujoco.mjtSensor.mjSENS_TOUCH) not in sensors_at(sid):
            raise RobotSpecError(
                f"{mjcf}: foot site '{name}' (field 'base.feet[{i}]' of {toml_path.name}) needs "
                "a <touch> sensor (foot contact)"
            )
        feet.append(sid)
    return {
        "floating_base": True,
        "base_body": base.body,
        "base_frame_id": frame_id(base.body, pin.FrameType.BODY),
        "imu_site": base.imu_site,
        "imu_site_id": imu,
        "imu_frame_id": frame_id(base.imu_site),
        "foot_sites": tuple(base.feet),
        "foot_site_ids": tuple(feet),
        "foot_frame_ids": tuple(frame_id(f) for f in base.feet),
    }


def check_agreement(
    mjcf, mj_model, pin_model, site_ids, frame_ids, lower, upper, floating=False
) -> None:
    """MuJoCo and Pinocchio must agree on the sites' positions (end effector, feet; world frame)
    and gravity torques, at ``AGREEMENT_SAMPLES`` seeded configurations within the joint limits.

    A floating base is drawn too: position uniform in a 2 m cube about the origin, orientation
    uniform (a normalized Gaussian quaternion). Its generalized gravity force is compared as
    well: MuJoCo's free joint takes the force in the world frame and the torque in the base
    frame, Pinocchio's free flyer both in the base frame.

    Raises RobotSpecError beyond ``AGREEMENT_TOLERANCE``.
    """
    rng = np.random.default_rng(0)
    lower, upper = sampling_bounds(lower, upper)
    mj_data = mujoco.MjData(mj_model)
    pin_data = pin_model.createData()
    worst_fk = worst_g = 0.0
    sites, frames = list(site_ids), list(frame_ids)
    for _ in range(AGREEMENT_SAMPLES):
        q = rng.uniform(lower, upper)
        if floating:
            pos = rng.uniform(-1.0, 1.0, 3)
            wxyz = rng.standard_normal(4)
            wxyz /= np.linalg.norm(wxyz)
            mj_q = np.concatenate([pos, wxyz, q])
            pin_q = np.concatenate([pos, wxyz[1:], wxyz[:1], q])
        else:
            mj_q = pin_q = q
        mj_data.qpos[:] = mj_q
        mj_data.qvel[:] = 0.0
        mujoco.mj_forward(mj_model, mj_data)
        pin.framesForwardKinematics(pin_model, pin_data, pin_q)
        g = pin.computeGeneralizedGravity(pin_model, pin_data, pin_q).copy()
        if floating:  # the base force into MuJoCo's world frame
            g[:3] = pin_data.oMi[1].rotation @ g[:3]
        for s, f in zip(sites, frames, strict=True):
            err = np.abs(mj_data.site_xpos[s] - pin_data.oMf[f].translation)
            worst_fk = max(worst_fk, float(np.max(err)))
        worst_g = max(worst_g, float(np.max(np.abs(mj_data.qfrc_bias - g))))
    if worst_fk > AGREEMENT_TOLERANCE or worst_g > AGREEMENT_TOLERANCE:
        what = "end-effector and foot positions" if floating else "end-effector position"
        raise RobotSpecError(
            f"{mjcf}: MuJoCo and Pinocchio disagree ({what} {worst_fk:.3g} m, "
            f"gravity torque {worst_g:.3g} N m; tolerance {AGREEMENT_TOLERANCE})"
        )
