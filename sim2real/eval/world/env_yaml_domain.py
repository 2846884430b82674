"""The training domain of an Isaac Lab or mjlab task as a ranges file: its run folder's
``params/env.yaml`` (:func:`env_yaml_domain`).

Both stacks dump the environment configuration there when training starts (Isaac Lab's
``dump_yaml`` of ``class_to_dict``: functions as ``"module:name"``, tuples as ``!!python/tuple``;
mjlab's ``yaml.dump`` of its dataclasses: ``!!python/object`` mappings and ``!!python/name``
functions). It is read with a safe loader (every Python tag becomes plain data; nothing is
imported or constructed). Every ``events`` term is read or refused by name (:data:`EVENTS`, by the
function's name): friction (Isaac Lab's ``randomize_rigid_body_material`` combined with the
terrain's material as PhysX combines them; mjlab's ``randomize_field`` of ``geom_friction``) the
floor's, a mass added to a body its payload, scaled link masses, joint friction, damping and
armature, actuator gains the ``[dynamics]`` factors, a centre-of-mass shift ``com_offset``,
``push_by_setting_velocity`` the pushes (added, per axis), mjlab's ``randomize_encoder_bias`` the
encoders' bias; the reset events (the initial pose and joint state) are read and change nothing
the soak draws. The policy group's observation noise becomes the sensors' sigmas (uniform
``[a, b]``: ``(b - a) / sqrt(12)``) and a velocity command's ranges, ``resampling_time_range``
(its period) and ``rel_standing_envs`` (its share of zero commands) the ``[commands]``.
"""

from __future__ import annotations

import math
from pathlib import Path

from sim2real.deploy.core.stacks import DomainReader
from sim2real.eval.world.env_yaml_events import EVENTS, Reading, range_text, zero_fraction
from sim2real.eval.world.legged_gym_domain import DomainError
from sim2real.eval.world.legged_gym_groups import G


def load_env_yaml(path: Path) -> dict:
    """``path`` read with a safe loader that turns Python tags into plain data: a tuple a list,
    an object its mapping, a function its dotted name.

    Raises:
        DomainError: not readable, or not YAML (named).
    """
    import yaml

    class Loader(yaml.SafeLoader):
        """A safe loader for ``yaml.dump``'s Python tags (nothing imported or built)."""

    def tagged(loader, suffix, node):
        if isinstance(node, yaml.MappingNode):
            return loader.construct_mapping(node, deep=True)
        if isinstance(node, yaml.SequenceNode):
            return loader.construct_sequence(node, deep=True)
        name = suffix.partition(":")[2]  # python/name:module.function
        return name or loader.construct_scalar(node)

    Loader.add_multi_constructor("tag:yaml.org,2002:python/", tagged)
    try:
        data = yaml.load(path.read_text(encoding="utf-8"), Loader=Loader)  # noqa: S506 - safe
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise DomainError(f"{path}: not readable as YAML: {exc}") from None
    if not isinstance(data, dict):
        raise DomainError(f"{path}: expected the environment configuration (a mapping)")
    return data


def function_name(func) -> str:
    """``"module:name"`` or ``"module.name"`` as ``name``."""
    return str(func or "").replace(":", ".").rpartition(".")[2]


#: The observation functions whose noise a ranges file draws -> (table, key, factor on sigma).
NOISE = {
    "base_ang_vel": ("imu", "gyro_noise_sigma", 1.0),
    "projected_gravity": ("imu", "accel_noise_sigma", G),
    "joint_pos_rel": ("sensors", "noise_sigma", 1.0),
    "joint_pos": ("sensors", "noise_sigma", 1.0),
}


def _noise(r: Reading, env: dict) -> None:
    group = (env.get("observations") or {}).get("policy") or {}
    if group.get("enable_corruption") is False:
        r.notes.append("observations.policy.enable_corruption false: no observation noise")
        return
    for name, term in group.items():
        if not isinstance(term, dict) or not isinstance(term.get("noise"), dict):
            continue
        noise = term["noise"]
        lo, hi = noise.get("n_min"), noise.get("n_max")
        func = function_name(term.get("func"))
        if func == "builtin_sensor":  # mjlab reads its IMU through sensors, named by the term
            func = {"base_ang_vel": "base_ang_vel"}.get(name, func)
        if lo is None or hi is None:
            r.refused.append(f"observations.policy.{name}.noise: {noise}: not a uniform noise")
            continue
        sigma = (float(hi) - float(lo)) / math.sqrt(12.0)
        if func in NOISE:
            table, key, factor = NOISE[func]
            r.tables.setdefault(table, {})[key] = f"[0.0, {factor * sigma:.6g}]"
        else:
            r.notes.append(f"observations.policy.{name} noise +-{float(hi):g}: not drawn "
                           "(the runtime estimates it from the encoders and the IMU)")  # fmt: skip


def _commands(r: Reading, env: dict) -> None:
    for name, command in (env.get("commands") or {}).items():
        ranges = (command or {}).get("ranges") if isinstance(command, dict) else None
        if isinstance(ranges, dict) and "lin_vel_x" in ranges:
            yaw = ranges.get("ang_vel_z", ranges.get("ang_vel_yaw"))
            pairs = {"vx": ranges["lin_vel_x"], "vy": ranges.get("lin_vel_y"), "yaw_rate": yaw}
            r.tables["commands"] = {
                k: f"[{float(v[0]):.6g}, {float(v[1]):.6g}]"
                for k, v in pairs.items()
                if v is not None
            }
            r.notes.append(f"commands.{name}.ranges: the soak's commands")
            _schedule(r, f"commands.{name}", command)
            return


