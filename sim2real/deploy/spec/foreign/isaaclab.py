"""Isaac Lab's and rsl_rl's ONNX exports, and the run folder Isaac Lab keeps beside them.

Both exporters write a bare graph: Isaac Lab's ``export_policy_as_onnx``
(``isaaclab_rl.rsl_rl.exporter``: ``obs`` -> ``actions``, or ``obs``, ``h_in``[, ``c_in``] ->
``actions``, ``h_out``[, ``c_out``]; opset 11, batch fixed at 1, the empirical normalizer in the
graph) and rsl_rl's ``OnPolicyRunner.export_policy_to_onnx`` (the model's ``as_onnx()``: the same
names, opset 18). **Neither writes metadata**: no joint names, terms, scales, gains or pose.

Isaac Lab's contract is its run folder: ``train.py`` dumps the environment configuration to
``<run>/params/env.yaml`` (``isaaclab.utils.io.dump_yaml``: ``class_to_dict``, functions and
classes as ``"module:name"``, tuples as ``!!python/tuple``) and ``play.py`` exports to
``<run>/exported/policy.onnx``. It is looked for at ``../params/env.yaml``, ``params/env.yaml``
and ``env.yaml`` from the ONNX file's folder, and read with a safe YAML loader (Python tags become
plain data; nothing is constructed or run). From it: the ``policy`` observation group's terms in
order (their functions, ``scale`` and ``clip`` (Isaac Lab clips before scaling), a
``height_scan``'s sensor grid (:mod:`sim2real.deploy.spec.foreign.isaaclab_scan`),
``history_length``: the term's last N values, oldest first, its ``CircularBuffer`` filled with
its first value after a reset; the group's, when set, for every term), the ``joint_pos`` action
(``JointPositionAction``: ``scale``, ``offset``, ``use_default_offset``, ``clip``), the robot's
``init_state.joint_pos`` and its actuators' ``stiffness`` and ``damping`` (regular expressions
over joint names) and the control rate
(``1 / (sim.dt * decimation)``); ``params/agent.yaml``'s ``clip_actions`` (rsl_rl's wrapper)
when present.

Not in any file: the joint order. Isaac Lab's observations and actions over every joint follow
the articulation, which PhysX orders breadth first over the kinematic tree: it is taken from the
robot's tree (:func:`sim2real.deploy.spec.foreign.mapping.breadth_first_order`) and said so.
"""

from __future__ import annotations

from pathlib import Path

from sim2real.deploy.spec.foreign.contract import (
    ISAACLAB_TERMS,
    ForeignContract,
    Term,
    clip_before_scaling,
    positive_number,
)
from sim2real.deploy.spec.foreign.isaaclab_scan import FUNCTION as SCAN
from sim2real.deploy.spec.foreign.isaaclab_scan import height_scan_term

NAME = "isaaclab"
#: Where the run's configuration is looked for, relative to the ONNX file's folder.
ENV_YAML = (Path("..") / "params" / "env.yaml", Path("params") / "env.yaml", Path("env.yaml"))

#: Isaac Lab's observation functions (``isaaclab.envs.mdp.observations``) -> (our kind, size,
#: relative to the default pose).
TERMS = {
    **ISAACLAB_TERMS,
    "generated_commands": ("velocity_command", 3, True),
    "joint_vel": ("joint_velocity", -1, True),
}
UNMAPPED = {
    "height_scan": "a terrain height scan",
    "base_pos_z": "the base height (no robot here measures it)",
    "joint_pos_limit_normalized": "joint positions normalized by the simulator's soft limits",
}
_ALL_JOINTS = (None, [".*"], ".*")
ORDER_NOTE = (
    "not in any file; Isaac Lab's articulation order assumed (PhysX: breadth first over the "
    "robot's kinematic tree)"
)


def detect(facts) -> bool:
    """Isaac Lab's / rsl_rl's graph names: ``obs`` (and ``h_in``, ``c_in``) -> ``actions``."""
    return bool(facts.inputs) and facts.inputs[0] == "obs" and "actions" in facts.outputs


def _positive(value, kind, where: str, unit: str, fail):
    """``value`` (env.yaml's ``sim.dt``, s, or ``decimation``) as a number of ``kind`` above 0:
    the control period is their product and the rate its inverse. Raises ``fail``'s error naming
    the file and key (a bool, a string, 0 or below, not finite)."""
    if not positive_number(value, kind):
        raise fail(f"{where}: expected a number of {unit} > 0, got {value!r}")
    return value


