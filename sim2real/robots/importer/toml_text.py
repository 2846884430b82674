"""robot.toml as the importer writes it: the tables and the comment giving the reason of every
value (:func:`write_robot_toml` for a fixed-base arm; :mod:`sim2real.robots.importer.legged` writes a
floating-base robot's with the same joint, sensor and motor lines)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from sim2real.robots.importer.model import SOFT_LIMIT_FRACTION, TASK_JOINT_FRACTION, Motion, _sig
from sim2real.robots.importer.source import PreparedSource


def _f(x: float) -> str:
    return repr(float(x) + 0.0)  # + 0.0: -0.0 reads 0.0


def _vec(v) -> str:
    return "[" + ", ".join(_f(round(float(x), 4)) for x in v) + "]"


def limit_notes(joint: str, src, low: dict) -> tuple[str, str]:
    """The robot.toml comments of a joint's velocity and effort limits: where each came from
    (the source description, or the motor's no-load speed / peak torque when that is lower or
    the source gives none). ``src``: the joint of the prepared source; ``low``: (joint,
    quantity) -> (source value, ...) of the limits the motor capped (:func:`cap_limits`)."""
    return tuple(
        f"motor {what} ({origin} {low[(joint, q)][0]:g})"
        if (joint, q) in low
        else (f"motor {what}" if value is None or value <= 0 else origin)
        for q, what, value, origin in (
            ("velocity", "no-load speed", src.velocity, src.velocity_from),
            ("effort", "peak torque", src.effort, src.effort_from),
        )
    )


def joint_lines(
    j: str, i: int, limits, kind: str, notes, motion: Motion, motor: str, gains_note=None
) -> list[str]:
    """The ``[[joints]]`` table of joint ``j`` (index ``i``) in robot.toml: ``limits`` (lower,
    upper rad, velocity rad/s, effort N m) with the source ``kind`` and the velocity/effort
    ``notes`` (:func:`limit_notes`), the derived motion limits and gains of ``motion``, and an
    optional source note on the gains (one for both, or ``(kp's, kd's)``)."""
    lo, hi, vel, eff = limits
    vnote, enote = notes
    kp, kd = f"kp = {_f(motion.kp[i])}", f"kd = {_f(motion.kd[i])}"
    if gains_note:
        kp_note, kd_note = (gains_note, gains_note) if isinstance(gains_note, str) else gains_note
        kp, kd = f"{kp}  # N m/rad, {kp_note}", f"{kd}  # N m s/rad, {kd_note}"
    command = (
        []
        if motion.command_velocity is None or motion.kp[i] == 0  # kp 0: no PD target
        else [f"command_velocity_limit = {_f(motion.command_velocity[i])}  # rad/s, PD target"]
    )
    return [
        "",
        "[[joints]]",
        f'name = "{j}"',
        (
            f"continuous = true  # no position limit ({kind}): speed and torque are checked"
            if math.isinf(lo) or math.isinf(hi)
            else f"position_limit = [{_f(lo)}, {_f(hi)}]  # {kind}"
        ),
        f"velocity_limit = {_f(vel)}  # rad/s, {vnote}",
        *command,
        f"acceleration_limit = {_f(motion.acceleration[i])}",
        f"jerk_limit = {_f(motion.jerk[i])}",
        f"effort_limit = {_f(eff)}  # N m, {enote}",
        f"soft_limit_fraction = {SOFT_LIMIT_FRACTION}",
        f'motor = "{motor}"',
        *(
            ['drive = "velocity"  # kp 0: a speed target, tau = kd (v_target - dq)']
            if motion.kp[i] == 0
            else []
        ),
        kp,
        kd,
    ]


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # JSON's escapes are TOML basic-string escapes
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML form for {value!r}")


def motor_table_lines(tables: dict[str, tuple[Path, dict]]) -> list[str]:
    """``[motors.NAME]`` tables of robot.toml for the motors given as files (``--motor
    JOINT=path.toml``): ``tables`` maps the name to (file, its validated table)."""
    lines: list[str] = []
    for name, (path, table) in sorted(tables.items()):
        lines += ["", f"# motor {name}: from {path} (--motor JOINT=FILE)"]
        lines += _table_lines(f"motors.{name}", table)
    return lines


def _table_lines(header: str, table: dict) -> list[str]:
    """``[header]``, its keys, then its sub-tables (``[header.key]``), recursively."""
    nested = {k: v for k, v in table.items() if isinstance(v, dict)}
    lines = [f"[{header}]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in table.items() if k not in nested]
    for key, sub in nested.items():
        lines += _table_lines(f"{header}.{key}", sub)
    return lines


def sensor_lines(
    chosen, resolution: int, quantum: float, control_rate: float, temp_note: str, files=()
):
    """The motor-catalog comment and the ``[sensors]`` encoder and temperature lines of
    robot.toml: one encoder count of noise at the coarsest motor encoder, read every tick.
    ``files``: the motors given as files (their tables close robot.toml)."""
    catalog = sorted(set(chosen.values()) - set(files))
    where = []
    if catalog:
        where.append("Motors " + ", ".join(catalog) + ": the catalog, robots/motors/.")
    if files:
        where.append("Motors " + ", ".join(sorted(files)) + ": [motors.*] tables at the end.")
    return [
        "# " + " ".join(where),
        "",
        "[sensors]",
        f"encoder_resolution = {resolution}  # counts/rev, the coarsest motor encoder",
        f"encoder_noise_sigma = {_f(_sig(quantum, 3))}  # rad, one encoder count",
        f"encoder_rate = {_f(control_rate)}  # Hz, read every control tick",
        "encoder_latency_ticks = 0",
        "encoder_dropout = 0.0",
        f"temperature_resolution = 1.0  # {temp_note}",
        "temperature_rate = 10.0  # Hz",
        "ambient_temperature = 25.0  # degC",
    ]


def sources_lines(kind: str) -> list[str]:
    """robot.toml's header comment on where the joint limits come from (``kind``: "URDF"...)."""
    return [
        f"# Joint order and position limits from the {kind}; velocity and effort limits are the "
        "lower",
        f"# of the {kind}'s and the motor's (robots/motors/<model>.toml); SI units, radians.",
    ]


