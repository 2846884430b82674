"""holosoma's ONNX metadata (``holosoma.utils.inference_helpers.attach_onnx_metadata``, called by
its PPO and FastSAC agents' ``export``; amazon-far/holosoma).

holosoma exports ``actor_obs`` -> ``action`` (opset 13, batch 1); each ``metadata_props`` value is
``json.dumps`` of:

========================  ===============================================================
key                       value
========================  ===============================================================
``dof_names``             the robot's joints, in the policy's order (``robot.dof_names``)
``kp``, ``kd``            PD gains per joint, N m/rad and N m s/rad
``command_ranges``        the velocity command's sampling ranges (or null)
``action_scale``          the action scale, one number or one per joint (newer exports)
``experiment_config``     the whole training configuration (not in holosoma_inference's G1 files)
``robot_urdf``, ...       the URDF, its path, the wandb run (not used)
========================  ===============================================================

From ``experiment_config``: the actor's observation groups (``algo.config.module_dict.actor.
input_dim``), each group's terms **in alphabetical order** (holosoma's observation manager sorts
them before concatenating), each term's function, ``scale`` (a multiplier) and ``clip`` (after
scaling) and the global ``observation.clip_observations``; the default pose
(``robot.init_state.default_joint_angles``), the action scale and clip
(``robot.control.action_scale``, ``clip_actions``, ``action_clip_value``; a scale per joint of
``action_scale * effort_limit / kp`` with ``action_scales_by_effort_limit_over_p_gain``) and the
control rate (``simulator.config.sim.fps / control_decimation``). A group's ``history_length`` N
gives each of its terms the last N values, oldest first, zeros before the reset's first.
``sin_phase``, ``cos_phase`` (left foot, right foot half a period later): ``gait_phase`` blocks
that stop while standing (``STAND_BELOW``; period and held phase from ``command.setup_terms.
locomotion_gait.params``). Without it: holosoma_inference's configuration for its shipped G1
files (:mod:`.holosoma_wbt`, :mod:`.holosoma_loco`), else the metadata alone (:func:`partial`).
"""

from __future__ import annotations

import dataclasses
import json
import math

from sim2real.deploy.spec.foreign.contract import (
    ForeignContract,
    Term,
    command_ranges,
    positive_number,
)
from sim2real.deploy.spec.foreign.holosoma_loco import (
    PHASE_TERMS,
    STAND_BELOW,
    TERMS,
    is_g1_loco,
    read_g1_loco,
)
from sim2real.deploy.spec.foreign.holosoma_wbt import is_wbt, read_wbt

NAME = "holosoma"

#: ``LocomotionGait``'s defaults: ``gait_period`` (s) and ``stand_phase_value`` (rad).
GAIT_DEFAULTS = {"gait_period": 1.0, "stand_phase_value": math.pi}


def detect(facts) -> bool:
    """holosoma's metadata: ``dof_names`` and ``kp`` as JSON lists."""
    md = facts.metadata
    if "dof_names" not in md or "kp" not in md:
        return False
    try:
        return isinstance(json.loads(md["dof_names"]), list)
    except json.JSONDecodeError:
        return False


