"""The Robot: one description (MJCF + robot.toml) from which MuJoCo and Pinocchio are both built."""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
from pydantic import ValidationError

from robots.schema import CONTROL_MODES, MotorConfig, RobotConfig

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


class RobotSpecError(ValueError):
    """A robot description is invalid.

    The message names the file, the field and what was expected.
    """


def _readonly(values) -> np.ndarray:
    arr = np.array(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Robot:
    """A validated robot: spec, MuJoCo model and Pinocchio model built from the same MJCF.

    Arrays are read-only, shaped ``(n_joints,)``, in the joint order of ``joint_names``.

    Attributes:
        name: Robot name from robot.toml.
        directory: Folder holding robot.toml and the MJCF.
        mjcf_path: Path of the MJCF file MuJoCo and Pinocchio read: the robot folder's, or a
            copy with its ``package://`` meshdir resolved (see ``_resolved_mjcf``).
        config: The validated robot.toml (``robots.schema.RobotConfig``).
        joint_names: Joint names in kinematic (and action/observation) order.
        position_lower, position_upper: Hard joint limits, rad.
        soft_lower, soft_upper: Soft limits (``soft_limit_fraction`` of the range about its
            centre), rad. Crossing one is a warning, not a violation.
        velocity_limit: Hard velocity limit, rad/s: the joint itself must stay within it.
        soft_velocity_limit: ``soft_limit_fraction`` of ``velocity_limit``, rad/s: the fastest
            command the smoother issues. The margin is for the drive's servo, which tracks a
            velocity command with overshoot (arm3: true speed up to 3.09 rad/s under commands of
            2.83 rad/s, 9 % over, ``deploy-run --robot arm3 --duration 400``).
        acceleration_limit: rad/s^2. jerk_limit: rad/s^3.
        effort_limit: N m at the joint.
        motors: The motor of each joint, per joint.
        home: Home pose, rad.
        control_period: 1 / control_rate, s. physics_timestep: s.
        decimation: Physics steps per control tick (an integer; checked).
        mj_model: MuJoCo model without actuators (kinematics and dynamics reference).
        pin_model: Pinocchio model; velocity and effort limits set from robot.toml, gravity from
            the MJCF ``<option gravity>``.
        ee_frame_id: Pinocchio frame id of the end-effector site.
        ee_site_id: MuJoCo site id of the end-effector site.
        description_hash: sha256 (hex) of the robot.toml fields except ``[task]`` (canonical
            JSON) and the MJCF bytes; a policy records it.
    """

    name: str
    directory: Path
    mjcf_path: Path
    config: RobotConfig
    joint_names: tuple[str, ...]
    position_lower: np.ndarray
    position_upper: np.ndarray
    soft_lower: np.ndarray
    soft_upper: np.ndarray
    velocity_limit: np.ndarray
    soft_velocity_limit: np.ndarray
    acceleration_limit: np.ndarray
    jerk_limit: np.ndarray
    effort_limit: np.ndarray
    motors: tuple[MotorConfig, ...]
    home: np.ndarray
    control_period: float
    physics_timestep: float
    decimation: int
    mj_model: mujoco.MjModel = field(repr=False)
    pin_model: pin.Model = field(repr=False)
    ee_frame_id: int
    ee_site_id: int
    description_hash: str

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def control_mode(self) -> str:
        """Default control mode from robot.toml: 'position', 'velocity' or 'torque'."""
        return self.config.control.mode

    def mjspec(self, mode: str | None = None) -> mujoco.MjSpec:
        """A fresh ``mujoco.MjSpec`` of the robot with its drives for ``mode``.

        Position mode: a PD servo per joint (``kp``, ``kd``). Velocity mode: a drive's PI velocity
        loop, ``tau = kd (v_cmd - dq) + kp (s - q)`` with the setpoint ``s`` the integral of the
        command (bounded to the joint range), as two actuators per joint that take the same
        command: ``<joint>_velocity`` (MuJoCo ``intvelocity`` with ``kp``: the integral term) and
        ``<joint>_velocity_p`` (MuJoCo ``velocity`` with ``kd``: the proportional term). The
        proportional term on the command matters: a servo that damps ``dq`` instead of
        ``v_cmd - dq`` lags ``a kd / kp`` behind an accelerating command (1.5 rad/s at 20 rad/s^2
        on arm3) and overshoots when it catches up. Torque mode: a direct motor. The total
        actuator torque on each joint is limited to ``effort_limit`` (MuJoCo
        ``actuatorfrcrange``). Edit the returned spec (for example to randomize link lengths)
        and ``compile()`` it; :meth:`actuators_per_joint` gives ``nu / n_joints``.

        Raises:
            RobotSpecError: unknown control mode.
        """
        mode = self.control_mode if mode is None else mode
        if mode not in CONTROL_MODES:
            raise RobotSpecError(
                f"{self.directory / 'robot.toml'}: control mode '{mode}' is unknown; "
                f"expected one of {CONTROL_MODES}"
            )
        spec = mujoco.MjSpec.from_file(str(self.mjcf_path))
        spec.option.timestep = self.physics_timestep
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET

        def add(name: str, joint: str, lo: float, hi: float) -> mujoco.MjsActuator:
            act = spec.add_actuator()
            act.name, act.target, act.trntype = name, joint, mujoco.mjtTrn.mjTRN_JOINT
            act.ctrlrange = [lo, hi]
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            return act

        for i, joint in enumerate(self.config.joints):
            mj_joint = spec.joint(joint.name)
            mj_joint.actfrcrange = [-self.effort_limit[i], self.effort_limit[i]]
            mj_joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
            lo, hi = self.position_lower[i], self.position_upper[i]
            if mode == "position":
                add(f"{joint.name}_position", joint.name, lo, hi).set_to_position(
                    kp=joint.kp, kv=joint.kd
                )
            elif mode == "torque":
                effort = self.effort_limit[i]
                add(f"{joint.name}_torque", joint.name, -effort, effort).set_to_motor()
        if mode == "velocity":  # all integral terms first, then all proportional terms
            for i, joint in enumerate(self.config.joints):
                vmax = self.velocity_limit[i]
                act = add(f"{joint.name}_velocity", joint.name, -vmax, vmax)
                act.set_to_intvelocity(kp=joint.kp, kv=0.0)
                act.actrange = [self.position_lower[i], self.position_upper[i]]
                act.actlimited = mujoco.mjtLimited.mjLIMITED_TRUE
            for i, joint in enumerate(self.config.joints):
                vmax = self.velocity_limit[i]
                add(f"{joint.name}_velocity_p", joint.name, -vmax, vmax).set_to_velocity(
                    kv=joint.kd
                )
        return spec

    def actuators_per_joint(self, mode: str | None = None) -> int:
        """Actuators per joint of :meth:`mjspec` in ``mode`` (2 in velocity mode, else 1); each
        takes the joint's command, ordered ``[all joints' first, all joints' second]``."""
        mode = self.control_mode if mode is None else mode
        return 2 if mode == "velocity" else 1

    def plant_model(self, mode: str | None = None) -> mujoco.MjModel:
        """Compiled MuJoCo model with actuators for ``mode`` (see :meth:`mjspec`)."""
        return self.mjspec(mode).compile()

    def forward_kinematics(self, q: np.ndarray) -> np.ndarray:
        """End-effector position (m, base frame), shape (3,), for one configuration ``q`` (rad)."""
        data = self.pin_model.createData()
        pin.framesForwardKinematics(self.pin_model, data, np.asarray(q, dtype=np.float64))
        return data.oMf[self.ee_frame_id].translation.copy()

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """Joint torques (N m), shape (n_joints,), that hold configuration ``q`` against gravity."""
        data = self.pin_model.createData()
        return pin.computeGeneralizedGravity(
            self.pin_model, data, np.asarray(q, dtype=np.float64)
        ).copy()


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
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RobotSpecError(f"{path}: not valid TOML: {exc}") from exc
    try:
        MotorConfig.model_validate(table)
    except ValidationError as exc:
        raise RobotSpecError(_format_validation_error(path, exc)) from None
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
        tmp = out.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, out)
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
    mj_names = tuple(mj_model.joint(i).name for i in range(mj_model.njnt))
    if mj_names != names:
        raise RobotSpecError(
            f"{toml_path}: field 'joints': names {list(names)} differ from the MJCF joints "
            f"{list(mj_names)} in {mjcf.name} (same names, same order expected)"
        )
    if any(mj_model.jnt_type[i] != mujoco.mjtJoint.mjJNT_HINGE for i in range(mj_model.njnt)):
        raise RobotSpecError(f"{mjcf}: only hinge joints are supported (a fixed-base arm)")

    lower = np.array([j.position_limit[0] for j in cfg.joints])
    upper = np.array([j.position_limit[1] for j in cfg.joints])
    for i, joint in enumerate(cfg.joints):
        if not mj_model.jnt_limited[i] or not np.allclose(
            mj_model.jnt_range[i], [lower[i], upper[i]], atol=1e-12, rtol=0
        ):
            raise RobotSpecError(
                f"{toml_path}: field 'joints[{i}].position_limit' = {list(joint.position_limit)} "
                f"differs from the MJCF range of joint '{joint.name}' "
                f"({list(mj_model.jnt_range[i]) if mj_model.jnt_limited[i] else 'unlimited'})"
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
    ee_site_id = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_SITE, site)
    if ee_site_id < 0:
        raise RobotSpecError(
            f"{toml_path}: field 'safety.end_effector_site' = '{site}' is not a site of {mjcf.name}"
        )

    pin_model = pin.buildModelFromMJCF(str(mjcf))
    pin_names = tuple(pin_model.names[1:])
    if pin_names != names:
        raise RobotSpecError(
            f"{mjcf}: Pinocchio reads joints {list(pin_names)}, expected {list(names)}"
        )
    pin_model.gravity.linear = np.array(mj_model.opt.gravity, dtype=np.float64)
    pin_model.velocityLimit = np.array([j.velocity_limit for j in cfg.joints])
    pin_model.effortLimit = np.array([j.effort_limit for j in cfg.joints])
    if not pin_model.existFrame(site):
        raise RobotSpecError(f"{mjcf}: Pinocchio has no frame for site '{site}'")
    ee_frame_id = pin_model.getFrameId(site)

    _check_agreement(mjcf, mj_model, pin_model, ee_site_id, ee_frame_id, lower, upper)

    frac = np.array([j.soft_limit_fraction for j in cfg.joints])
    centre, half = (upper + lower) / 2.0, (upper - lower) / 2.0
    # The description a policy depends on: everything but the [task] table (where goals come
    # from is the evaluation's business, not the robot's), in canonical form, and the MJCF bytes.
    # Optional fields left unset (None) are left out, so that adding one to the schema changes no
    # existing robot's hash. The MJCF is the file in the robot folder (package URIs unresolved).
    described = json.dumps(
        cfg.model_dump(exclude={"task"}, exclude_none=True, mode="json"), sort_keys=True
    )
    digest = hashlib.sha256(described.encode() + b"\0" + described_mjcf.read_bytes()).hexdigest()
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
    )


