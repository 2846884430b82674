"""robot.toml of a floating-base (legged) robot: :func:`write_legged_toml`, every value with the
reason for it in a comment (the sensors' noise, the foot contact threshold, the soak's pushes),
as :mod:`sim2real.robots.importer.legged` imports the robot.
"""

from __future__ import annotations

import math
import shlex
from pathlib import Path

from sim2real.robots.importer.floating_mjcf import FREE_JOINT, IMU_SITE
from sim2real.robots.importer.model import Motion, _sig
from sim2real.robots.importer.source import PreparedSource
from sim2real.robots.importer.toml_text import (
    _f,
    all_joint_lines,
    control_lines,
    motor_table_lines,
    pairs_lines,
    sensor_lines,
    sources_lines,
)
from sim2real.robots.importer.wheels import kind_lines, wheel_joints

#: Normalizers of the seed's IMU noise figures (section 5 gives sigma on normalized readings):
#: angular rate over 4 rad/s (legged_gym's ``obs_scales.ang_vel = 0.25``, i.e. 1 / 4 rad/s),
#: acceleration over standard gravity.
ANGULAR_RATE_SCALE = 4.0  # rad/s
ACCELERATION_SCALE = 9.80665  # m/s^2
#: Default IMU white noise: the middle of the specified ranges (angular rate 0.01-0.03,
#: linear acceleration 0.03-0.08, normalized).
GYRO_NOISE_SIGMA = 0.02 * ANGULAR_RATE_SCALE  # 0.08 rad/s
ACCEL_NOISE_SIGMA = 0.055 * ACCELERATION_SCALE  # 0.54 m/s^2
#: Turn-on bias, 1 sigma: a calibrated MEMS IMU of the Bosch BMI088 class (datasheet
#: BST-BMI088-DS001: zero-rate offset +-1 deg/s, zero-g offset +-20 mg typical); we take
#: 0.01 rad/s and 0.05 m/s^2 (about 5 mg, after the user's level calibration).
GYRO_BIAS_SIGMA = 0.01  # rad/s
ACCEL_BIAS_SIGMA = 0.05  # m/s^2
#: Bias random walk: Kalibr's ADIS16448 example (gyroscope_random_walk 3.9e-5 rad/s^2/sqrt(Hz),
#: accelerometer_random_walk 4.3e-4 m/s^3/sqrt(Hz)) inflated 10x for a robot's vibration and
#: temperature, as Kalibr's "IMU Noise Model" page advises for real conditions.
GYRO_BIAS_WALK = 4e-4  # rad/s/sqrt(s)
#: rad/s, the noise of the joint velocity a drive reports (our estimate: a rotor encoder's count
#: differenced at a 1 kHz or faster current loop and filtered, through the gear).
VELOCITY_NOISE_SIGMA = 0.02
#: The IMU's own attitude: roll and pitch error (rad, 0.5 deg: Xsens MTi-3 datasheet, static) and
#: its correlation time (s, our choice).
ORIENTATION_SIGMA = 0.0087
ORIENTATION_TAU = 1.0
#: Its heading's drift (a 6-axis AHRS, no magnetometer): the residual yaw-rate bias once the
#: filter has calibrated its gyroscope at rest, 1 sigma, the in-run bias stability of the Xsens
#: MTi-1 series (MTi-3) datasheet, 10 deg/h; the heading's angle random walk, its gyroscope
#: noise density, 0.007 deg/s/sqrt(Hz).
HEADING_RATE_SIGMA = 10.0 * math.pi / 180.0 / 3600.0  # 4.85e-5 rad/s
HEADING_WALK = 0.007 * math.pi / 180.0  # 1.22e-4 rad/sqrt(s)
ACCEL_BIAS_WALK = 4e-3  # m/s^2/sqrt(s)
#: Foot force noise: the specified range (force sensors 0.05-0.10 normalized), the lower end, over
#: the standing load of one foot (m g / n_feet). Contact threshold: 3 sigma above it, and at
#: least 5 N.
FORCE_NOISE_FRACTION = 0.05
CONTACT_THRESHOLD_SIGMAS = 3.0
#: The soak's pushes on the base (``[soak] push_force``): the largest gives the robot legged_gym's
#: largest push, a base velocity change of ``PUSH_VELOCITY`` (unitree_rl_gym
#: LeggedRobotCfg.domain_rand.max_push_vel_xy), over the longest push, ``PUSH_TIME`` (eval.
#: fault_schedule.FaultRanges.push_duration); the smallest ``PUSH_LOW`` of it (our choice).
PUSH_VELOCITY = 1.0  # m/s
PUSH_TIME = 0.5  # s
PUSH_LOW = 0.2