#: robot.toml's words for where the control rate and the physics timestep came from (the
#: sources :func:`sim2real.robots.importer.pipeline.import_robot` and
#: :func:`sim2real.robots.importer.physics_option.choose_timestep` name); a flag is credited only
#: when it was given.
RATE_SOURCES = {
    "--control-rate": "robot-import --control-rate",
    "--physics-timestep": "robot-import --physics-timestep",
    "the MJCF": "the MJCF's <option timestep>",
    "the toolkit's default": "robot-import's default; --physics-timestep sets it",
    "the importer's default": "robot-import's default; --control-rate sets it",
}


def control_lines(
    name: str,
    mjcf: str,
    mode_note: str,
    rates: tuple[float, float],
    home_note: str,
    home,
    top: list[str] = (),
    rates_from: tuple[str, str] = ("--control-rate", "--physics-timestep"),
) -> list[str]:
    """robot.toml's ``name``, ``mjcf`` (then the lines ``top``: more top-level keys) and
    ``[control]`` table up to ``home`` (rad), position mode: ``mode_note`` comments the mode,
    ``rates`` are (control rate Hz, physics timestep s), ``rates_from`` where each came from
    (:data:`RATE_SOURCES`' keys, or a text of its own), ``home_note`` says where the home pose
    came from."""
    control_rate, physics_timestep = rates
    rate_from, timestep_from = (RATE_SOURCES.get(s, s) for s in rates_from)
    return [
        f'name = "{name}"',
        f'mjcf = "{mjcf}"',
        *top,
        "",
        "[control]",
        f'mode = "position"            # {mode_note}',
        f"control_rate = {_f(control_rate)}          # Hz ({rate_from})",
        f"physics_timestep = {_f(physics_timestep)}     # s ({timestep_from})",
        f"# rad: {home_note}",
        f"home = {_vec(home)}",
        "",
    ]


def all_joint_lines(
    joint_names, limits: dict, prepared: PreparedSource, lowered, motion: Motion, chosen, gains=None
) -> list[str]:
    """The ``[[joints]]`` tables (:func:`joint_lines`) of every joint in order: ``limits`` joint
    -> (lower, upper rad, velocity rad/s, effort N m), ``lowered`` the motor caps
    (``ImportReport.lowered``), ``chosen`` joint -> motor, ``gains`` joint -> the source note of
    its gains (None: no note)."""
    low = {(j, q): (a, b) for j, q, a, b, _ in lowered}
    lines = []
    for i, j in enumerate(joint_names):
        notes = limit_notes(j, prepared.joints[j], low)
        note = None if gains is None else gains[j]
        lines += joint_lines(j, i, limits[j], prepared.kind, notes, motion, chosen[j], note)
    return lines


