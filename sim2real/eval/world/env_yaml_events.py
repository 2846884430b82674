"""What each Isaac Lab and mjlab event of an ``env.yaml`` becomes in a ranges file (:data:`EVENTS`,
by the event function's name), for :func:`sim2real.eval.world.env_yaml_domain.env_yaml_domain`;
and the file's text (:meth:`Reading.text`). An event that is on and that the soak cannot run is
refused, naming the term and its parameter.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

#: PhysX's friction combine modes, in the order it picks one of two materials' (the later wins),
#: and the coefficient each gives of a body's ``a`` and the terrain's ``t``.
COMBINE = {
    "average": lambda a, t: (a + t) / 2,
    "min": min,
    "multiply": lambda a, t: a * t,
    "max": max,
}


class Reading:
    """An ``env.yaml`` being read: what its events make (``top``, ``tables``), notes for the
    file's comments, refusals (one line each)."""

    def __init__(self, env: dict):
        self.env = env
        self.top: dict[str, str] = {}
        self.tables: dict[str, dict[str, str]] = {}
        self.notes: list[str] = []
        self.refused: list[str] = []

    def set(self, table: str, key: str, value: str) -> None:
        self.tables.setdefault(table, {})[key] = value

    def text(self, path: Path) -> str:
        """The ranges file: what was read, over a domain that randomizes nothing else."""
        lines = [f"# training domain of {path} (read by sim2real.eval.world.env_yaml_domain)"]
        lines += [f"# {note}" for note in dict.fromkeys(self.notes)]
        lines.append(f"floor_friction = {self.top.get('floor_friction', '[1.0, 1.0]')}")
        lines += [f"{k} = {v}" for k, v in self.top.items() if k != "floor_friction"]
        defaults = {
            "dynamics": {
                k: "0.0"
                for k in ("link_length", "mass", "friction", "damping", "actuator_strength")
            },  # fmt: skip
            "sensors": {"noise_sigma": "[0.0, 0.0]", "latency_ticks": "[0, 0]"},
            "imu": {
                "gyro_noise_sigma": "[0.0, 0.0]",
                "accel_noise_sigma": "[0.0, 0.0]",
                "bias_scale": "[0.0, 0.0]",
                "latency_ticks": "[0, 0]",
            },  # fmt: skip
        }
        for table in ("dynamics", "sensors", "imu", "pushes", "commands"):
            entries = {**defaults.get(table, {}), **self.tables.get(table, {})}
            if entries:
                lines += ["", f"[{table}]", *(f"{k} = {v}" for k, v in entries.items())]
        return "\n".join(lines) + "\n"


def _pair(value) -> tuple[float, float] | None:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        return None
    return (lo, hi) if math.isfinite(lo) and math.isfinite(hi) and lo <= hi else None


def range_text(r: Reading, where: str, value) -> str | None:
    """``value`` as a ranges file's ``[low, high]`` (None, and a refusal noted, when it is not
    one)."""
    pair = _pair(value)
    if pair is None:
        r.refused.append(f"{where}: expected [low, high], got {value!r}")
        return None
    return f"[{pair[0]:.6g}, {pair[1]:.6g}]"


def zero_fraction(r: Reading, where: str, value) -> None:
    """``value``, each new velocity command's chance of being zero (Isaac Lab's and mjlab's
    ``rel_standing_envs``, holosoma's ``stand_prob``), as the ``[commands]`` ``zero_fraction``
    (a refusal noted when it is not a number in [0, 1])."""
    if isinstance(value, int | float) and not isinstance(value, bool) and 0 <= value <= 1:
        r.set("commands", "zero_fraction", f"{float(value):.6g}")
    else:
        r.refused.append(f"{where}: expected a share in [0, 1], got {value!r}")


def half_range(r: Reading, where: str, value, what: str) -> str | None:
    """A factor range as the half-range about 1 that holds it (noted when widened)."""
    pair = _pair(value)
    if pair is None or pair[0] <= 0:
        r.refused.append(f"{where}: expected a factor range [low > 0, high], got {value!r}")
        return None
    half = max(1.0 - pair[0], pair[1] - 1.0, 0.0)
    if not math.isclose(1.0 - pair[0], pair[1] - 1.0):
        r.notes.append(f"{where} {list(pair)}: {what} +-{half:.4g} (widened to 1 +- r)")
    return f"{half:.6g}"