#: robot.toml's comment on the joints' acceleration and jerk limits.
_LIMITS_COMMENT = (
    "# acceleration_limit: 0.5 x (effort - worst gravity torque) / worst joint inertia with",
    "# armature (rotor inertia x ratio^2), base held, 400 seeded poses; jerk_limit: 20 x",
    "# acceleration. kp, kd: see the comment of each joint.",
)
#: ... and on a PD-target robot's (``--target-limits pd``, :func:`~sim2real.robots.importer.
#: legged.pd_target_limits`).
_PD_TARGET_COMMENT = (
    "# PD targets (robot-import --target-limits pd): acceleration_limit at least",
    "# 4 x (effort / kp) / control_period^2 and jerk_limit at least acceleration_limit /",
    "# (0.5 x control_period): a target may move, rest to rest within one control period,",
    "# as far as the drive's full torque reaches (effort / kp), as a policy trained",
    "# without a smoother steps it; command_velocity_limit, the target's speed in that",
    "# move, 2 x (effort / kp) / control_period (the joint's own stays velocity_limit).",
)
_VELOCITY_NOISE_COMMENT = (
    "# the joint velocity each drive reports with its angle (Unitree's motor_state.dq, from",
    "# its rotor encoder at the current loop's rate): white noise, our estimate. Delete the",
    "# line if the drives report none.",
)


def write_legged_toml(
    path: Path,
    *,
    name: str,
    prepared: PreparedSource,
    mjcf: str,
    joint_names: list[str],
    limits: dict,
    motion: Motion,
    gains_from: dict[str, tuple[str, str]],
    chosen: dict[str, str],
    motor_cfg: dict,
    pairs: list,
    legged: dict,
    imu_link: str,
    mass: float,
    control_rate: float,
    physics_timestep: float,
    home_from: str,
    disabled_by: str | None,
    lowered: list,
    notes: list[str],
    command: list[str],
    motor_tables: dict | None = None,
    target_limits: str = "pd",
    tables: list[str] = (),
    rates_from: tuple[str, str] = ("--control-rate", "--physics-timestep"),
    pairs_apart: list = (),
) -> None:
    """robot.toml of a floating-base robot, a comment giving the reason of every value.

    ``gains_from``: joint -> where its kp and its kd came from
    (:meth:`sim2real.robots.importer.drive_sources.DriveChoice.gains_note`); ``notes``:
    ``--note`` lines for the header (sources of flag values); ``command``: the command line
    that regenerates the folder; ``motor_tables``: the motors given as files
    (:func:`sim2real.robots.importer.model.motor_table_lines`); ``tables``: lines of more tables,
    at the end (``[unitree]``: :mod:`sim2real.robots.importer.unitree`); ``rates_from``,
    ``pairs_apart``: as :func:`sim2real.robots.importer.toml_text.write_robot_toml`'s.
    """
    motor_tables = motor_tables or {}
    resolution = min(motor_cfg[m].encoder_resolution or 16384 for m in set(chosen.values()))
    quantum = 2 * math.pi / resolution
    feet = legged["feet"]
    lines = [
        *_header_lines(name, prepared, command, notes),
        *control_lines(
            name,
            mjcf,
            "joint position targets, PD at the physics rate",
            (control_rate, physics_timestep),
            home_from,
            motion.home,
            kind_lines(wheel_joints(joint_names, limits)),
            rates_from=rates_from,
        ),
        *_LIMITS_COMMENT,
        *(_PD_TARGET_COMMENT if target_limits == "pd" else ()),
    ]
    lines += all_joint_lines(joint_names, limits, prepared, lowered, motion, chosen, gains_from)
    lines += [
        "",
        *sensor_lines(chosen, resolution, quantum, control_rate, "degC", motor_tables),
        *_VELOCITY_NOISE_COMMENT,
        f"velocity_noise_sigma = {_f(VELOCITY_NOISE_SIGMA)}  # rad/s",
        "",
        *_imu_lines(imu_link, control_rate),
        *_contact_lines(mass, len(feet), control_rate),
        "[safety]",
        "# No end effector and no workspace box: a legged robot walks anywhere.",
        *pairs_lines(disabled_by, pairs, floor=True, apart=pairs_apart),
        "",
        *_base_and_soak_lines(prepared, legged, mass),
        *motor_table_lines(motor_tables),
        *tables,
        "",
    ]
    path.write_text("\n".join(lines), encoding="utf-8")


def _header_lines(name: str, prepared: PreparedSource, command: list[str], notes: list[str]):
    """robot.toml's first comment lines: its source, the command that regenerates it, the
    sources of its values and the ``--note`` lines."""
    return [
        f"# {name}: imported by robot-import --floating-base from {prepared.display}.",
        "# Regenerate with (from the repository root):",
        "#   " + " ".join(shlex.quote(a) for a in command),
        *sources_lines(prepared.kind),
        *[f"# {line}" for note in notes for line in note.splitlines()],
    ]