def read(facts) -> ForeignContract:
    """The contract of a holosoma export (module docstring).

    Raises:
        ForeignFormatError: a field of ``experiment_config`` that is not what holosoma writes,
            a non-position control type, an action term other than joint position (each named);
            without ``experiment_config``, see :func:`partial`.
    """
    fail = facts.failure(NAME)
    md = {}
    for key, text in facts.metadata.items():
        try:
            md[key] = json.loads(text)
        except json.JSONDecodeError:
            md[key] = text
    names = tuple(str(n) for n in md["dof_names"])
    if "experiment_config" not in md or not isinstance(md["experiment_config"], dict):
        if is_wbt(facts):
            return read_wbt(facts, md, names, fail)
        if is_g1_loco(facts, names):
            return read_g1_loco(facts, md, names, fail)
        return partial(facts, md, names, fail)
    ec = md["experiment_config"]
    get = _config_reader(ec, fail)
    control = _position_control(get, fail)
    kp, kd = tuple(md["kp"]), tuple(md.get("kd") or ())
    scale = float(control["action_scale"])
    action_scale: float | tuple[float, ...] = scale
    if control.get("action_scales_by_effort_limit_over_p_gain"):
        effort = get("robot", "dof_effort_limit_list")
        action_scale = tuple(scale * e / k if k else 0.0 for e, k in zip(effort, kp, strict=True))
    default = get("robot", "init_state", "default_joint_angles")
    unposed = [n for n in names if n not in default]
    if unposed:
        raise fail(
            f"experiment_config.robot.init_state.default_joint_angles has no angle for {unposed}"
        )
    groups = get("algo", "config", "module_dict", "actor", "input_dim", default=["actor_obs"])
    terms = _observation_terms(get, groups, fail)
    sim = get("simulator", "config", "sim", default={})
    rate = _rate(sim, fail) if "fps" in sim else None
    missing = [] if kd else ["kd: not recorded; the robot's robot.toml damping is used"]
    if rate is None:
        missing.append("control rate: not recorded (the robot's is used)")
    found = [
        ("dof_names", f"{len(names)} joints"),
        ("kp", json.dumps(md["kp"])),
        ("kd", json.dumps(md.get("kd"))),
        ("command_ranges", json.dumps(md.get("command_ranges"))),
        ("experiment_config", f"{len(json.dumps(ec))} characters of training configuration"),
    ]
    return facts.contract(
        NAME,
        "ONNX metadata (holosoma attach_onnx_metadata)",
        joint_names=names,
        terms=terms,
        default_pose=tuple(float(default[n]) for n in names),
        action_scale=action_scale,
        action_clip=float(control["action_clip_value"]) if control.get("clip_actions") else None,
        kp=kp,
        kd=kd or None,
        control_rate=rate,
        command_ranges=command_ranges(md.get("command_ranges")),
        history_fill="zeros",  # its history deque pads with zeros until full
        found=found,
        missing=missing,
        notes=(
            f"observation groups {list(groups)}, each group's terms in alphabetical order "
            "(holosoma's observation manager sorts them)",
        ),
    )


def _config_reader(ec: dict, fail):
    """``get(*keys, default=KeyError)``: the value at ``keys`` in ``experiment_config``, or
    ``default``; without a default a missing key raises ``fail``'s error naming it."""

    def get(*keys, default=KeyError):
        node = ec
        for k in keys:
            if not isinstance(node, dict) or k not in node:
                if default is KeyError:
                    raise fail(f"metadata 'experiment_config' has no '{'.'.join(keys)}'")
                return default
            node = node[k]
        return node

    return get


def _rate(sim: dict, fail) -> float:
    """The control rate, Hz: ``simulator.config.sim``'s ``fps`` (physics steps per s) over its
    ``control_decimation`` (steps a policy tick), each a number > 0 (a fail naming the key)."""
    values = []
    for key, kind in (("fps", (int, float)), ("control_decimation", (int,))):
        value = sim.get(key)
        if not positive_number(value, kind):
            expected = "a number > 0" if key == "fps" else "a whole number > 0"
            raise fail(
                f"metadata 'experiment_config': 'simulator.config.sim.{key}': expected "
                f"{expected}, got {value!r}"
            )
        values.append(value)
    return values[0] / values[1]


def _position_control(get, fail) -> dict:
    """``experiment_config.robot.control``, checked to be joint position targets (control type
    ``P``, every action term a ``JointPositionActionTerm``).

    Raises:
        ForeignFormatError: another control type or action term (named).
    """
    control = get("robot", "control")
    if control.get("control_type") != "P":
        raise fail(
            f"experiment_config.robot.control.control_type is {control.get('control_type')!r}: "
            "only 'P' (joint position targets) maps onto this toolkit's position mode"
        )
    action_terms = get("action", "terms", default={}) or {}
    for key, term in action_terms.items():
        if not str(term.get("func", "")).endswith(":JointPositionActionTerm"):
            raise fail(f"action term '{key}' is {term.get('func')!r}, not JointPositionActionTerm")
    return control


def _observation_terms(get, groups, fail) -> list:
    """The actor's observation terms, group by group, each group's terms sorted (holosoma's
    observation manager concatenates them so), with their history, clip and gait clock."""
    global_clip = get("observation", "clip_observations", default=None)
    gait = get("command", "setup_terms", "locomotion_gait", default=None)
    terms = []
    for group in groups:
        cfg = get("observation", "groups", group)
        history = int(cfg.get("history_length", 1) or 1)
        for name in sorted(cfg.get("terms", {})):
            term = _term(name, cfg["terms"][name], history, global_clip, fail)
            terms.append(_gait_term(term, gait, fail) if term.kind == "gait_phase" else term)
    return terms


#: What ``experiment_config`` holds that nothing else in holosoma's metadata does.
FROM_EXPERIMENT_CONFIG = (
    "observation terms (their order, scales and clips)",
    "default pose",
    "action clip",
    "control rate",
)


