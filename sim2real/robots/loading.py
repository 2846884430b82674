"""Reading and validating a robot description: robot.toml and its MJCF into a
:class:`sim2real.robots.robot.Robot`.

:func:`load_robot` finds the robot.toml (:func:`resolve_robot_toml`), adds the motor catalog's
tables (``robots/motors``, :func:`load_motor`), validates the file (``sim2real.robots.schema``), resolves a
``package://`` meshdir to an installed description package (:mod:`sim2real.robots.packages`), checks the
MJCF against robot.toml and MuJoCo against Pinocchio (:mod:`sim2real.robots.crosscheck`), and builds the
Robot.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
from pydantic import ValidationError

from sim2real.robots.continuous import continuous_mask, sampling_bounds
from sim2real.robots.crosscheck import (
    _base_frames,
    _check_free_joint,
    _check_mjcf_radians,
    check_agreement,
)
from sim2real.robots.packages import resolved_mjcf
from sim2real.robots.robot import Robot, RobotSpecError
from sim2real.robots.schema import MotorConfig, RobotConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROBOTS_DIR = Path(__file__).resolve().parent
#: The motor catalog: one TOML file a model (``MotorConfig`` fields at the top level).
MOTORS_DIR = ROBOTS_DIR / "motors"


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
    """Motor models of the catalog: name -> path of its TOML file (``sim2real/robots/motors/NAME.toml``)."""
    return {p.stem: p for p in sorted(MOTORS_DIR.glob("*.toml"))}


def load_motor(name: str) -> MotorConfig:
    """The catalog's motor ``name`` (``sim2real/robots/motors/NAME.toml``), validated.

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
            ``crosscheck.AGREEMENT_TOLERANCE`` at ``AGREEMENT_SAMPLES`` random configurations.
    """
    toml_path = resolve_robot_toml(name_or_path).resolve()
    cfg = _read_config(toml_path)
    described_mjcf = (toml_path.parent / cfg.mjcf).resolve()
    if not described_mjcf.is_file():
        raise RobotSpecError(f"{toml_path}: field 'mjcf': file {described_mjcf} does not exist")
    _check_mjcf_radians(described_mjcf)
    mjcf = resolved_mjcf(described_mjcf)
    mj_model, j0 = _mujoco_model(toml_path, mjcf, cfg)
    names = tuple(j.name for j in cfg.joints)
    floating = cfg.base is not None
    lower, upper = _position_limits(toml_path, mjcf, mj_model, cfg, j0)
    decimation, home = _control(toml_path, cfg, lower, upper)
    site = cfg.safety.end_effector_site
    ee_site_id = -1 if site is None else mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_SITE, site)
    if site is not None and ee_site_id < 0:
        raise RobotSpecError(
            f"{toml_path}: field 'safety.end_effector_site' = '{site}' is not a site of {mjcf.name}"
        )
    pin_model, ee_frame_id = _pinocchio_model(mjcf, mj_model, cfg, j0)
    legged = _base_frames(toml_path, mjcf, mj_model, pin_model, cfg) if floating else {}
    sites = [ee_site_id] if ee_site_id >= 0 else []
    frames = [ee_frame_id] if ee_frame_id >= 0 else []
    sites += list(legged.get("foot_site_ids", ()))
    frames += list(legged.get("foot_frame_ids", ()))
    check_agreement(mjcf, mj_model, pin_model, sites, frames, lower, upper, floating)
    ctl = cfg.control

    digest = description_hash(cfg, described_mjcf.read_bytes())
    robot = Robot(
        name=cfg.name,
        directory=toml_path.parent,
        mjcf_path=mjcf,
        config=cfg,
        joint_names=names,
        **_limit_fields(cfg, lower, upper),
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
    # commands a fixed base's motors can follow under gravity
    from sim2real.robots.chain_bounds import holding_command_limit

    limit = holding_command_limit(robot)
    if np.array_equal(limit, robot.command_velocity_limit):
        return robot
    return dataclasses.replace(robot, command_velocity_limit=_readonly(limit))


def _limit_fields(cfg: RobotConfig, lower: np.ndarray, upper: np.ndarray) -> dict[str, np.ndarray]:
    """The :class:`Robot`'s per-joint limits, read-only (n,) arrays: position (rad), the soft
    position limits (``soft_limit_fraction`` of each range about its centre; a continuous
    joint's infinite), velocity and its soft and command limits (rad/s), acceleration, jerk
    and effort."""
    frac = np.array([j.soft_limit_fraction for j in cfg.joints])
    velocity = np.array([j.velocity_limit for j in cfg.joints])
    soft_velocity = frac * velocity
    finite_lo, finite_hi = sampling_bounds(lower, upper)
    centre = np.where(continuous_mask(lower, upper), 0.0, (finite_hi + finite_lo) / 2.0)
    half = (upper - lower) / 2.0  # inf for a continuous joint: its soft limits are infinite too
    return {
        "position_lower": _readonly(lower),
        "position_upper": _readonly(upper),
        "soft_lower": _readonly(centre - frac * half),
        "soft_upper": _readonly(centre + frac * half),
        "velocity_limit": _readonly(velocity),
        "soft_velocity_limit": _readonly(soft_velocity),
        "command_velocity_limit": _readonly(
            [
                soft if j.command_velocity_limit is None else j.command_velocity_limit
                for j, soft in zip(cfg.joints, soft_velocity, strict=True)
            ]
        ),
        "acceleration_limit": _readonly([j.acceleration_limit for j in cfg.joints]),
        "jerk_limit": _readonly([j.jerk_limit for j in cfg.joints]),
        "effort_limit": _readonly([j.effort_limit for j in cfg.joints]),
    }


def _read_config(toml_path: Path) -> RobotConfig:
    """robot.toml read, its catalog motors merged in, validated (``RobotSpecError`` naming the
    file and field)."""
    try:
        raw = tomllib.loads(toml_path.read_bytes().decode("utf-8"))
    except OSError as exc:
        raise RobotSpecError(f"{toml_path}: cannot read: {exc}") from exc
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RobotSpecError(f"{toml_path}: not valid TOML: {exc}") from exc
    _merge_catalog_motors(raw, toml_path)
    try:
        return RobotConfig.model_validate(raw)
    except ValidationError as exc:
        raise RobotSpecError(_format_validation_error(toml_path, exc)) from None


def _mujoco_model(toml_path: Path, mjcf: Path, cfg: RobotConfig) -> tuple[mujoco.MjModel, int]:
    """The compiled MJCF and the index of its first robot joint (1 after a free joint): its
    joints robot.toml's, by name and in order, all hinges (``RobotSpecError`` where not)."""
    try:
        mj_model = mujoco.MjModel.from_xml_path(str(mjcf))
    except ValueError as exc:
        raise RobotSpecError(f"{mjcf}: MuJoCo cannot compile it: {exc}") from exc
    names = tuple(j.name for j in cfg.joints)
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
    return mj_model, j0


def _position_limits(toml_path: Path, mjcf: Path, mj_model, cfg: RobotConfig, j0: int):
    """(n,) rad lower and upper limits (infinite for a continuous joint), each the MJCF's range
    (``RobotSpecError`` where robot.toml and the MJCF differ)."""
    lower = np.array([-np.inf if j.continuous else j.position_limit[0] for j in cfg.joints])
    upper = np.array([np.inf if j.continuous else j.position_limit[1] for j in cfg.joints])
    for i, joint in enumerate(cfg.joints):
        k = i + j0
        if joint.continuous:
            if mj_model.jnt_limited[k]:
                raise RobotSpecError(
                    f"{toml_path}: field 'joints[{i}].continuous' = true but the MJCF limits "
                    f"joint '{joint.name}' to {list(mj_model.jnt_range[k])} in {mjcf.name} "
                    "(expected no range)"
                )
            continue
        if not mj_model.jnt_limited[k] or not np.allclose(
            mj_model.jnt_range[k], [lower[i], upper[i]], atol=1e-12, rtol=0
        ):
            raise RobotSpecError(
                f"{toml_path}: field 'joints[{i}].position_limit' = {list(joint.position_limit)} "
                f"differs from the MJCF range of joint '{joint.name}' "
                f"({list(mj_model.jnt_range[k]) if mj_model.jnt_limited[k] else 'unlimited'})"
            )
    return lower, upper


def _control(toml_path: Path, cfg: RobotConfig, lower, upper) -> tuple[int, np.ndarray]:
    """``(decimation, home)``: physics steps per control period (the control rate an integer
    fraction of the physics rate) and the home pose within the limits (``RobotSpecError``)."""
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
    return decimation, home


def _pinocchio_model(mjcf: Path, mj_model, cfg: RobotConfig, j0: int):
    """``(pin_model, ee_frame_id)``: Pinocchio's model of the MJCF, its joints robot.toml's and
    its root a free flyer where the robot floats, MuJoCo's gravity, the joints' velocity and
    effort limits; the end-effector site's frame (-1: none). ``RobotSpecError`` where Pinocchio
    refuses or reads otherwise."""
    names = tuple(j.name for j in cfg.joints)
    floating = cfg.base is not None
    try:
        pin_model = pin.buildModelFromMJCF(str(mjcf))
    except Exception as exc:  # noqa: BLE001 - Pinocchio's parser raises anything (IndexError, ...)
        raise RobotSpecError(
            f"{mjcf}: Pinocchio's MJCF parser refuses it: {type(exc).__name__}: "
            + "; ".join(line.strip() for line in str(exc).splitlines() if line.strip())
        ) from None
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
    site = cfg.safety.end_effector_site
    if site is None:
        return pin_model, -1
    # an MJCF site is an OP_FRAME (a body of the same name is a BODY frame: asked without the
    # type, Pinocchio raises "Several frames match the filter")
    if not pin_model.existFrame(site, pin.FrameType.OP_FRAME):
        raise RobotSpecError(f"{mjcf}: Pinocchio has no frame for site '{site}'")
    return pin_model, pin_model.getFrameId(site, pin.FrameType.OP_FRAME)


#: What the description hash leaves out: the robot's ``kind`` (how the toolkit assembles the
#: stages around it, :mod:`sim2real.deploy.robot_kind`, not what the policy sees or commands),
#: the ``[task]``, ``[soak]`` and ``[unitree]`` tables, the guard's
#: ``safety.link_length_tolerance`` (how sure the guard is of the MJCF, not what the policy sees
#: or commands), the drives' velocity reading and the IMU's onboard attitude (the base
#: estimator's inputs).
HASH_EXCLUDED = {
    "kind": True,
    "task": True,
    "soak": True,
    "unitree": True,
    "safety": {"link_length_tolerance"},
    # the plant's motor, not the policy's contract
    "motors": {"__all__": {"command_delay", "position_target"}},
    "sensors": {
        "velocity_noise_sigma": True,
        "imu": {"orientation_sigma", "orientation_tau", "heading_rate_sigma", "heading_walk"},
    },
}


def description_hash(cfg: RobotConfig, mjcf_bytes: bytes) -> str:
    """sha256 (hex) of the description a policy depends on: every robot.toml field but its
    ``kind``, the ``[task]``, ``[soak]`` and ``[unitree]`` tables (where goals come from and how hard the soak
    pushes are the evaluation's business, how joints map to a Unitree robot's motor slots the
    backend's, not the robot's) and :data:`HASH_EXCLUDED`'s guard setting, in canonical JSON,
    and the MJCF bytes (the file in the robot folder, package URIs unresolved). Optional fields
    left unset (None) are left out, so that adding one to the schema changes no existing robot's
    hash."""
    described = json.dumps(
        cfg.model_dump(exclude=HASH_EXCLUDED, exclude_none=True, mode="json"),
        sort_keys=True,
    )
    return hashlib.sha256(described.encode() + b"\0" + mjcf_bytes).hexdigest()