def _load_yaml(path: Path, fail):
    import yaml

    class Loader(yaml.SafeLoader):
        """Safe loading of ``yaml.dump``'s Python tags: a tuple is a list, any other Python
        object its tag as a string (nothing is imported or constructed)."""

    Loader.add_constructor(
        "tag:yaml.org,2002:python/tuple", lambda loader, node: loader.construct_sequence(node)
    )
    Loader.add_multi_constructor(
        "tag:yaml.org,2002:python/", lambda loader, suffix, node: f"<python/{suffix}>"
    )
    try:
        return yaml.load(path.read_text(), Loader=Loader)  # noqa: S506 - a SafeLoader subclass
    except (OSError, yaml.YAMLError) as exc:
        raise fail(f"{path}: not readable as YAML: {exc}") from None


def read(facts) -> ForeignContract:
    """The contract of an Isaac Lab run (module docstring).

    Raises:
        ForeignFormatError: no ``env.yaml`` (naming where it was looked for), or a section of it
            that does not map (naming it).
    """
    fail = facts.failure(NAME)
    folder = facts.path.resolve().parent
    candidates = [(folder / p).resolve() for p in ENV_YAML]
    env_path = next((p for p in candidates if p.is_file()), None)
    if env_path is None:
        raise fail(
            "Isaac Lab / rsl_rl export (obs -> actions) without metadata: the file carries no "
            "joint order, observation terms, scales, gains or default pose; Isaac Lab keeps them "
            f"in the run's params/env.yaml, looked for at {[str(p) for p in candidates]}: not "
            "found; pass --spec FILE"
        )
    env = _load_yaml(env_path, fail)
    where = str(env_path)

    def get(node, *keys):
        for k in keys:
            if not isinstance(node, dict) or k not in node:
                raise fail(f"{where}: no '{'.'.join(keys)}'")
            node = node[k]
        return node

    group = get(env, "observations", "policy")
    history = group.get("history_length")
    commands = env.get("commands") or {}
    terms = [
        _term(key, cfg, history, commands)
        for key, cfg in group.items()
        if isinstance(cfg, dict) and "func" in cfg
    ]
    scene = env.get("scene") or {}
    terms = [  # a height scan: its sensor's grid (sim2real.deploy.spec.foreign.isaaclab_scan)
        height_scan_term(t, group[t.name], scene) if t.source.endswith(f":{SCAN}") else t
        for t in terms
    ]
    action_key, action = _position_action(get(env, "actions"), where, fail)
    robot = get(env, "scene", "robot")
    gains, missing, notes = _gains(robot)
    missing.insert(0, f"joint order: {ORDER_NOTE}")
    clip = _action_clip(action, env_path, fail)
    dt = _positive(get(env, "sim", "dt"), (int, float), f"{where}: 'sim.dt'", "seconds", fail)
    decimation = _positive(get(env, "decimation"), (int,), f"{where}: 'decimation'",
                           "physics steps (a whole number)", fail)  # fmt: skip
    found = [
        ("env.yaml", where),
        ("observations.policy", ", ".join(t.name for t in terms)),
        (f"actions.{action_key}", f"scale {action.get('scale')}, offset {action.get('offset')}"),
        ("scene.robot.init_state.joint_pos", str(robot.get("init_state", {}).get("joint_pos"))),
        ("control rate", f"1 / ({dt} s x {decimation})"),
    ]
    return facts.contract(
        NAME,
        where,
        joint_names=None,
        joint_order_rule="breadth_first",
        joint_order_note=ORDER_NOTE,
        terms=terms,
        default_pose=_patterns(robot.get("init_state", {}).get("joint_pos"), default=0.0),
        action_scale=_patterns(action.get("scale", 1.0)),
        action_offset=None
        if action.get("use_default_offset", True)
        else _patterns(action.get("offset", 0.0)),
        action_clip=clip,
        kp=gains[0],
        kd=gains[1],
        control_rate=1.0 / (float(dt) * decimation),
        found=found,
        missing=missing,
        notes=notes,
    )


def _position_action(actions, where: str, fail) -> tuple[str, dict]:
    """The one action term of ``env.yaml``'s ``actions`` and its key, checked to be a
    ``JointPositionAction`` over every joint in the articulation's order.

    Raises:
        ForeignFormatError: several action terms, another kind, or a subset of the joints.
    """
    actions = {k: v for k, v in (actions or {}).items() if isinstance(v, dict)}
    if len(actions) != 1 or not str(next(iter(actions.values())).get("class_type", "")).endswith(
        ":JointPositionAction"
    ):
        kinds = {k: v.get("class_type") for k, v in actions.items()}
        raise fail(f"{where}: actions {kinds}: only one JointPositionAction maps")
    ((action_key, action),) = actions.items()
    if action.get("joint_names") not in _ALL_JOINTS or action.get("preserve_order"):
        raise fail(
            f"{where}: actions.{action_key} selects joints {action.get('joint_names')} "
            f"(preserve_order {action.get('preserve_order')}): only every joint in the "
            "articulation's order maps"
        )
    return action_key, action