def _imu_lines(imu_link: str, control_rate: float) -> list[str]:
    """robot.toml's ``[sensors.imu]``, the source of each value in a comment."""
    return [
        "# IMU at site 'imu' (link " + imu_link + "): Kalibr's noise model (robots/schema.py).",
        "[sensors.imu]",
        "# specified noise: angular rate sigma 0.01-0.03 over 4 rad/s (legged_gym ang_vel scale",
        "# 0.25), linear acceleration 0.03-0.08 over g; the middle of each range",
        f"gyro_noise_sigma = {_f(_sig(GYRO_NOISE_SIGMA, 3))}  # rad/s",
        f"accel_noise_sigma = {_f(_sig(ACCEL_NOISE_SIGMA, 3))}  # m/s^2",
        "# turn-on bias: BMI088-class MEMS (datasheet BST-BMI088-DS001: +-1 deg/s, +-20 mg",
        "# typical), after a level calibration",
        f"gyro_bias_sigma = {_f(GYRO_BIAS_SIGMA)}  # rad/s",
        f"accel_bias_sigma = {_f(ACCEL_BIAS_SIGMA)}  # m/s^2",
        "# bias random walk: Kalibr's ADIS16448 example x 10 (Kalibr wiki, 'IMU Noise Model')",
        f"gyro_bias_walk = {_f(GYRO_BIAS_WALK)}  # rad/s/sqrt(s)",
        f"accel_bias_walk = {_f(ACCEL_BIAS_WALK)}  # m/s^2/sqrt(s)",
        f"rate = {_f(control_rate)}  # Hz, one reading a control tick",
        "latency_ticks = 0",
        "dropout = 0.0",
        "# The IMU's own attitude, as a legged robot's AHRS sends it (Unitree's LowState",
        "# imu_state.quaternion, the attitude unitree_rl_gym's deploy_real feeds its policies):",
        "# roll and pitch errors as first-order Gauss-Markov processes (robots/schema.py); the",
        "# static roll/pitch accuracy MEMS AHRS modules specify (Xsens MTi-3 datasheet: 0.5 deg;",
        "# dynamic 1.0 deg), 1 s correlation. Delete these four lines if the IMU sends no",
        "# attitude. Its heading drifts as a 6-axis AHRS's (no magnetometer, as Unitree's): a",
        "# residual yaw-rate bias, the MTi-3's in-run bias stability (10 deg/h), and the angle",
        "# random walk of its gyroscope's noise density (0.007 deg/s/sqrt(Hz)). A motion-tracking",
        "# policy's anchor reads this attitude (docs/motion-tracking.md).",
        f"orientation_sigma = {_f(ORIENTATION_SIGMA)}  # rad",
        f"orientation_tau = {_f(ORIENTATION_TAU)}  # s",
        f"heading_rate_sigma = {_f(_sig(HEADING_RATE_SIGMA, 3))}  # rad/s",
        f"heading_walk = {_f(_sig(HEADING_WALK, 3))}  # rad/sqrt(s)",
        "",
    ]


def _contact_lines(mass: float, n_feet: int, control_rate: float) -> list[str]:
    """robot.toml's ``[sensors.contact]``: force noise from a foot's standing load."""
    load = mass * ACCELERATION_SCALE / n_feet
    force_sigma = _sig(FORCE_NOISE_FRACTION * load, 2)
    threshold = _sig(max(5.0, CONTACT_THRESHOLD_SIGMAS * force_sigma), 2)
    return [
        "# Foot contact: the touch sensor's normal force (N) + noise, thresholded.",
        "[sensors.contact]",
        f"# noise: the specified force noise (0.05-0.10 normalized) x the standing load of a foot, "
        f"{load:.1f} N",
        f"force_noise_sigma = {_f(force_sigma)}  # N",
        f"threshold = {_f(threshold)}  # N, {CONTACT_THRESHOLD_SIGMAS:g} noise sigmas, >= 5 N",
        f"rate = {_f(control_rate)}  # Hz",
        "latency_ticks = 0",
        "",
    ]


def _base_and_soak_lines(prepared: PreparedSource, legged: dict, mass: float) -> list[str]:
    """robot.toml's ``[base]`` (body, IMU site, feet, standing height) and ``[soak]`` (the
    pushes, from legged_gym's largest)."""
    feet = legged["feet"]
    push = mass * PUSH_VELOCITY / PUSH_TIME  # N, the soak's largest push
    return [
        "[base]",
        f'body = "{prepared.root_link}"  # carries the free joint "{FREE_JOINT}"',
        f'imu_site = "{IMU_SITE}"',
        "# foot sites (touch sensors) around each foot's collision geometry:",
        *[f"#   {f}: {legged['foot_shapes'][f]}" for f in feet],
        "feet = [" + ", ".join(f'"{f}"' for f in feet) + "]",
        f"standing_height = {_f(legged['standing_height'])}  # m, base above the floor at home",
        "",
        "[soak]",
        "# Pushes on the base: up to the impulse of legged_gym's largest push (a "
        f"{PUSH_VELOCITY:g} m/s base velocity",
        "# change, unitree_rl_gym LeggedRobotCfg.domain_rand.max_push_vel_xy) delivered over the "
        "longest",
        f"# push ({PUSH_TIME:g} s): {mass:.1f} kg x {PUSH_VELOCITY:g} m/s / {PUSH_TIME:g} s; the "
        f"low end {PUSH_LOW:g} of it.",
        f"push_force = [{_f(_sig(PUSH_LOW * push))}, {_f(_sig(push))}]  # N",
    ]
