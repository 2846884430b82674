"""Reading and validating a robot description: robot.toml and its MJCF into a
:class:`robots.robot.Robot`.

:func:`load_robot` finds the robot.toml (:func:`resolve_robot_toml`), adds the motor catalog's
tables (``robots/motors``, :func:`load_motor`), validates the file (``robots.schema``), resolves a
``package://`` meshdir to an installed description package (:func:`package_root`), checks the
MJCF against robot.toml and MuJoCo against Pinocchio, and builds the Robot.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
from pydantic import ValidationError

from robots.files import atomic_write
from robots.robot import Robot, RobotSpecError
from robots.schema import MotorConfig, RobotConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROBOTS_DIR = Path(__file__).resolve().parent
#: The motor catalog: one TOML file a model (``MotorConfig`` fields at the top level).
MOTORS_DIR = ROBOTS_DIR / "motors"
#: Prefix of an MJCF ``meshdir`` that names an installed package instead of a folder.
PACKAGE_SCHEME = "package://"
#: Where installed description packages keep their files, inside their Python distribution
#: (example-robot-data installs through cmeel under ``cmeel.prefix/share/<name>``).
PACKAGE_LOCATIONS = {
    "example-robot-data": ("example-robot-data", "cmeel.prefix/share/example-robot-data")
}

#: Tolerance of the MuJoCo/Pinocchio agreement check (m for positions, N m for torques).
AGREEMENT_TOLERANCE = 1e-9
#: Configurations drawn (seeded) within the joint limits for the agreement check.
AGREEMENT_SAMPLES = 100


def _readonly(values) -> np.ndarray:
    arr = np.array(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr


def resolve_robot_toml(name_or_path: str | Path) -> Path:
    """Path of robot.toml for a shipped robot name ('arm3'), a folder or a robot.toml path."""
    candidate = Path(name_or_path)
    if candidate.is_file():
        return candidate
    if candidate.is_dir():
        return candidate / "robot.toml"
    shipped = ROBOTS_DIR / str(name_or_path) / "robot.toml"
    if shipped.is_file():
        return shipped
    known = sorted(p.parent.name for p in ROBOTS_DIR.glob("*/robot.toml"))
    raise RobotSpecError(
        f"robot '{name_or_path}': no such file or folder, and not a shipped robot (known: {known})"
    )


def motor_catalog() -> dict[str, Path]:
    """Motor models of the catalog: name -> path of its TOML file (``robots/motors/NAME.toml``)."""
    return {p.stem: p for p in sorted(MOTORS_DIR.glob("*.toml"))}


def load_motor(name: str) -> MotorConfig:
    """The catalog's motor ``name`` (``robots/motors/NAME.toml``), validated.

    Raises:
        RobotSpecError: no such model in the catalog (the message lists the known ones), or an
            invalid file (the message names the file and the field).
    """
    return MotorConfig.model_validate(_catalog_table(name, None))


def _catalog_table(name: str, where: str | None) -> dict:
    path = MOTORS_DIR / f"{name}.toml"
    if not path.is_file():
        known = sorted(motor_catalog())
        prefix = f"{where}: " if where else ""
        raise RobotSpecError(
            f"{prefix}motor '{name}' is neither a [motors.{name}] table in robot.toml nor a "
            f"model of the catalog {MOTORS_DIR} (known: {known}); add {MOTORS_DIR}/{name}.toml"
        )
    return read_motor_file(path)


def read_motor_file(path: Path) -> dict:
    """The table of a motor TOML file (the catalog's schema: ``MotorConfig`` fields at the top
    level), validated.

    Raises:
        RobotSpecError: unreadable file, invalid TOML, or a missing or invalid field (one line
            naming the file and the field).
    """
    path = Path(path)
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RobotSpecError(f"{path}: cannot read: {exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RobotSpecError(f"{path}: not valid TOML: {exc}") from exc
    try:
        MotorConfig.model_validate(table)
    except ValidationError as exc:
        raise RobotSpecError(_format_validation_error(path, exc).replace("\n", "; ")) from None
    return table


def _merge_catalog_motors(raw: dict, toml_path: Path) -> None:
    """Add the catalog table of every joint's motor that robot.toml does not define itself.

    The merged table sits in ``raw['motors']`` under the same name with the file's values, so a
    table moved from robot.toml to the catalog leaves the validated config (and the description
    hash) unchanged.
    """
    joints = raw.get("joints")
    if not isinstance(joints, list):
        return  # validation names the problem
    motors = raw.setdefault("motors", {})
    if not isinstance(motors, dict):
        return
    for i, joint in enumerate(joints):
        name = joint.get("motor") if isinstance(joint, dict) else None
        if not isinstance(name, str) or name in motors:
            continue
        where = f"{toml_path}: field 'joints[{i}].motor' (joint '{joint.get('name', '?')}')"
        motors[name] = _catalog_table(name, where)


def package_root(package: str) -> Path:
    """Folder of an installed description package (``package://PACKAGE/...`` URIs).

    Looks in the folders of the ``SIM2REAL_PACKAGE_PATH`` environment variable (``os.pathsep``
    separated, each holding ``PACKAGE/``), then in the Python distributions of
    ``PACKAGE_LOCATIONS``.

    Raises:
        RobotSpecError: the package is not installed.
    """
    for folder in filter(None, os.environ.get("SIM2REAL_PACKAGE_PATH", "").split(os.pathsep)):
        candidate = Path(folder) / package
        if candidate.is_dir():
            return candidate.resolve()
    if package in PACKAGE_LOCATIONS:
        from importlib import metadata

        dist_name, inside = PACKAGE_LOCATIONS[package]
        try:
            root = Path(str(metadata.distribution(dist_name).locate_file(inside)))
        except metadata.PackageNotFoundError:
            root = None
        if root is not None and root.is_dir():
            return root.resolve()
        hint = f"pip install {dist_name}  (or: pip install 'sim2real-deploy[robots]')"
    else:
        known = sorted(PACKAGE_LOCATIONS)
        hint = f"put its folder in a folder listed in SIM2REAL_PACKAGE_PATH (known: {known})"
    raise RobotSpecError(f"package '{package}' is not installed: {hint}")


def resolve_package_uri(uri: str) -> Path:
    """``package://PACKAGE/rest`` -> the file's path in the installed package (not checked)."""
    package, _, rest = uri[len(PACKAGE_SCHEME) :].partition("/")
    return package_root(package) / rest


def _resolved_mjcf(mjcf: Path) -> Path:
    """The MJCF MuJoCo and Pinocchio read: ``mjcf`` itself, or, when its ``<compiler meshdir>``
    names an installed package (``package://...``), a copy in the temporary folder with the
    meshdir resolved to an absolute path (the robot folder holds no third-party meshes)."""
    root = ET.parse(mjcf).getroot()
    compiler = root.find("compiler")
    meshdir = None if compiler is None else compiler.get("meshdir")
    if not meshdir or not meshdir.startswith(PACKAGE_SCHEME):
        return mjcf
    try:
        folder = resolve_package_uri(meshdir)
    except RobotSpecError as exc:
        raise RobotSpecError(f"{mjcf}: <compiler meshdir='{meshdir}'>: {exc}") from None
    if not folder.is_dir():
        raise RobotSpecError(
            f"{mjcf}: <compiler meshdir='{meshdir}'> resolves to {folder}, which does not exist"
        )
    text = mjcf.read_text(encoding="utf-8").replace(
        f'meshdir="{meshdir}"', f'meshdir="{folder.as_posix()}"', 1
    )
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / "sim2real-robots" / digest / mjcf.name
    if not out.is_file():
        out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(out, text)
    return out


def _format_validation_error(path: Path, err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(f"[{p}]" if isinstance(p, int) else str(p) for p in e["loc"]).replace(
            ".[", "["
        )
        where = f"field '{loc}'" if loc else "top level"
        got = e.get("input")
        if e["type"] == "missing":
            lines.append(f"{path}: {where}: missing (required)")
        else:
            lines.append(f"{path}: {where}: {e['msg']} (got {got!r})")
    return "\n".join(lines)


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


def load_robot(name_or_path: str | Path) -> Robot:
    """Load, validate and cross-check a robot description.

    Args:
        name_or_path: A shipped robot name (``'arm3'``, ``'arm6'``), a robot folder, or the path of
            a robot.toml.

    Returns:
        A frozen :class:`Robot`.

    Raises:
        RobotSpecError: with the file and field named, for a missing file, invalid TOML, a missing
            or invalid field (non-positive limits, unknown control mode, ...), an MJCF without
            ``angle="radian"``, joint names or limits that differ between MJCF and robot.toml, a
            control rate that is not an integer fraction of the physics rate, or MuJoCo and
            Pinocchio disagreeing on forward kinematics or gravity torques by more than
            ``AGREEMENT_TOLERANCE`` at ``AGREEMENT_SAMPLES`` random configurations.
    """
    toml_path = resolve_robot_toml(name_or_path).resolve()
    try:
        raw_bytes = toml_path.read_bytes()
        raw = tomllib.loads(raw_bytes.decode("utf-8"))
    except OSError as exc:
        raise RobotSpecError(f"{toml_path}: cannot read: {exc}") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RobotSpecError(f"{toml_path}: not valid TOML: {exc}") from exc
    _merge_catalog_motors(raw, toml_path)
    try:
        cfg = RobotConfig.model_validate(raw)
    except ValidationError as exc:
        raise RobotSpecError(_format_validation_error(toml_path, exc)) from None

    described_mjcf = (toml_path.parent / cfg.mjcf).resolve()
    if not described_mjcf.is_file():
        raise RobotSpecError(f"{toml_path}: field 'mjcf': file {described_mjcf} does not exist")
    _check_mjcf_radians(described_mjcf)
    mjcf = _resolved_mjcf(described_mjcf)

    try:
        mj_model = mujoco.MjModel.from_xml_path(str(mjcf))
    except ValueError as exc:
        raise RobotSpecError(f"{mjcf}: MuJoCo cannot compile it: {exc}") from exc
    names = tuple(j.name for j in cfg.joints)
    floating = cfg.base is not None
    j0 = _check_free_joint(toml_path, mjcf, mj_model, cfg)
    mj_names = tuple(mj_model.joint(i).name for i in range(j0, mj_model.njnt))
    if mj_names != names:
        raise RobotSpecError(
            f"{toml_path}: field 'joints': names {list(names)} differ from the MJCF joints "
            f"{list(mj_names)} in {mjcf.name} (same names, same order expected)"
        )
    if any(mj_model.jnt_type[i] != mujoco.mjtJoint.mjJNT_HINGE for i in range(j0, mj_model.njnt)):
        raise RobotSpecError(
            f"{mjcf}: only hinge joints are supported (besides one free joint of a "
            "floating-base robot's [base] body)"
        )

    lower = np.array([j.position_limit[0] for j in cfg.joints])
    upper = np.array([j.position_limit[1] for j in cfg.joints])
    for i, joint in enumerate(cfg.joints):
        k = i + j0
        if not mj_model.jnt_limited[k] or not np.allclose(
            mj_model.jnt_range[k], [lower[i], upper[i]], atol=1e-12, rtol=0
        ):
            raise RobotSpecError(
                f"{toml_path}: field 'joints[{i}].position_limit' = {list(joint.position_limit)} "
                f"differs from the MJCF range of joint '{joint.name}' "
                f"({list(mj_model.jnt_range[k]) if mj_model.jnt_limited[k] else 'unlimited'})"
            )

    ctl = cfg.control
    ratio = 1.0 / (ctl.control_rate * ctl.physics_timestep)
    decimation = int(round(ratio))
    if decimation < 1 or abs(ratio - decimation) > 1e-9:
        raise RobotSpecError(
            f"{toml_path}: field 'control.control_rate' = {ctl.control_rate} Hz is not an integer "
            f"fraction of the physics rate 1/{ctl.physics_timestep} s (decimation {ratio:.4g})"
        )
    home = np.array(ctl.home)
    if np.any(home < lower) or np.any(home > upper):
        raise RobotSpecError(
            f"{toml_path}: field 'control.home' = {ctl.home} is outside the joint limits"
        )

    site = cfg.safety.end_effector_site
    ee_site_id = -1 if site is None else mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_SITE, site)
    if site is not None and ee_site_id < 0:
        raise RobotSpecError(
            f"{toml_path}: field 'safety.end_effector_site' = '{site}' is not a site of {mjcf.name}"
        )

    pin_model = pin.buildModelFromMJCF(str(mjcf))
    pin_names = tuple(pin_model.names[1 + j0 :])
    if pin_names != names:
        raise RobotSpecError(
            f"{mjcf}: Pinocchio reads joints {list(pin_names)}, expected {list(names)}"
        )
    if floating and pin_model.joints[1].shortname() != "JointModelFreeFlyer":
        raise RobotSpecError(
            f"{mjcf}: Pinocchio reads the root joint as {pin_model.joints[1].shortname()}, "
            "expected a free flyer (JointModelFreeFlyer) from the <freejoint>"
        )
    pin_model.gravity.linear = np.array(mj_model.opt.gravity, dtype=np.float64)
    free = np.full(6 if floating else 0, np.inf)
    pin_model.velocityLimit = np.concatenate([free, [j.velocity_limit for j in cfg.joints]])
    pin_model.effortLimit = np.concatenate([free, [j.effort_limit for j in cfg.joints]])
    # Pinocchio 4 keeps lower/upper bounds apart and velocityLimit sets only the upper ones
    if hasattr(pin_model, "lowerVelocityLimit"):
        pin_model.lowerVelocityLimit = -pin_model.upperVelocityLimit
        pin_model.lowerEffortLimit = -pin_model.upperEffortLimit
    ee_frame_id = -1
    if site is not None:
        if not pin_model.existFrame(site):
            raise RobotSpecError(f"{mjcf}: Pinocchio has no frame for site '{site}'")
        ee_frame_id = pin_model.getFrameId(site)
    legged = _base_frames(toml_path, mjcf, mj_model, pin_model, cfg) if floating else {}
    sites = [ee_site_id] if ee_site_id >= 0 else []
    frames = [ee_frame_id] if ee_frame_id >= 0 else []
    sites += list(legged.get("foot_site_ids", ()))
    frames += list(legged.get("foot_frame_ids", ()))
    _check_agreement(mjcf, mj_model, pin_model, sites, frames, lower, upper, floating)

    frac = np.array([j.soft_limit_fraction for j in cfg.joints])
    centre, half = (upper + lower) / 2.0, (upper - lower) / 2.0
    digest = description_hash(cfg, described_mjcf.read_bytes())
    return Robot(
        name=cfg.name,
        directory=toml_path.parent,
        mjcf_path=mjcf,
        config=cfg,
        joint_names=names,
        position_lower=_readonly(lower),
        position_upper=_readonly(upper),
        soft_lower=_readonly(centre - frac * half),
        soft_upper=_readonly(centre + frac * half),
        velocity_limit=_readonly([j.velocity_limit for j in cfg.joints]),
        soft_velocity_limit=_readonly(frac * np.array([j.velocity_limit for j in cfg.joints])),
        acceleration_limit=_readonly([j.acceleration_limit for j in cfg.joints]),
        jerk_limit=_readonly([j.jerk_limit for j in cfg.joints]),
        effort_limit=_readonly([j.effort_limit for j in cfg.joints]),
        motors=tuple(cfg.motors[j.motor] for j in cfg.joints),
        home=_readonly(home),
        control_period=1.0 / ctl.control_rate,
        physics_timestep=ctl.physics_timestep,
        decimation=decimation,
        mj_model=mj_model,
        pin_model=pin_model,
        ee_frame_id=ee_frame_id,
        ee_site_id=ee_site_id,
        description_hash=digest,
        **legged,
    )


def description_hash(cfg: RobotConfig, mjcf_bytes: bytes) -> str:
    """sha256 (hex) of the description a policy depends on: every robot.toml field but the
    ``[task]``, ``[soak]`` and ``[unitree]`` tables (where goals come from and how hard the soak
    pushes are the evaluation's business, how joints map to a Unitree robot's motor slots the
    backend's, not the robot's), in canonical JSON, and the MJCF bytes (the file in
    the robot folder, package URIs unresolved). Optional fields left unset (None) are left out,
    so that adding one to the schema changes no existing robot's hash."""
    described = json.dumps(
        cfg.model_dump(exclude={"task", "soak", "unitree"}, exclude_none=True, mode="json"),
        sort_keys=True,
    )
    return hashlib.sha256(described.encode() + b"\0" + mjcf_bytes).hexdigest()


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


def _check_agreement(
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
