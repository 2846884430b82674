"""A foreign contract as ``policy-export --inspect`` reports it (:func:`summary`): what its stack
recorded, how each observation term maps onto our blocks, what is missing and what stands in for
it, and, given a robot, the joint mapping, the drive's differences from robot.toml and the
PolicySpec that deploy-run would use."""

from __future__ import annotations

import json
from typing import Any

from sim2real.deploy.spec.foreign.contract import ForeignContract, PerJoint
from sim2real.deploy.spec.policy_spec import SpecError

#: The one line ``--inspect`` prints for a policy that observes the base's linear velocity.
BASE_VELOCITY_LINE = (
    "base linear velocity: observed by the policy ({terms}); deploy-run takes it from the "
    "runtime's base estimator (IMU and leg-odometry Kalman filter), not from a sensor"
)


def _values(value: PerJoint | None) -> str:
    if value is None:
        return "not recorded"
    if isinstance(value, int | float):
        return f"{float(value):g} (every joint)"
    if isinstance(value, dict):
        return json.dumps(value)
    return "[" + ", ".join(f"{v:.4g}" for v in value) + "]"


def _term_line(contract: ForeignContract, t) -> str:
    size = contract.term_size(t)
    scale = t.scale if isinstance(t.scale, float) else list(t.scale)
    head = f"{t.name} [{size if size is not None else '?'}]"
    if t.kind is None:
        return f"{head}: CANNOT BE MAPPED: {t.reason}"
    parts = [f"x {scale}" if scale != 1.0 else "unscaled"]
    if t.kind == "joint_position":
        parts.append("about the default pose" if t.relative else "absolute")
    if t.components:
        parts.append(f"entries {list(t.components)} of the vector")
    if t.period:
        parts.append(f"period {t.period:g} s")
    if t.stand_below:
        parts.append(
            f"stops below a command of {t.stand_below:g}, every foot at {t.stand_phase:.4g} rad"
        )
    parts.append("unclipped" if t.clip is None else f"clip +-{t.clip:g}")
    if t.history > 1:
        parts.append(f"its last {t.history} ticks, oldest first ({contract.history_fill} before)")
    return f"{head} -> {t.kind} ({', '.join(parts)})"


def summary(contract: ForeignContract, robot=None) -> dict[str, Any]:
    """The report of ``contract`` (and of its mapping onto ``robot`` when given).

    Returns:
        ``{"format", "source", "found": [[key, value]], "joints", "observation": [lines],
        "action", "kp", "kd", "default_pose", "control_rate", "missing": [lines], "notes":
        [lines], "base_velocity": line or None}``, with a robot also ``"robot"``: ``{"name",
        "joint_map": "name -> robot index, ...", "drive_differences": [lines], "spec": JSON or
        None, "error": message or None}``.
    """
    c = contract
    terms = c.base_velocity_terms()
    out: dict[str, Any] = {
        "format": c.format,
        "source": c.source,
        "found": [list(kv) for kv in c.found],
        "joints": (
            f"{len(c.joint_names)} in the policy's order: {', '.join(c.joint_names)}"
            if c.joint_names is not None
            else f"{c.n_joints}, order {c.joint_order_note}"
        ),
        "observation": [_term_line(c, t) for t in c.terms],
        "action": (
            f"position, target = {'offset' if c.action_offset is not None else 'default pose'}"
            f" + scale x action; scale {_values(c.action_scale)}; "
            f"clip {'none' if c.action_clip is None else f'+-{c.action_clip:g}'}"
        ),
        "kp": _values(c.kp),
        "kd": _values(c.kd),
        "default_pose": _values(c.default_pose),
        "control_rate": "not recorded" if c.control_rate is None else f"{c.control_rate:g} Hz",
        "missing": list(c.missing),
        "notes": list(c.notes),
        "base_velocity": BASE_VELOCITY_LINE.format(terms=", ".join(terms)) if terms else None,
    }
    if robot is not None:
        out["robot"] = _on_robot(c, robot)
    return out


def _on_robot(contract: ForeignContract, robot) -> dict[str, Any]:
    from sim2real.deploy.spec.drive import drive_differences
    from sim2real.deploy.spec.foreign.mapping import policy_joint_names, to_spec

    result: dict[str, Any] = {"name": robot.name, "error": None, "spec": None}
    try:
        spec = to_spec(contract, robot)
        spec.check_robot(robot, check_hash=False)
    except SpecError as exc:
        result["error"] = str(exc)
        return result
    names = policy_joint_names(contract, robot)
    result["joint_map"] = ", ".join(f"{name} -> {robot.joint_names.index(name)}" for name in names)
    result["drive_differences"] = list(drive_differences(spec.drive, robot).values())
    result["spec"] = json.loads(spec.to_json())
    return result


def format_lines(info: dict[str, Any]) -> list[str]:
    """:func:`summary` as indented text lines for the terminal."""
    lines = [f"  foreign contract: {info['format']} (from {info['source']})"]
    if "error" in info:
        return lines + [f"    cannot be read: {info['error']}"]
    lines.append(f"    joints: {info['joints']}")
    lines.append("    observation (in the graph's order):")
    lines += [f"      {t}" for t in info["observation"]]
    for key in ("action", "kp", "kd", "default_pose", "control_rate"):
        lines.append(f"    {key.replace('_', ' ')}: {info[key]}")
    if info.get("base_velocity"):
        lines.append(f"    {info['base_velocity']}")
    lines += [f"    missing: {m}" for m in info["missing"]] or ["    missing: nothing"]
    lines += [f"    note: {n}" for n in info["notes"]]
    robot = info.get("robot")
    if robot:
        if robot["error"]:
            lines.append(f"    on robot '{robot['name']}': REFUSED: {robot['error']}")
        else:
            lines.append(f"    on robot '{robot['name']}':")
            lines.append(f"      graph outputs -> robot joints: {robot['joint_map']}")
            diffs = robot["drive_differences"] or ["none"]
            lines += [f"      drive differs from robot.toml: {d}" for d in diffs]
            lines.append("      policy spec: " + json.dumps(robot["spec"], sort_keys=True))
    return lines
