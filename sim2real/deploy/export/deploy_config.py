"""``policy-export --from-config``: a legged_gym / unitree_rl_gym deploy config (YAML) as the
PolicySpec, so no spec is written by hand.

unitree_rl_gym's MuJoCo deployment (``deploy/deploy_mujoco/deploy_mujoco.py`` with
``deploy/deploy_mujoco/configs/<robot>.yaml``) builds the observation of its policies as::

    obs[0:3]          = omega * ang_vel_scale              base angular velocity, base frame
    obs[3:6]          = gravity_orientation(quat)          projected gravity
    obs[6:9]          = cmd * cmd_scale                    velocity command (per axis)
    obs[9:9+n]        = (qj - default_angles) * dof_pos_scale
    obs[9+n:9+2n]     = dqj * dof_vel_scale
    obs[9+2n:9+3n]    = action                             the previous action
    obs[9+3n:9+3n+2]  = sin, cos(2 pi phase)               phase = (t mod 0.8) / 0.8

and maps the action to position targets ``action * action_scale + default_angles``, a new action
every ``control_decimation`` physics steps of ``simulation_dt``. :func:`spec_from_config` writes the
same contract in this toolkit's terms (scale = 1 / their multiplier, offset = the default pose;
``gait_phase`` of period ``GAIT_PERIOD``). :func:`read_config` reads ``kps``, ``kds``,
``default_angles`` (one per joint), ``ang_vel_scale``, ``dof_pos_scale``, ``dof_vel_scale``,
``action_scale``, ``cmd_scale`` (3), ``num_actions``, ``num_obs``, ``control_decimation``,
``simulation_dt`` and the optional ``cmd_init`` (3: the command deploy_mujoco walks with); other
keys (``policy_path``, ``xml_path``, ``simulation_duration``) are not used. The per-joint lists are
in the MJCF's joint order (deploy_mujoco reads ``qpos[7:]`` and writes ``ctrl`` in it), which is the
robot folder's (robot-import keeps the description's): entry ``i`` is ``robot.joint_names[i]``. The
robot's PD gains and home pose are compared with ``kps``, ``kds``, ``default_angles``
(:func:`sim2real.robots.pd_gains.gain_differences`).

The stack's hardware configs (``deploy/deploy_real/configs``) are read too: :func:`policy_joints`
and :func:`robot_drive`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim2real.deploy.export.errors import ExportError
from sim2real.deploy.spec.policy_spec import (
    LEGGED_ACTION_CLIP,
    ActionSpec,
    ObservationBlock,
    PolicySpec,
    SpecError,
)
from sim2real.deploy.tasks.task import follows_velocity_commands
from sim2real.robots import Robot, load_robot
from sim2real.robots.pd_gains import gain_differences, write_gains

#: The gait clock's period, s: ``period = 0.8`` in unitree_rl_gym's deploy_mujoco.py (the phase
#: its policies were trained with, legged_gym/envs/<robot>/<robot>_env.py).
GAIT_PERIOD = 0.8
#: Observation clip (normalized units): legged_gym's LeggedRobotCfg.normalization
#: .clip_observations, the clip of training; deploy_mujoco itself does not clip.
OBSERVATION_CLIP = 100.0
#: Entries besides the three per-joint blocks: angular velocity, gravity, command (3 each) and
#: the phase's sin and cos.
FIXED_ENTRIES = 3 + 3 + 3 + 2
_SCALARS = ("ang_vel_scale", "dof_pos_scale", "dof_vel_scale", "action_scale", "simulation_dt")
_JOINT_LISTS = ("kps", "kds", "default_angles")


@dataclass(frozen=True)
class DeployConfig:
    """A unitree_rl_gym deploy config, checked: SI units, radians.

    Attributes:
        path: The file. kps: (n,) N m/rad. kds: (n,) N m s/rad. default_angles: (n,) rad.
        ang_vel_scale, dof_pos_scale, dof_vel_scale, action_scale: Their multipliers (> 0).
        cmd_scale: (3,) multipliers of vx, vy, yaw rate. num_actions, num_obs: Sizes.
        control_decimation: Physics steps a control tick. simulation_dt: Physics step, s.
        cmd_init: (3,) the initial command (vx, vy m/s, yaw rate rad/s), or None.
        control_dt: s, a hardware config's control period (``simulation_dt`` is then that and
            ``control_decimation`` 1: the config names no physics step), or None.
        motor_index: (num_actions,) the motor slot of each policy joint
            (``leg_joint2motor_idx``), or None (joint ``i`` is the robot's joint ``i``).
        held: The joints the policy does not drive, held by the deploy code: ``(slots, kps,
            kds, targets)`` from ``arm_waist_joint2motor_idx``, ``arm_waist_kps``,
            ``arm_waist_kds``, ``arm_waist_target``; None when the config has none.
    """

    path: Path
    kps: np.ndarray
    kds: np.ndarray
    default_angles: np.ndarray
    ang_vel_scale: float
    dof_pos_scale: float
    dof_vel_scale: float
    action_scale: float
    cmd_scale: np.ndarray
    num_actions: int
    num_obs: int
    control_decimation: int
    simulation_dt: float
    cmd_init: np.ndarray | None
    control_dt: float | None = None
    motor_index: tuple[int, ...] | None = None
    held: tuple[tuple[int, ...], np.ndarray, np.ndarray, np.ndarray] | None = None

    @property
    def control_rate(self) -> float:
        """Hz, ``1 / (simulation_dt * control_decimation)``."""
        return 1.0 / (self.simulation_dt * self.control_decimation)


def _bad(path: Path, field: str, expected: str, got) -> ExportError:
    return ExportError(f"{path}: field '{field}': expected {expected}, got {got!r}")


def _positive(path: Path, raw: dict, field: str) -> float:
    value = raw.get(field)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _bad(path, field, "a number > 0", value)
    if not (math.isfinite(value) and value > 0):
        raise _bad(path, field, "a finite number > 0", value)
    return float(value)


def _integer(path: Path, raw: dict, field: str) -> int:
    value = raw.get(field)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise _bad(path, field, "an integer >= 1", value)
    return value


def _numbers(path: Path, raw: dict, field: str, size: int, positive: bool = False) -> np.ndarray:
    value = raw.get(field)
    kind = f"a list of {size} {'positive ' if positive else ''}numbers"
    if not isinstance(value, list) or len(value) != size:
        got = f"{len(value)} entries" if isinstance(value, list) else value
        raise _bad(path, field, kind, got)
    if any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
        raise _bad(path, field, kind, value)
    arr = np.array(value, dtype=np.float64)
    if not np.isfinite(arr).all() or (positive and not (arr > 0).all()):
        raise _bad(path, field, kind, value)
    return arr


def _slots(path: Path, raw: dict, field: str, size: int | None = None) -> tuple[int, ...]:
    value = raw.get(field)
    kind = "a list of distinct motor slots (integers >= 0)" + (
        f", {size} of them" if size is not None else ""
    )
    if (
        not isinstance(value, list)
        or (size is not None and len(value) != size)
        or any(isinstance(v, bool) or not isinstance(v, int) or v < 0 for v in value)
        or len(set(value)) != len(value)
    ):
        raise _bad(path, field, kind, value)
    return tuple(value)


def _rate(path: Path, raw: dict) -> tuple[float, int, float | None]:
    """``(simulation_dt, control_decimation, control_dt)``; a deploy_real config's
    ``control_dt`` is one step of one physics step each, else ``control_dt`` is None."""
    if "simulation_dt" not in raw and "control_decimation" not in raw and "control_dt" in raw:
        dt = _positive(path, raw, "control_dt")
        return dt, 1, dt
    return _positive(path, raw, "simulation_dt"), _integer(path, raw, "control_decimation"), None


def read_config(path: str | Path) -> DeployConfig:
    """Read and check a deploy config (module docstring).

    Raises:
        ExportError: a missing file, invalid YAML, a missing or invalid field (the message names
            the file, the field and what is expected), or ``num_obs`` that is not the layout's
            ``11 + 3 num_actions``.
    """
    import yaml

    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ExportError(f"{path}: cannot read the deploy config: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ExportError(f"{path}: not valid YAML: {first}") from None
    if not isinstance(raw, dict):
        raise ExportError(f"{path}: expected a YAML mapping of deploy settings (kps, kds, ...)")
    n = _integer(path, raw, "num_actions")
    lists = {f: _numbers(path, raw, f, n, positive=f == "kps") for f in _JOINT_LISTS}
    if (lists["kds"] < 0).any():
        raise _bad(path, "kds", f"a list of {n} numbers >= 0", raw["kds"])
    num_obs = _integer(path, raw, "num_obs")
    expected = FIXED_ENTRIES + 3 * n
    if num_obs != expected:
        raise ExportError(
            f"{path}: field 'num_obs': expected {expected} (deploy_mujoco's layout for "
            f"num_actions {n}: angular velocity 3, gravity 3, command 3, joint positions, "
            f"velocities and last action {n} each, gait phase 2), got {num_obs}"
        )
    cmd_init = raw.get("cmd_init")
    motor_index = None
    if "leg_joint2motor_idx" in raw:
        motor_index = _slots(path, raw, "leg_joint2motor_idx", n)
    held = None
    if "arm_waist_joint2motor_idx" in raw:
        slots = _slots(path, raw, "arm_waist_joint2motor_idx")
        if set(slots) & set(motor_index or range(n)):
            raise _bad(path, "arm_waist_joint2motor_idx", "slots no policy joint drives", slots)
        k = len(slots)
        held = (
            slots,
            _numbers(path, raw, "arm_waist_kps", k, positive=True),
            _numbers(path, raw, "arm_waist_kds", k),
            _numbers(path, raw, "arm_waist_target", k),
        )
    simulation_dt, decimation, control_dt = _rate(path, raw)
    return DeployConfig(
        path=path,
        kps=lists["kps"],
        kds=lists["kds"],
        default_angles=lists["default_angles"],
        **{f: _positive(path, raw, f) for f in _SCALARS if f != "simulation_dt"},
        simulation_dt=simulation_dt,
        cmd_scale=_numbers(path, raw, "cmd_scale", 3, positive=True),
        num_actions=n,
        num_obs=num_obs,
        control_decimation=decimation,
        cmd_init=None if cmd_init is None else _numbers(path, raw, "cmd_init", 3),
        control_dt=control_dt,
        motor_index=motor_index,
        held=held,
    )


def _joint_of_slot(config: DeployConfig, robot: Robot, slot: int, field: str) -> int:
    """The robot joint (index) of motor slot ``slot`` (module docstring)."""
    unitree = robot.config.unitree
    if unitree is not None and unitree.motor_index:
        if slot in unitree.motor_index:
            return list(unitree.motor_index).index(slot)
        raise ExportError(
            f"{config.path}: field '{field}': motor slot {slot} drives no joint of the robot "
            f"'{robot.name}' (robot.toml [unitree] motor_index {list(unitree.motor_index)})"
        )
    raise ExportError(
        f"{config.path}: field '{field}': motor slot {slot}, but the robot '{robot.name}' has "
        "no motor slots to find it among (robot.toml [unitree] motor_index): import it with "
        "robot-import --unitree FAMILY; a slot is never read as a joint's index"
    )


def policy_joints(config: DeployConfig, robot: Robot) -> list[int]:
    """The robot joint (index) of each policy joint, in the policy's order.

    A hardware config (``deploy/deploy_real/configs/<robot>.yaml``, read by ``deploy_real.py``)
    gives the rate as ``control_dt`` (s) instead of ``simulation_dt`` and
    ``control_decimation``, and the motor slot of policy joint ``i`` as
    ``leg_joint2motor_idx[i]``: the robot joint whose ``robot.toml`` ``[unitree] motor_index``
    is that slot (a robot without one is refused). Without it, joint ``i`` is the
    robot's joint ``i``. A robot with more joints than the policy drives (the 29-joint G1 under
    unitree_rl_gym's 12-joint policy) runs it with the others held (:mod:`sim2real.deploy.spec.subset`).
    """
    if config.motor_index is None:
        return list(range(config.num_actions))
    return [_joint_of_slot(config, robot, s, "leg_joint2motor_idx") for s in config.motor_index]


def robot_drive(config: DeployConfig, robot: Robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(kp, kd, home)`` over every joint of ``robot`` as the config's deploy code drives it:
    its ``kps``, ``kds``, ``default_angles`` on the policy's joints; on the joints it holds,
    ``deploy_real.py``'s ``arm_waist_kps``, ``arm_waist_kds``, ``arm_waist_target`` (slots
    ``arm_waist_joint2motor_idx``); the robot's own values on any other. Compared with (or
    written into) the robot's kp, kd and home by :func:`spec_and_robot`."""
    kp = np.array([j.kp for j in robot.config.joints], dtype=np.float64)
    kd = np.array([j.kd for j in robot.config.joints], dtype=np.float64)
    home = np.array(robot.home, dtype=np.float64)
    index = policy_joints(config, robot)
    kp[index], kd[index], home[index] = config.kps, config.kds, config.default_angles
    if config.held is not None:
        slots, kps, kds, targets = config.held
        held = [_joint_of_slot(config, robot, s, "arm_waist_joint2motor_idx") for s in slots]
        kp[held], kd[held], home[held] = kps, kds, targets
    return kp, kd, home


def check_robot(config: DeployConfig, robot: Robot) -> None:
    """Refuse a robot the config does not describe.

    Raises:
        ExportError: a fixed-base robot, another joint count, a default angle outside its
            joint's limits, or another control rate (the message names the config field and the
            robot's value).
    """
    path, n = config.path, config.num_actions
    where = f"the robot '{robot.name}' ({robot.directory})"
    if not follows_velocity_commands(robot):  # a legged_gym config's robot walks
        raise ExportError(f"{path}: a legged_gym deploy config, but {where} has a fixed base")
    if config.motor_index is None and n != robot.n_joints:
        raise ExportError(
            f"{path}: field 'num_actions': {n} joints, {where} has {robot.n_joints} "
            f"({', '.join(robot.joint_names)}); a policy over some of them needs "
            "'leg_joint2motor_idx' (deploy_real's configs), the motor slot of each"
        )
    lo, hi = robot.position_lower, robot.position_upper
    index = policy_joints(config, robot)
    for k, (i, a) in enumerate(zip(index, config.default_angles, strict=True)):
        if not lo[i] <= a <= hi[i]:
            name = robot.joint_names[i]
            raise ExportError(
                f"{path}: field 'default_angles'[{k}] = {a:g} rad is outside the limits "
                f"[{lo[i]:g}, {hi[i]:g}] of {name}, joint {i} of {where}: the config's joints "
                "are in the robot's joint order (or leg_joint2motor_idx's)"
            )
    rate = 1.0 / robot.control_period
    if abs(config.control_rate - rate) > 1e-6 * rate:
        raise ExportError(
            f"{path}: fields 'simulation_dt' x 'control_decimation' = "
            f"{config.simulation_dt:g} x {config.control_decimation}: a control rate of "
            f"{config.control_rate:g} Hz, {where} runs at {rate:g} Hz (robot.toml "
            f"control.control_rate; robot-import --control-rate {config.control_rate:g})"
        )


def spec_from_config(config: DeployConfig, robot: Robot) -> PolicySpec:
    """The PolicySpec of deploy_mujoco's observation and action for ``robot`` (module
    docstring); ``robot_hash`` is left empty (a policy trained elsewhere never saw this
    description; name, joint order and control rate are still checked).

    Raises:
        ExportError: the robot does not fit the config (:func:`check_robot`).
    """
    check_robot(config, robot)
    n = config.num_actions
    joints = tuple(range(n))
    default = tuple(float(a) for a in config.default_angles)
    clip = OBSERVATION_CLIP

    def block(name, size, scale, offset=None, **kw):
        scale = tuple(float(s) for s in np.broadcast_to(scale, size))
        offset = (0.0,) * size if offset is None else offset
        return ObservationBlock(name, size, scale, offset, clip, **kw)

    blocks = (
        block("base_angular_velocity", 3, 1.0 / config.ang_vel_scale),
        block("projected_gravity", 3, 1.0),
        block("velocity_command", 3, 1.0 / config.cmd_scale),
        block("joint_position", n, 1.0 / config.dof_pos_scale, default, joints=joints),
        block("joint_velocity", n, 1.0 / config.dof_vel_scale, joints=joints),
        block("last_action", n, 1.0, joints=joints),
        block("gait_phase", 2, 1.0, period=GAIT_PERIOD),
    )
    spec = PolicySpec(
        robot=robot.name,
        joint_names=tuple(robot.joint_names[i] for i in policy_joints(config, robot)),
        robot_hash="",
        observation_blocks=blocks,
        action=ActionSpec(
            mode="position",
            size=n,
            scale=(float(config.action_scale),) * n,
            offset=default,
            clip=LEGGED_ACTION_CLIP,
        ),
        control_rate=1.0 / robot.control_period,  # the config's, within check_robot's bound
    )
    try:
        spec.validate()
    except SpecError as exc:  # pragma: no cover - the checks above cover the fields
        raise ExportError(f"{config.path}: {exc}") from None
    if spec.obs_dim != config.num_obs:  # pragma: no cover - read_config checked the layout
        raise ExportError(f"{config.path}: num_obs {config.num_obs}, the spec has {spec.obs_dim}")
    return spec


def _load_robot(robot: Robot | str | Path) -> Robot:
    if isinstance(robot, Robot):
        return robot
    try:
        return load_robot(robot)
    except Exception as exc:  # noqa: BLE001 - RobotSpecError, FileNotFoundError, ...
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ExportError(f"--robot {robot}: cannot load the robot: {first}") from None


def spec_and_robot(
    config_path: str | Path, robot: Robot | str | Path, write_robot: bool = False
) -> tuple[PolicySpec, Robot, list[str]]:
    """``--from-config``: the spec of a deploy config for a robot folder, the robot's PD gains
    and home pose checked against the config's (and written into its robot.toml with
    ``write_robot``).

    Args:
        config_path: The deploy config (YAML). robot: The robot folder (or a loaded Robot).
        write_robot: Write the config's ``kps``, ``kds``, ``default_angles`` into the robot's
            robot.toml where they differ (:func:`sim2real.robots.pd_gains.write_gains`).

    Returns:
        ``(spec, robot, notes)``: the robot as loaded after any write; notes for the user (what
        was written, a physics step that differs from the config's ``simulation_dt``).

    Raises:
        ExportError: an invalid config, a robot it does not describe (:func:`check_robot`), or
            gains or home that differ without ``write_robot`` (the first few named).
    """
    config = read_config(config_path)
    robot = _load_robot(robot)
    check_robot(config, robot)
    toml = robot.directory / "robot.toml"
    kp, kd, home = robot_drive(config, robot)
    diffs = gain_differences(robot, kp, kd, home)
    notes = []
    if diffs and not write_robot:
        more = f" and {len(diffs) - 3} more" if len(diffs) > 3 else ""
        raise ExportError(
            f"{config.path}: kps, kds or default_angles differ from {toml}: "
            f"{'; '.join(str(d) for d in diffs[:3])}{more}; pass --write-robot to write the "
            "config's values into robot.toml"
        )
    if diffs:
        try:
            robot = write_gains(
                robot,
                kp,
                kd,
                home,
                f"{config.path.name} (policy-export --from-config --write-robot)",
            )
        except Exception as exc:  # noqa: BLE001 - RobotSpecError, OSError
            raise ExportError(f"--write-robot: {exc}") from None
        fields = sorted({d.field for d in diffs})
        joints = len({d.joint for d in diffs})
        notes.append(
            f"wrote {', '.join(fields)} of {joints} joint(s) into {toml} from {config.path.name}"
        )
    if config.control_dt is None and abs(robot.physics_timestep - config.simulation_dt) > 1e-12:
        notes.append(
            f"note: the robot's physics step is {robot.physics_timestep:g} s, the config's "
            f"simulation_dt {config.simulation_dt:g} s (the PD runs at the physics step)"
        )
    return spec_from_config(config, robot), robot, notes