def _patterns(value, default: float | None = None):
    """A config value as a :data:`~sim2real.deploy.spec.foreign.contract.PerJoint` (``{".*": 0}`` for a
    missing table with ``default``)."""
    if value is None:
        return None if default is None else float(default)
    if isinstance(value, dict):
        return {str(k): float(v) for k, v in value.items()}
    return float(value)


def _term(key: str, cfg: dict, group_history: int | None, commands: dict) -> Term:
    func = str(cfg.get("func", ""))
    name = func.rpartition(":")[2]
    raw = cfg.get("scale")
    scale = tuple(map(float, raw)) if isinstance(raw, list) else float(1.0 if raw is None else raw)
    kind, size, relative = TERMS.get(name, (None, 0, True))
    reason = UNMAPPED.get(name, f"the function {func!r} is not one this toolkit maps")
    if name == "generated_commands":
        command = (cfg.get("params") or {}).get("command_name")
        ctype = str((commands.get(command) or {}).get("class_type", ""))
        if not ctype.endswith("VelocityCommand"):
            kind, reason = None, f"command '{command}' is {ctype or 'unknown'}, not a velocity one"
    params = cfg.get("params") or {}
    asset = params.get("asset_cfg") or {}
    if isinstance(asset, dict) and asset.get("joint_names") not in _ALL_JOINTS:
        kind, reason = None, f"it reads the joints {asset.get('joint_names')} (a subset)"
    # the group's history_length, when set, is every term's (ObservationManager._prepare_terms)
    history = int(group_history if group_history is not None else cfg.get("history_length") or 0)
    clip = None
    if cfg.get("clip") is not None:
        lo, hi = (float(x) for x in cfg["clip"])
        clip, problem = clip_before_scaling(lo, hi, scale)  # as Isaac Lab clips
        if problem:
            kind, reason = None, problem
    if history > 1 and cfg.get("flatten_history_dim") is False:
        kind, reason = None, f"a history of {history} steps not flattened (flatten_history_dim)"
    return Term(
        key, kind, size, scale, clip, relative=relative, reason=reason, source=func,
        history=history,
    )  # fmt: skip


def _gains(robot: dict):
    """((kp, kd) pattern tables or None, missing lines, notes) of the robot's actuators."""
    kp: dict[str, float] = {}
    kd: dict[str, float] = {}
    missing, notes = [], []
    for name, act in (robot.get("actuators") or {}).items():
        ctype = str(act.get("class_type", ""))
        exprs = act.get("joint_names_expr") or []
        if "ActuatorNet" in ctype:
            missing.append(f"PD gains of actuator '{name}': an actuator network ({ctype})")
            continue
        for table, key in ((kp, "stiffness"), (kd, "damping")):
            value = act.get(key)
            if value is None:
                missing.append(f"{key} of actuator '{name}': not set (the USD's value)")
            elif isinstance(value, dict):
                table.update({str(k): float(v) for k, v in value.items()})
            else:
                table.update({str(e): float(value) for e in exprs})
        notes.append(f"actuator '{name}' ({ctype.rpartition(':')[2]}): PD on {exprs}")
    if missing:
        missing.append("PD gains: incomplete; the robot's robot.toml gains are used")
        return (None, None), missing, notes
    return (kp or None, kd or None), missing, notes


def _action_clip(action: dict, env_path: Path, fail) -> float | None:
    """The action's symmetric clip: the action term's ``clip`` table, or rsl_rl's
    ``clip_actions`` from ``params/agent.yaml`` beside ``env.yaml``; None: unclipped."""
    bounds = set()
    for pattern, pair in (action.get("clip") or {}).items():
        lo, hi = (float(x) for x in pair)
        if lo != -hi:
            raise fail(f"{env_path}: the action clip of '{pattern}' [{lo}, {hi}] is asymmetric")
        bounds.add(hi)
    if len(bounds) > 1:
        raise fail(f"{env_path}: the action clip differs between joints {sorted(bounds)}")
    agent = env_path.parent / "agent.yaml"
    if agent.is_file():
        value = (_load_yaml(agent, fail) or {}).get("clip_actions")
        if value is not None:
            bounds.add(float(value))
    return min(bounds) if bounds else None
