"""Unitree's ``deploy.yaml``: the contract unitree_rl_lab and unitree_rl_mjlab write by a policy.

Unitree's Isaac Lab and mjlab stacks export a bare graph (``obs`` -> ``actions``, no metadata)
to ``<policy>/exported/policy.onnx`` (its weights may sit in ``policy.onnx.data``, ONNX's
external data) and the contract their C++ deployment reads to ``<policy>/params/deploy.yaml``
(unitree_rl_mjlab ``deploy/robots/<robot>/config/policy/<task>/<version>/``; read by its
``deploy/include/isaaclab``). It is looked for at ``../params/deploy.yaml``,
``params/deploy.yaml`` and ``deploy.yaml`` from the ONNX file's folder and read with a safe YAML
loader that builds one Python tag, the ``slice`` unitree_rl_lab's ``yaml.dump`` writes for "every
joint" (``!!python/object/apply:builtins.slice``). Its keys, as that C++ code uses them:

- ``joint_ids_map``: the motor slot (LowState / LowCmd index) of each policy joint, in the
  policy's order: ``joint_pos[i] = motor_state[joint_ids_map[i]].q``. The joint order is
  therefore the robot's joints ordered by these slots (robot.toml ``[unitree] motor_index``; a
  robot without it is refused: ``robot-import --unitree FAMILY`` numbers its slots).
- ``step_dt``: the control period, s.
- ``stiffness``, ``damping``: the PD gains in the motor slots' order (``motor_cmd[i].kp =
  stiffness[i]``; the exporter writes ``stiffness[joint_ids_map] = ...``); every other per-joint
  list is in the policy's order: ``default_joint_pos``, the pose ``joint_pos_rel`` is relative to.
- ``actions.JointPositionAction``: ``target = raw * scale + offset`` (an absent ``offset`` is 0;
  an absent ``scale`` is 1), then ``clip``: per joint ``[low, high]`` of the target (not mapped
  here: refused in one line); ``joint_ids``: every joint (null, the whole slice, or each index in
  turn) or a subset (refused).
- ``observations``: the terms in the graph's order; each clipped (``[low, high]``) and then
  scaled (per entry), Isaac Lab's order; ``history_length`` N: the term's last N readings, the
  oldest first, each term's in turn, all N the current reading at the policy's start (its
  ``ObservationTermCfg::reset``): the spec's per-term history, fill ``first``; 1 the present only.
  ``velocity_commands`` is the command, clamped by the C++ code to ``commands.base_velocity.
  ranges`` (kept in the contract's notes; our runtime gives the policy the command as given);
  ``gait_phase`` (``params.period``, s) is ``[sin, cos]`` of the phase.
"""

from __future__ import annotations

from pathlib import Path

from sim2real.deploy.spec.foreign.contract import (
    ISAACLAB_TERMS,
    ForeignContract,
    Term,
    clip_before_scaling,
    command_ranges,
)

NAME = "unitree_deploy"
#: Where the contract is looked for, relative to the ONNX file's folder.
DEPLOY_YAML = (
    Path("..") / "params" / "deploy.yaml",
    Path("params") / "deploy.yaml",
    Path("deploy.yaml"),
)
#: The C++ deployment's observation terms (``REGISTER_OBSERVATION``) -> (our kind, size,
#: relative to the default pose): Isaac Lab's that it shares, and its own.
TERMS = {
    **ISAACLAB_TERMS,
    "velocity_commands": ("velocity_command", 3, True),
    "gait_phase": ("gait_phase", 2, True),
}
ORDER_NOTE = "deploy.yaml joint_ids_map: the motor slot of each policy joint"


def _find(facts) -> Path | None:
    folder = facts.path.resolve().parent
    return next((p for p in (folder / c for c in DEPLOY_YAML) if p.is_file()), None)


def detect(facts) -> bool:
    """A bare ``obs`` -> ``actions`` graph with a ``deploy.yaml`` beside it (module docstring)."""
    bare = bool(facts.inputs) and facts.inputs[0] == "obs" and "actions" in facts.outputs
    return bare and _find(facts) is not None