def pairs_lines(disabled_by: str | None, pairs, floor: bool = False, apart: list = ()) -> list[str]:
    """robot.toml's ``collision_pairs`` (geom name pairs) with the comment on what left pairs
    unchecked (``disabled_by``: "the SRDF (x.srdf)", None: only adjacency) and on what the
    plant collides: the robot's bodies only in these pairs (the importer ``<exclude>``s every
    other), and there only where the MJCF's contact bits or a ``<pair>`` let the geoms touch
    (``apart``: the pairs they keep apart, :func:`sim2real.robots.importer.staging.bits_apart`);
    ``floor``: a floating-base robot's floor, whose own bits decide what touches it. Then the
    ``stale_limit``."""
    shown = [f"{a}|{b}" for a, b in apart[:3]] + (
        [f"{len(apart) - 3} more"] if len(apart) > 3 else []
    )
    never = (
        f" {len(apart)} of these pairs never touch there, the guard checks them all ({shown})."
        if apart
        else ""
    )
    return [
        (
            f"# Geom pairs of links {disabled_by} does not disable, "
            if disabled_by
            else "# Geom pairs of non-adjacent links, "
        )
        + "apart at home: the guard checks these.",
        "# The plant (MuJoCo) collides two of the robot's bodies only in these pairs (the MJCF",
        "# <exclude>s every other body pair), and only where the MJCF's contype/conaffinity bits",
        "# (or a <contact><pair>) let the two geoms touch." + never,
        *(
            ["# The floor touches the geoms its own contype/conaffinity bits let touch."]
            if floor
            else []
        ),
        "collision_pairs = [",
        *[f'  ["{a}", "{b}"],' for a, b in pairs],
        "]",
        "stale_limit = 0.05",
    ]


def write_robot_toml(
    path: Path,
    *,
    name,
    prepared: PreparedSource,
    mjcf,
    joint_names,
    limits,
    motion: Motion,
    chosen,
    motor_cfg,
    pairs,
    workspace,
    control_rate,
    physics_timestep,
    disabled_by: str | None,
    lowered,
    motor_tables: dict[str, tuple[Path, dict]] | None = None,
    rates_from: tuple[str, str] = ("--control-rate", "--physics-timestep"),
    pairs_apart: list = (),
) -> None:
    """Write robot.toml with a comment giving the reason of every value.

    ``prepared``: the description (its file, kind and where each joint's limits came from);
    ``rates_from``: where the control rate and the physics timestep came from
    (:func:`control_lines`); ``pairs_apart``: the pairs the MJCF's contact bits keep apart
    (:func:`pairs_lines`);
    ``disabled_by``: what named the link pairs left unchecked ("the SRDF (x.srdf)"), or None;
    ``motor_tables``: the motors given as files (:func:`motor_table_lines`).
    """
    motor_tables = motor_tables or {}
    kind = prepared.kind

    resolutions = [
        motor_cfg[m].encoder_resolution
        for m in set(chosen.values())
        if motor_cfg[m].encoder_resolution
    ]
    resolution = min(resolutions) if resolutions else 16384
    quantum = 2 * math.pi / resolution
    home_note = (
        f"0 clipped into the soft limits. End effector there at {_vec(workspace['home_ee'])} m."
    )
    lines = [
        f"# {name}: imported by robot-import from {prepared.display}.",
        *sources_lines(kind),
        *control_lines(
            name,
            mjcf,
            "joint position targets (a servo's native mode)",
            (control_rate, physics_timestep),
            home_note,
            motion.home,
            rates_from=rates_from,
        ),
        "# acceleration_limit: 0.5 x (effort - worst gravity torque) / worst joint inertia with",
        "# armature (rotor inertia x ratio^2), 400 seeded poses; jerk_limit: 20 x acceleration.",
        "# kp: full effort at 0.05 rad error (capped for stability at the physics step);",
        "# kd: critical damping for the worst inertia. Plant servo gains, not datasheet values.",
        *all_joint_lines(joint_names, limits, prepared, lowered, motion, chosen),
        "",
        *sensor_lines(
            chosen, resolution, quantum, control_rate, "degC, as servos report it", motor_tables
        ),
        "",
        *_arm_safety_and_task_lines(workspace, disabled_by, pairs, pairs_apart),
        *motor_table_lines(motor_tables),
        "",
    ]
    path.write_text("\n".join(lines), encoding="utf-8")


def _arm_safety_and_task_lines(workspace: dict, disabled_by, pairs, pairs_apart) -> list[str]:
    """An arm's robot.toml ``[safety]`` (end-effector site, workspace box, checked pairs) and
    ``[task]`` (the reach goals' box) from the importer's workspace sampling."""
    return [
        "[safety]",
        'end_effector_site = "ee"',
        "# Box of every reachable end-effector position + 5 cm, cut 5 cm below the base (table).",
        f"workspace_min = {_vec(workspace['workspace_min'])}",
        f"workspace_max = {_vec(workspace['workspace_max'])}",
        *pairs_lines(disabled_by, pairs, apart=pairs_apart),
        "",
        "[task]",
        "# 10th-90th percentile box of positions reached within 70 % of each range about home;",
        "# goals are such positions inside the box (joint_fraction): every goal is reachable.",
        'region = "box"',
        f"joint_fraction = {TASK_JOINT_FRACTION}",
        f"box_min = {_vec(workspace['task_min'])}",
        f"box_max = {_vec(workspace['task_max'])}",
        f"success_radius = {_f(workspace['success_radius'])}  # m, 6 % of the reach",
    ]