def _one_body(params: dict) -> str | None:
    """The one body an event names (``asset_cfg.body_names``), or None (several, a pattern)."""
    names = (params.get("asset_cfg") or {}).get("body_names")
    if isinstance(names, str):
        names = [names]
    if isinstance(names, list | tuple) and len(names) == 1 and not set(names[0]) & set(".*[]|?+("):
        return str(names[0])
    return None


def _every_body(params: dict) -> bool:
    names = (params.get("asset_cfg") or {}).get("body_names")
    return names in (None, ".*", [".*"], ("*",))


def _reset(r: Reading, where: str, params: dict, term: dict) -> None:
    r.notes.append("reset events (initial pose, joint state): the soak starts each session at home")


def _material(r: Reading, where: str, params: dict, term: dict) -> None:
    restitution = _pair(params.get("restitution_range") or (0.0, 0.0))
    if restitution is None or restitution != (0.0, 0.0):
        r.refused.append(f"{where}.params.restitution_range {params.get('restitution_range')}: "
                         "the soak's floor has no restitution to draw")  # fmt: skip
    friction = _pair(params.get("static_friction_range"))
    if friction is None:
        r.refused.append(f"{where}.params.static_friction_range: expected [low, high]")
        return
    terrain = ((r.env.get("scene") or {}).get("terrain") or {}).get("physics_material") or {}
    mode = str(terrain.get("friction_combine_mode") or "average")
    t = float(terrain.get("static_friction", 1.0))
    if mode not in COMBINE:
        r.refused.append(f"scene.terrain.physics_material.friction_combine_mode '{mode}'")
        return
    lo, hi = (COMBINE[mode](a, t) for a in friction)
    r.top["floor_friction"] = f"[{lo:.6g}, {hi:.6g}]"
    r.notes.append(f"{where}: the robot's static friction {list(friction)} with the terrain's "
                   f"{t:g} ({mode}, as PhysX combines them) is the floor's")  # fmt: skip


def _mass(r: Reading, where: str, params: dict, term: dict, key: str = "mass_distribution_params",
          operation: str | None = None) -> None:  # fmt: skip
    operation = operation or params.get("operation", "add")
    value = params.get(key, params.get("ranges"))
    body = _one_body(params)
    if operation == "add" and body is not None:
        text = range_text(r, f"{where}.params.{key}", value)
        if text is not None:
            r.top["added_base_mass"] = text
            r.top["added_mass_body"] = f'"{body}"'
    elif operation == "scale" and _every_body(params):
        half = half_range(r, f"{where}.params.{key}", value, "link mass")
        if half is not None:
            r.set("dynamics", "mass", half)
    else:
        r.refused.append(f"{where}: a mass '{operation}' over bodies {params.get('asset_cfg')}: "
                         "the soak adds a payload to one body or scales every link's mass")  # fmt: skip


def _com(r: Reading, where: str, params: dict, term: dict) -> None:
    body = _one_body(params)
    ranges = params.get("com_range", params.get("ranges"))
    if isinstance(ranges, list | tuple):
        ranges = {axis: ranges for axis in "xyz"}
    axes = {"x": 0, "y": 1, "z": 2}
    parts = []
    for axis, index in axes.items():
        value = (ranges or {}).get(axis, (ranges or {}).get(index))
        if value is not None:
            text = range_text(r, f"{where}.params ({axis})", value)
            parts.append(f"{axis} = {text}")
    if body is None or not parts:
        r.refused.append(f"{where}: a centre-of-mass shift needs one body and its ranges")
        return
    r.set("dynamics", "com_offset", "{" + f'body = "{body}", ' + ", ".join(parts) + "}")


def _push(r: Reading, where: str, params: dict, term: dict) -> None:
    interval = _pair(term.get("interval_range_s"))
    if term.get("mode") != "interval" or interval is None:
        r.refused.append(f"{where}: a push not at intervals (mode {term.get('mode')!r})")
        return
    velocity = params.get("velocity_range") or {}
    linear = {a: velocity[a] for a in ("x", "y", "z") if a in velocity}
    angular = {a: velocity[a] for a in ("roll", "pitch", "yaw") if a in velocity}

    def table(axes: dict) -> str:
        return "{" + ", ".join(f"{a} = {range_text(r, where, v)}" for a, v in axes.items()) + "}"

    r.set("pushes", "interval", f"[{interval[0]:.6g}, {interval[1]:.6g}]")
    r.set("pushes", "mode", '"add"')  # both stacks add the draw to the root's velocity
    if linear:
        r.set("pushes", "velocity", table(linear))
    if angular:
        r.set("pushes", "angular_velocity", table(angular))