def read(facts) -> ForeignContract:
    """The contract of a policy with Unitree's ``deploy.yaml`` (module docstring).

    Raises:
        ForeignFormatError: the file is not YAML, or a key is missing, of the wrong length or
            not mappable (naming the file and the key).
    """
    import yaml

    fail = facts.failure(NAME)
    path = _find(facts)
    where = str(path)
    try:
        cfg = yaml.load(path.read_text(), Loader=_loader())  # noqa: S506 - a SafeLoader subclass
    except (OSError, yaml.YAMLError) as exc:
        raise fail(f"{where}: not readable as YAML: {exc}") from None
    if not isinstance(cfg, dict):
        raise fail(f"{where}: expected a mapping of keys, got {type(cfg).__name__}")

    def key(name, kind=list):
        value = cfg.get(name)
        if not isinstance(value, kind):
            raise fail(f"{where}: '{name}': expected a {kind.__name__}, got {value!r}")
        return value

    slots = tuple(int(s) for s in key("joint_ids_map"))
    n = len(slots)
    if facts.act_dim is not None and facts.act_dim != n:
        raise fail(f"{where}: 'joint_ids_map' has {n} joints, the graph {facts.act_dim} actions")
    if len(set(slots)) != n:
        raise fail(f"{where}: 'joint_ids_map' repeats a motor slot: {list(slots)}")

    def joints(name, value):
        if not (isinstance(value, list) and len(value) == n):
            raise fail(f"{where}: '{name}': expected {n} numbers (one per joint), got {value!r}")
        return tuple(float(v) for v in value)

    step_dt = cfg.get("step_dt")
    if not (isinstance(step_dt, int | float) and step_dt > 0):
        raise fail(f"{where}: 'step_dt': expected the control period in s (> 0), got {step_dt!r}")
    default = joints("default_joint_pos", cfg.get("default_joint_pos"))
    kp, kd = (
        _by_slot(name, cfg.get(name), slots, where, fail) for name in ("stiffness", "damping")
    )
    raw_scale, raw_offset, scale, offset = _action(key("actions", dict), n, joints, where, fail)
    observations = key("observations", dict)
    terms = tuple(_term(name, term or {}, where, fail) for name, term in observations.items())
    ranges = ((cfg.get("commands") or {}).get("base_velocity") or {}).get("ranges")
    notes = [f"joint order: {ORDER_NOTE} {list(slots)}"]
    if ranges:
        notes.append(
            f"commands.base_velocity.ranges {ranges}: the C++ deployment clamps the command to "
            "them; here the command reaches the policy as given"
        )
    found = [
        ("deploy.yaml", where),
        ("joint_ids_map", str(list(slots))),
        ("observations", ", ".join(t.name for t in terms)),
        ("actions.JointPositionAction", f"scale {raw_scale}, offset {raw_offset}"),
        ("control rate", f"1 / {step_dt} s"),
    ]
    return facts.contract(
        NAME,
        where,
        joint_names=None,
        joint_order_rule="motor_slots",
        joint_order_note=ORDER_NOTE,
        joint_slots=slots,
        terms=terms,
        default_pose=default,
        action_scale=scale if isinstance(scale, tuple) else float(scale),
        action_offset=offset,
        action_clip=None,
        kp=kp,
        kd=kd,
        control_rate=1.0 / float(step_dt),
        command_ranges=command_ranges(ranges),
        found=found,
        notes=notes,
    )