def _schedule(r: Reading, where: str, command: dict) -> None:
    """A velocity command's ``resampling_time_range`` (s, each command's length drawn from it)
    as the ``[commands]`` period, its ``rel_standing_envs`` (each new command's chance of being
    zero) as ``zero_fraction``."""
    if "resampling_time_range" in command:
        period = range_text(r, f"{where}.resampling_time_range", command["resampling_time_range"])
        if period is not None:
            r.set("commands", "period", period)
    if command.get("rel_standing_envs") is not None:
        zero_fraction(r, f"{where}.rel_standing_envs", command["rel_standing_envs"])
    if command.get("heading_command"):
        _heading(r, where, command)


def _heading(r: Reading, where: str, command: dict) -> None:
    """A heading command (Isaac Lab's and mjlab's ``UniformVelocityCommand._update_command``:
    for the ``rel_heading_envs`` share of the envs, ``ang_vel_z = clip(heading_control_stiffness
    * wrap_to_pi(heading - heading_w), *ranges.ang_vel_z)`` each step, the heading drawn from
    ``ranges.heading`` at each resample) as the ``[commands]`` heading keys; a clip that is not
    symmetric about 0, which the soak's ``max_yaw_rate`` cannot state, is refused by name."""
    ranges = command.get("ranges") or {}
    yaw = ranges.get("ang_vel_z", ranges.get("ang_vel_yaw"))
    heading = range_text(r, f"{where}.ranges.heading", ranges.get("heading"))
    clip = range_text(r, f"{where}.ranges.ang_vel_z", yaw)
    k = command.get("heading_control_stiffness", 1.0)  # Isaac Lab's and mjlab's default
    share = command.get("rel_heading_envs", 1.0)  # the same
    if heading is None or clip is None:
        return
    lo, hi = (float(v) for v in yaw)
    if not (lo == -hi and hi > 0):
        r.refused.append(
            f"{where}.ranges.ang_vel_z: a heading command's yaw-rate clip must be symmetric "
            f"about 0 (the soak's max_yaw_rate), got {clip}"
        )
        return
    if not (isinstance(k, int | float) and k > 0):
        r.refused.append(f"{where}.heading_control_stiffness: expected a number > 0, got {k!r}")
        return
    if not (isinstance(share, int | float) and 0 <= share <= 1):
        r.refused.append(f"{where}.rel_heading_envs: expected a share in [0, 1], got {share!r}")
        return
    r.set("commands", "heading_command", "true")
    r.set("commands", "heading", heading)
    r.set("commands", "heading_stiffness", f"{float(k):.6g}")
    r.set("commands", "max_yaw_rate", f"{hi:.6g}")
    r.set("commands", "heading_fraction", f"{float(share):.6g}")
    r.notes.append(
        f"{where}.heading_command: yaw rate = clip({float(k):g} * wrap_to_pi(heading - yaw), "
        f"{lo:g}, {hi:g}) for a share {float(share):g} of the commands, heading {heading}"
    )


def env_yaml_domain(path: str | Path) -> str:
    """The ranges file (TOML text) of the training domain an Isaac Lab or mjlab ``env.yaml``
    describes (module docstring).

    Raises:
        DomainError: an unreadable file, no ``events``, an event the soak cannot run (a
            restitution, a held external force, a mass or gain set absolutely, ...) or one this
            reader does not know (each named with ``events.<term>``).
    """
    path = Path(path)
    env = load_env_yaml(path)
    events = env.get("events")
    if not isinstance(events, dict):
        raise DomainError(f"{path}: no 'events' (expected an Isaac Lab or mjlab env.yaml)")
    r = Reading(env)
    for name, term in events.items():
        if not isinstance(term, dict):  # an event switched off (None)
            continue
        func = function_name(term.get("func"))
        read = EVENTS.get(func)
        if read is None:
            r.refused.append(f"events.{name} ({func}): not an event this reader knows")
            continue
        read(r, f"events.{name}", term.get("params") or {}, term)
    _noise(r, env)
    _commands(r, env)
    if r.refused:
        raise DomainError(
            f"{path}: " + "; ".join(r.refused) + "; nothing is dropped silently: write the "
            "training domain as a ranges file (see sim2real/eval/world/example_ranges.toml)"
        )
    return r.text(path)


def run_folder_domain(policy: str | Path, metadata: dict) -> str | None:
    """The training domain of a policy file's run folder: the first ``env.yaml`` where
    :data:`sim2real.deploy.spec.foreign.isaaclab.ENV_YAML` looks for it beside ``policy``, read
    by :func:`env_yaml_domain` when it has ``events`` (a run folder's env.yaml without events,
    none dumped, says nothing of the domain); None: no env.yaml there, or none with events.
    ``metadata`` is not read (Isaac Lab's, mjlab's and Unitree's deploy.yaml's run folders keep
    the domain beside the file)."""
    from sim2real.deploy.spec.foreign.isaaclab import ENV_YAML

    folder = Path(policy).resolve().parent
    env = next(((folder / p).resolve() for p in ENV_YAML if (folder / p).is_file()), None)
    if env is None:
        return None
    return env_yaml_domain(env) if isinstance(load_env_yaml(env).get("events"), dict) else None


#: The training-domain face of the stacks whose run folder holds an ``env.yaml`` (Isaac Lab,
#: mjlab, Unitree's deploy.yaml of their policies; :mod:`sim2real.stacks`).
DOMAIN = DomainReader(
    "an Isaac Lab or mjlab env.yaml (.yaml)", (".yaml", ".yml"), env_yaml_domain, run_folder_domain
)