def _numbers(md: dict, key: str, n: int, fail) -> tuple[float, ...] | None:
    """Metadata ``key`` as ``n`` numbers (None: absent or null).

    Raises:
        ForeignFormatError (through ``fail``): not a list of ``n`` numbers.
    """
    value = md.get(key)
    if value is None:
        return None
    if not (isinstance(value, list) and len(value) == n and all(_is_number(v) for v in value)):
        raise fail(f"metadata '{key}' is {str(value)[:60]}; expected {n} numbers (one per dof)")
    return tuple(float(v) for v in value)


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def partial(facts, md: dict, names: tuple[str, ...], fail) -> ForeignContract:
    """The contract of a holosoma export without ``experiment_config`` (the G1 policies
    holosoma_inference ships): joints, kp, kd, command ranges and (newer exports) the action
    scale from the metadata; ``missing`` names the rest (:data:`FROM_EXPERIMENT_CONFIG`). It has
    no observation terms: :func:`sim2real.deploy.spec.foreign.mapping.to_spec` refuses it
    naming them, ``robot-import --drive-from`` reads its gains.

    Raises:
        ForeignFormatError: ``kp``, ``kd`` or a per-joint ``action_scale`` that is not one
            number per dof.
    """
    n = len(names)
    kp, kd = _numbers(md, "kp", n, fail), _numbers(md, "kd", n, fail)
    scale = md.get("action_scale")
    action_scale = float(scale) if _is_number(scale) else _numbers(md, "action_scale", n, fail)
    lacks = list(FROM_EXPERIMENT_CONFIG) + (["action scale"] if action_scale is None else [])
    lacks += ["kd"] if kd is None else []
    found = [("dof_names", f"{n} joints")]
    found += [(k, json.dumps(md[k])) for k in ("kp", "kd", "action_scale", "command_ranges")
              if md.get(k) is not None]  # fmt: skip
    return facts.contract(
        NAME,
        "ONNX metadata (holosoma attach_onnx_metadata, no experiment_config)",
        joint_names=names,
        terms=(),
        action_scale=action_scale,
        kp=kp,
        kd=kd,
        command_ranges=command_ranges(md.get("command_ranges")),
        found=found,
        missing=[
            "metadata 'experiment_config' (the training configuration): "
            + ", ".join(lacks)
            + " are not in the file; deploy-run needs a spec (--spec) for this policy"
        ],
    )


def _term(name: str, cfg: dict, history: int, global_clip, fail) -> Term:
    func = str(cfg.get("func", ""))
    key = func.rpartition(":")[2] or name
    raw_scale = cfg.get("scale", 1.0)
    scale = tuple(float(s) for s in raw_scale) if isinstance(raw_scale, list) else float(raw_scale)
    clips = [float(global_clip)] if global_clip is not None else []
    reason = ""
    if cfg.get("clip") is not None:
        lo, hi = (float(x) for x in cfg["clip"])
        if lo != -hi or not hi > 0:
            reason = f"an asymmetric clip [{lo:g}, {hi:g}] (blocks clip symmetrically)"
        clips.append(hi)  # holosoma clips after scaling
    clip = min(clips) if clips else None
    if key in TERMS:
        kind, size, components = TERMS[key]
    elif key in PHASE_TERMS:
        kind, size, components = "gait_phase", 2, PHASE_TERMS[key]
    else:
        kind, components = None, ()
        size, reason = 0, f"the function {func!r} is not one this toolkit maps"
    if reason:
        kind = None
    return Term(
        name, kind, size, scale, clip, components, reason=reason, source=func, history=history
    )


def _gait_term(term: Term, gait, fail) -> Term:
    """A phase term with holosoma's clock: period and held phase from the ``locomotion_gait``
    command term's params (:data:`GAIT_DEFAULTS` where it leaves them out), stopping below
    ``STAND_BELOW``; unmapped without that command term (holosoma itself raises then).

    Raises:
        ForeignFormatError: a period that is not a positive number or a held phase that is not
            a number (named).
    """
    if not isinstance(gait, dict):
        reason = "no command term 'locomotion_gait' (the gait clock's period) in the configuration"
        return dataclasses.replace(term, kind=None, reason=reason)
    params = {**GAIT_DEFAULTS, **(gait.get("params") or {})}
    period, held = params["gait_period"], params["stand_phase_value"]
    if not (_is_number(period) and period > 0):
        raise fail(
            "experiment_config.command.setup_terms.locomotion_gait.params.gait_period is "
            f"{period!r}; expected the gait period in s (> 0)"
        )
    if not _is_number(held):
        raise fail(
            "experiment_config.command.setup_terms.locomotion_gait.params.stand_phase_value is "
            f"{held!r}; expected a phase in rad"
        )
    return dataclasses.replace(
        term, period=float(period), stand_below=STAND_BELOW, stand_phase=float(held)
    )