def _action(actions: dict, n: int, joints, where: str, fail):
    """``(raw scale, raw offset, scale, offset)`` of deploy.yaml's one JointPositionAction over
    every joint (a scale a number or one per joint; an offset one per joint, default 0).

    Raises:
        ForeignFormatError (``fail``): another action, a subset of the joints, a per-joint clip.
    """
    if set(actions) != {"JointPositionAction"}:
        raise fail(f"{where}: actions {sorted(actions)}: only one JointPositionAction maps")
    action = actions["JointPositionAction"] or {}
    if not _every_joint(action.get("joint_ids"), n):
        raise fail(
            f"{where}: actions.JointPositionAction.joint_ids {action['joint_ids']}: only an "
            "action over every joint of joint_ids_map maps"
        )
    if action.get("clip") is not None:
        raise fail(
            f"{where}: actions.JointPositionAction.clip: a per-joint clip of the targets is not "
            "mapped (our action clip bounds the raw action); remove it or pass --spec FILE"
        )
    raw_scale = action.get("scale")
    scale = 1.0 if raw_scale is None else raw_scale
    scale = joints("actions.JointPositionAction.scale", scale) if isinstance(scale, list) else scale
    raw_offset = action.get("offset")
    offset = (
        (0.0,) * n
        if raw_offset is None
        else joints("actions.JointPositionAction.offset", raw_offset)
    )
    return raw_scale, raw_offset, scale, offset


def _term(name: str, cfg: dict, where: str, fail) -> Term:
    """One observation term (module docstring): its kind, scale and clip (clipped before
    scaling, so our clip is ``high * |scale|``)."""
    kind, size, relative = TERMS.get(name, (None, 0, True))
    reason = f"{where}: not a term Unitree's deployment registers and this toolkit maps"
    raw = cfg.get("scale")
    if isinstance(raw, list):
        scale = tuple(float(x) for x in raw)
        if len(set(scale)) == 1:
            scale = scale[0]
    else:
        scale = float(1.0 if raw is None else raw)
    clip = None
    if cfg.get("clip") is not None:
        lo, hi = (float(x) for x in cfg["clip"])
        clip, problem = clip_before_scaling(lo, hi, scale)
        if problem:
            kind, reason = None, problem
    history = 1 if cfg.get("history_length") is None else cfg["history_length"]
    if not (isinstance(history, int) and not isinstance(history, bool) and history >= 0):
        kind, reason = None, f"history_length {history!r} (expected a number of steps >= 1)"
        history = 1
    params = cfg.get("params") or {}
    if not _every_joint((params.get("asset_cfg") or {}).get("joint_ids"), None):
        kind, reason = None, f"it reads the joints {params['asset_cfg']['joint_ids']} (a subset)"
    period = 0.0
    if name == "gait_phase":
        period = float(params.get("period") or 0.0)
        if not period > 0:
            kind, reason = None, f"gait_phase without a period (params {params})"
    return Term(
        name, kind, size, scale, clip, relative=relative, reason=reason, period=period,
        history=history,
    )  # fmt: skip


def _loader():
    """A safe YAML loader that also builds ``!!python/object/apply:builtins.slice [a, b, c]``
    (the only Python tag Unitree's exporter writes); any other Python tag stays refused."""
    import yaml

    class Loader(yaml.SafeLoader):
        """yaml.SafeLoader and the slice tag."""

    Loader.add_constructor(
        "tag:yaml.org,2002:python/object/apply:builtins.slice",
        lambda loader, node: slice(*loader.construct_sequence(node)),
    )
    return Loader


def _every_joint(ids, n: int | None) -> bool:
    """Whether ``joint_ids`` selects every joint: absent, the whole ``slice`` (Isaac Lab's
    ``slice(None)``), or the indices ``0 .. n-1`` in turn (``n`` None: not checked)."""
    if ids is None or ids == slice(None):
        return True
    return n is not None and isinstance(ids, list) and ids == list(range(n))


def _by_slot(name: str, value, slots, where: str, fail) -> tuple[float, ...]:
    """A per-motor list (the motor slots' order, module docstring) as the policy's joints see it:
    entry ``slots[i]`` for joint ``i``."""
    if not (isinstance(value, list) and len(value) > max(slots)):
        raise fail(
            f"{where}: '{name}': expected one number per motor slot (>= {max(slots) + 1}, in the "
            f"slots' order), got {value!r}"
        )
    return tuple(float(value[s]) for s in slots)
