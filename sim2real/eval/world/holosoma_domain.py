"""The training domain of a holosoma policy as a ranges file: the ``randomization`` section of the
``experiment_config`` its ONNX file carries (holosoma's ``attach_onnx_metadata``;
:func:`holosoma_domain`).

holosoma's randomization manager runs ``setup_terms``, ``reset_terms`` and ``step_terms``, each a
function (``module:name``) and its ``params`` (holosoma ``config_values/loco/<robot>/
randomization.py``). Every term is read or refused by name (:data:`TERMS`): the pushes
(``PushRandomizerState``: every ``push_interval_s`` the base's x and y velocity set to
``U(-max_push_vel, max_push_vel)``, legged_gym's push), link masses and the base's added mass
(``randomize_mass_startup``), the feet's friction with the terrain's (averaged, as Isaac Gym's
PhysX does), the base's centre of mass, the PD gains (``ActuatorRandomizerState``), the encoders'
bias (``setup_dof_pos_bias``); an action delay and a random force injection (``torque_rfi``) are
refused when they are on. The terms that only run the ones above at reset or each step, and the
initial state's, change nothing the soak draws. The actor's observation noise (uniform
``+-noise``) becomes the sensors' sigmas; the file's ``command_ranges``, the command manager's
``locomotion_command_resampling_time`` and ``stand_prob`` the ``[commands]``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable

from sim2real.deploy.core.stacks import DomainReader
from sim2real.eval.world.env_yaml_events import Reading, half_range, range_text, zero_fraction
from sim2real.eval.world.legged_gym_domain import DomainError
from sim2real.eval.world.legged_gym_groups import G


def _on(params: dict, flag: str = "enabled") -> bool:
    return bool(params.get(flag, True))


def _push(r: Reading, where: str, p: dict) -> None:
    if not _on(p) or "push_interval_s" not in p:  # at reset and each step: the setup term's
        return
    interval = range_text(r, f"{where}.push_interval_s", p.get("push_interval_s"))
    vx, vy = (abs(float(v)) for v in p.get("max_push_vel", (1.0, 1.0)))
    if interval is not None:
        r.set("pushes", "interval", interval)
        r.set("pushes", "velocity", f"{{x = [{-vx:.6g}, {vx:.6g}], y = [{-vy:.6g}, {vy:.6g}]}}")


def _delay(r: Reading, where: str, p: dict) -> None:
    steps = p.get("ctrl_delay_step_range") or (0, 0)
    if _on(p) and max(steps) > 0:
        r.refused.append(f"{where}.ctrl_delay_step_range {list(steps)}: an action delay (the "
                         "soak's runtime sends each action at once)")  # fmt: skip


def _rfi(r: Reading, where: str, p: dict) -> None:
    if _on(p):
        r.refused.append(f"{where}: a random force injection on the torques (rfi_lim "
                         f"{p.get('rfi_lim')})")  # fmt: skip


def _bias(r: Reading, where: str, p: dict) -> None:
    if _on(p):
        text = range_text(r, f"{where}.dof_pos_bias_range", p.get("dof_pos_bias_range"))
        if text is not None:
            r.set("sensors", "encoder_bias", text)


def _actuator(r: Reading, where: str, p: dict) -> None:
    if p.get("enable_pd_gain"):
        for key, field in (("kp_range", "kp"), ("kd_range", "kd")):
            half = half_range(r, f"{where}.{key}", p.get(key), field)
            if half is not None:
                r.set("dynamics", field, half)
    if p.get("enable_rfi_lim"):
        r.refused.append(f"{where}.rfi_lim_range {p.get('rfi_lim_range')}: a random force "
                         "injection on the torques")  # fmt: skip


def _mass(r: Reading, where: str, p: dict) -> None:
    if not _on(p):
        return
    if p.get("enable_link_mass"):
        half = half_range(r, f"{where}.link_mass_range", p.get("link_mass_range"), "link mass")
        if half is not None:
            r.set("dynamics", "mass", half)
    if p.get("enable_base_mass"):
        text = range_text(r, f"{where}.added_mass_range", p.get("added_mass_range"))
        if text is not None:
            r.top["added_base_mass"] = text


def _friction(key: str) -> Callable:
    def read(r: Reading, where: str, p: dict) -> None:
        if not _on(p):
            return
        restitution = p.get("restitution_range") or (0.0, 0.0)
        if any(float(x) for x in restitution):
            r.refused.append(f"{where}.restitution_range {list(restitution)}: the soak's floor "
                             "has no restitution to draw")  # fmt: skip
        text = range_text(r, f"{where}.{key}", p.get(key))
        if text is not None:
            lo, hi = (float(x) for x in json.loads(text))
            r.top["floor_friction"] = f"[{(lo + 1) / 2:.6g}, {(hi + 1) / 2:.6g}]"
            r.notes.append(f"{where}.{key} {text}: averaged with the terrain's 1.0 (PhysX)")

    return read


def _com(r: Reading, where: str, p: dict) -> None:
    if not _on(p):
        return
    ranges = p.get("base_com_range") or {}
    parts = [f"{a} = {range_text(r, f'{where}.base_com_range.{a}', v)}" for a, v in ranges.items()]
    r.set("dynamics", "com_offset", "{" + ", ".join(parts) + "}")


def _none(r: Reading, where: str, p: dict) -> None:
    """A term that runs a setup term's randomization again, or the initial state's."""


#: holosoma's randomization functions (by name) -> ``(reading, where, params) -> None``.
TERMS = {
    "PushRandomizerState": _push,
    "setup_action_delay_buffers": _delay,
    "setup_torque_rfi": _rfi,
    "setup_dof_pos_bias": _bias,
    "ActuatorRandomizerState": _actuator,
    "randomize_mass_startup": _mass,
    "randomize_friction_startup": _friction("friction_range"),
    "randomize_robot_rigid_body_material_startup": _friction("static_friction_range"),
    "randomize_base_com_startup": _com,
    "randomize_push_schedule": _none,
    "randomize_action_delay": _none,
    "configure_torque_rfi": _none,
    "apply_pushes": _none,
    "randomize_dof_state": _none,
}
#: The observation terms whose noise a ranges file draws -> (table, key, factor on sigma).
NOISE = {
    "base_ang_vel": ("imu", "gyro_noise_sigma", 1.0),
    "projected_gravity": ("imu", "accel_noise_sigma", G),
    "dof_pos": ("sensors", "noise_sigma", 1.0),
}


def _schedule(r: Reading, command: dict) -> None:
    """The command manager's ``params.locomotion_command_resampling_time`` (s between
    commands) as the ``[commands]`` period, its ``locomotion_command`` term's ``stand_prob``
    (each new command's chance of being zero) as ``zero_fraction``."""
    period = (command.get("params") or {}).get("locomotion_command_resampling_time")
    if period is not None:
        if _number(period) and period > 0:
            r.set("commands", "period", f"{float(period):.6g}")
        else:
            r.refused.append(f"command.params.locomotion_command_resampling_time: expected s "
                             f"> 0, got {period!r}")  # fmt: skip
    term = (command.get("setup_terms") or {}).get("locomotion_command") or {}
    share = (term.get("params") or {}).get("stand_prob")
    if share is not None:
        zero_fraction(r, "command.setup_terms.locomotion_command.params.stand_prob", share)


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def holosoma_domain(config: dict, command_ranges: dict | None, source: str) -> str:
    """The ranges file (TOML text) of holosoma's ``experiment_config`` ``config`` (module
    docstring); ``command_ranges`` the file's (holosoma's names), ``source`` names the file.

    Raises:
        DomainError: a term the soak cannot run that is on, or one this reader does not know
            (each named with ``randomization.<stage>.<term>``).
    """
    r = Reading({})
    randomization = config.get("randomization") or {}
    for stage in ("setup_terms", "reset_terms", "step_terms"):
        for name, term in (randomization.get(stage) or {}).items():
            func = str((term or {}).get("func", "")).rpartition(":")[2]
            where = f"randomization.{stage}.{name}"
            read = TERMS.get(func)
            if read is None:
                r.refused.append(f"{where} ({func}): not a randomization this reader knows")
            else:
                read(r, where, (term or {}).get("params") or {})
    groups = ((config.get("observation") or {}).get("groups")) or {}
    actor = groups.get("actor_obs") or next(iter(groups.values()), {})
    for name, term in (actor.get("terms") or {}).items():
        noise = float((term or {}).get("noise") or 0.0)
        key = str((term or {}).get("func", "")).rpartition(":")[2] or name
        if noise and key in NOISE and actor.get("enable_noise", True):
            table, field, factor = NOISE[key]
            r.set(table, field, f"[0.0, {factor * noise / math.sqrt(3.0):.6g}]")
    _schedule(r, config.get("command") or {})
    ranges = command_ranges or {}
    names = {"vx": "lin_vel_x", "vy": "lin_vel_y", "yaw_rate": "ang_vel_yaw"}
    for ours, theirs in names.items():
        value = ranges.get(theirs, ranges.get("ang_vel_z") if ours == "yaw_rate" else None)
        if value is not None:
            r.set("commands", ours, f"[{float(value[0]):.6g}, {float(value[1]):.6g}]")
    if r.refused:
        raise DomainError(f"{source}: " + "; ".join(r.refused) + "; nothing is dropped silently: "
                          "write the training domain as a ranges file")  # fmt: skip
    return r.text(source)


def policy_domain(policy, metadata: dict) -> str | None:
    """:func:`holosoma_domain` of a holosoma file's metadata (``experiment_config``, its
    ``command_ranges``); None when it has no ``experiment_config``.

    Raises:
        DomainError: its JSON does not parse, or the domain is refused (named).
    """
    from sim2real.eval.world.domain import COMMAND_RANGES_KEY

    if "experiment_config" not in metadata:
        return None
    try:
        config = json.loads(metadata["experiment_config"])
        ranges = json.loads(metadata.get(COMMAND_RANGES_KEY) or "null")
    except json.JSONDecodeError as exc:
        raise DomainError(f"{policy}: metadata is not JSON ({exc})") from None
    return holosoma_domain(config, ranges if isinstance(ranges, dict) else None, str(policy))


#: holosoma's training-domain face (the ``holosoma`` stack's, :mod:`sim2real.stacks`): the
#: ``experiment_config`` its exports carry; no config file of its own is read.
DOMAIN = DomainReader(
    "holosoma's experiment_config (in its ONNX metadata)", of_policy=policy_domain
)