def _check_agreement(mjcf, mj_model, pin_model, site_id, frame_id, lower, upper) -> None:
    """MuJoCo and Pinocchio must agree on end-effector FK and gravity torques.

    Raises RobotSpecError beyond ``AGREEMENT_TOLERANCE``.
    """
    rng = np.random.default_rng(0)
    mj_data = mujoco.MjData(mj_model)
    pin_data = pin_model.createData()
    worst_fk = worst_g = 0.0
    for _ in range(AGREEMENT_SAMPLES):
        q = rng.uniform(lower, upper)
        mj_data.qpos[:] = q
        mj_data.qvel[:] = 0.0
        mujoco.mj_forward(mj_model, mj_data)
        pin.framesForwardKinematics(pin_model, pin_data, q)
        g = pin.computeGeneralizedGravity(pin_model, pin_data, q)
        worst_fk = max(
            worst_fk,
            float(np.max(np.abs(mj_data.site_xpos[site_id] - pin_data.oMf[frame_id].translation))),
        )
        worst_g = max(worst_g, float(np.max(np.abs(mj_data.qfrc_bias - g))))
    if worst_fk > AGREEMENT_TOLERANCE or worst_g > AGREEMENT_TOLERANCE:
        raise RobotSpecError(
            f"{mjcf}: MuJoCo and Pinocchio disagree (end-effector position {worst_fk:.3g} m, "
            f"gravity torque {worst_g:.3g} N m; tolerance {AGREEMENT_TOLERANCE})"
        )