def _force(r: Reading, where: str, params: dict, term: dict) -> None:
    ranges = [_pair(params.get(k) or (0.0, 0.0)) for k in ("force_range", "torque_range")]
    if any(p != (0.0, 0.0) for p in ranges):
        r.refused.append(f"{where}: an external force or torque held on a body "
                         f"({params.get('force_range')}, {params.get('torque_range')})")  # fmt: skip


def _scaled(keys: dict[str, str]) -> Callable:
    """An event scaling joint quantities: ``{param: dynamics key}``."""

    def read(r: Reading, where: str, params: dict, term: dict) -> None:
        operation = params.get("operation", "abs")
        for param, field in keys.items():
            value = params.get(param)
            if value is None:
                continue
            if operation != "scale":
                r.refused.append(f"{where}.params.{param}: '{operation}' (the soak scales it)")
                continue
            half = half_range(r, f"{where}.params.{param}", value, field)
            if half is not None:
                r.set("dynamics", field, half)
        for param in ("lower_limit_distribution_params", "upper_limit_distribution_params"):
            if params.get(param) is not None:
                r.refused.append(f"{where}.params.{param}: joint limits are the robot's")

    return read


_FIELDS = {"dof_armature": "armature", "dof_frictionloss": "friction", "dof_damping": "damping"}


def _field(r: Reading, where: str, params: dict, term: dict) -> None:
    """mjlab's ``randomize_field``."""
    field, operation = params.get("field"), params.get("operation", "abs")
    ranges = params.get("ranges")
    if isinstance(ranges, dict) and field != "body_ipos":
        ranges = ranges.get(0, next(iter(ranges.values()), None))
    if field == "geom_friction" and operation == "abs":
        text = range_text(r, f"{where}.params.ranges", ranges)
        if text is not None:
            r.top["floor_friction"] = text
            r.notes.append(f"{where}: the robot's geoms' friction; here the floor's, which has "
                           "contact priority")  # fmt: skip
    elif field == "body_ipos" and operation == "add":
        _com(r, where, params, term)
    elif field == "body_mass":
        _mass(r, where, {**params, "mass_distribution_params": ranges}, term)
    elif field in _FIELDS and operation == "scale":
        half = half_range(r, f"{where}.params.ranges", ranges, _FIELDS[field])
        if half is not None:
            r.set("dynamics", _FIELDS[field], half)
    else:
        r.refused.append(f"{where}: randomize_field of '{field}' ({operation}): not a quantity "
                         "the soak draws that way")  # fmt: skip


def _encoder_bias(r: Reading, where: str, params: dict, term: dict) -> None:
    text = range_text(r, f"{where}.params.bias_range", params.get("bias_range"))
    if text is not None:
        r.set("sensors", "encoder_bias", text)


def _visual(r: Reading, where: str, params: dict, term: dict) -> None:
    r.notes.append(f"{where}: a visual randomization (no camera here)")


#: Event functions (by name) -> ``(reading, "events.<term>", params, term) -> None``.
EVENTS: dict[str, Callable] = {
    "reset_root_state_uniform": _reset,
    "reset_root_state_from_terrain": _reset,
    "reset_joints_by_scale": _reset,
    "reset_joints_by_offset": _reset,
    "reset_scene_to_default": _reset,
    "randomize_rigid_body_material": _material,
    "randomize_rigid_body_mass": _mass,
    "randomize_rigid_body_com": _com,
    "push_by_setting_velocity": _push,
    "apply_external_force_torque": _force,
    "randomize_actuator_gains": _scaled(
        {"stiffness_distribution_params": "kp", "damping_distribution_params": "kd"}
    ),
    "randomize_joint_parameters": _scaled(
        {"friction_distribution_params": "friction", "armature_distribution_params": "armature"}
    ),
    "randomize_field": _field,
    "randomize_encoder_bias": _encoder_bias,
    "randomize_visual_texture_material": _visual,
    "randomize_visual_color": _visual,
}
