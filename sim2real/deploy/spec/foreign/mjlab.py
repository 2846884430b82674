"""mjlab's ONNX metadata (``mjlab.rl.exporter_utils``: ``get_base_metadata`` and
``attach_metadata_to_onnx``; mujocolab/mjlab).

mjlab's velocity runner exports the actor with Isaac Lab's exporter (``obs`` -> ``actions``, batch
fixed at 1, opset 11) and appends ``model.metadata_props``, every value a string: a list is
comma-separated with numbers at three decimals (``list_to_csv_str``), an entry that is itself a
list (a per-entry scale, a ``[min, max]`` clip) joined with ``;``; anything else is ``str()``.

==================================  ===========================================================
key                                 value
==================================  ===========================================================
``joint_names``                     the robot's joints, in the policy's order
``joint_stiffness``, ``_damping``   the actuators' PD gains, N m/rad and N m s/rad
``default_joint_pos``               the default pose, rad (actions and ``joint_pos`` about it)
``action_scale``                    one number or one per joint: ``target = default + s a``
``observation_names``               the actor group's terms, in order
``command_names``                   the command terms (``twist``: vx, vy, yaw rate)
``observation_terms_scale``         (newer mjlab) per term: its multiplier (``1.000``: none)
``observation_terms_clip``          (newer mjlab) per term: ``min;max`` before scaling
``observation_terms_history_length`` (newer mjlab) per term: steps of history (0: none; N: its
                                    last N values, oldest first, filled with its first value)
``run_path``                        the W&B run (not used)
==================================  ===========================================================

The metadata names the terms, not the functions behind them: they map by the names of mjlab's
velocity task (``base_lin_vel``, ``base_ang_vel``, ``projected_gravity``, ``joint_pos`` and
``joint_vel`` relative to the default, ``actions``, ``command``). Not recorded: the control rate
(the robot's holds), the action clip (mjlab's ``JointPositionAction`` clips nothing); without the
newer keys, scales of 1 and no clip (the velocity task's terms have none).
"""

from __future__ import annotations

import math
import re

from sim2real.deploy.spec.foreign.contract import ForeignContract, Term, clip_before_scaling

NAME = "mjlab"
#: Keys that identify mjlab's metadata.
REQUIRED = ("joint_names", "observation_names", "default_joint_pos", "action_scale")

#: mjlab velocity-task term name -> (our kind, size; -1 one per joint).
TERMS = {
    "base_lin_vel": ("base_linear_velocity", 3),
    "base_ang_vel": ("base_angular_velocity", 3),
    "projected_gravity": ("projected_gravity", 3),
    "joint_pos": ("joint_position", -1),
    "joint_vel": ("joint_velocity", -1),
    "actions": ("last_action", -1),
    "command": ("velocity_command", 3),
}
#: Terms no robot here provides, and why.
UNMAPPED = {
    "height_scan": (
        "a terrain height scan whose grid the metadata does not state (pass --spec FILE with a "
        "height_scan block and its scan)"
    ),
    "foot_height": "foot heights over the terrain (a height map)",
    "foot_air_time": "the feet's air time (a training-only quantity)",
    "foot_contact_forces": "contact forces (no robot here measures them)",
}


def detect(facts) -> bool:
    """mjlab's metadata: the keys of ``REQUIRED`` are present."""
    return all(k in facts.metadata for k in REQUIRED)


def _items(text: str) -> list[str]:
    """A ``list_to_csv_str`` value's entries (an older mjlab wrote a nested list as
    ``[a, b],[c, d]``: each bracket is one entry, its commas turned into ``;``)."""
    text = text.strip()
    if "[" in text:
        return [m.replace(",", ";").replace(" ", "") for m in re.findall(r"\[([^\]]*)\]", text)]
    return [t.strip() for t in text.split(",")] if text else []


def read(facts) -> ForeignContract:
    """The contract of an mjlab export (module docstring).

    Raises:
        ForeignFormatError: a value that is not what mjlab writes (naming the key).
    """
    md = facts.metadata
    fail = facts.failure(NAME)

    def floats(key: str) -> tuple[float, ...]:
        try:
            return tuple(float(x) for x in _items(md[key]))
        except ValueError:
            raise fail(f"metadata '{key}' = {md[key]!r} is not a list of numbers") from None

    names = tuple(_items(md["joint_names"]))
    default = floats("default_joint_pos")
    scale_items = floats("action_scale")
    action_scale = scale_items[0] if len(scale_items) == 1 else scale_items
    kp = floats("joint_stiffness") if "joint_stiffness" in md else None
    kd = floats("joint_damping") if "joint_damping" in md else None
    commands = _items(md.get("command_names", ""))
    observation = _items(md["observation_names"])
    per_term = {}
    for key in (
        "observation_terms_scale",
        "observation_terms_clip",
        "observation_terms_history_length",
    ):
        if key in md:
            per_term[key] = _items(md[key])
            if len(per_term[key]) != len(observation):
                raise fail(
                    f"metadata '{key}' has {len(per_term[key])} entries, 'observation_names' "
                    f"{len(observation)}"
                )
    terms = []
    for i, name in enumerate(observation):
        scale = _scale(per_term, i, fail)
        clip, clip_reason = _clip(per_term, i, scale, fail)
        history = _history(per_term, i, fail)
        kind, size = TERMS.get(name, (None, 0))
        reason = UNMAPPED.get(name, "not a term of mjlab's velocity task (mapped by name)")
        if name == "command" and "twist" not in commands:
            kind, reason = None, f"the command terms are {commands}, not the velocity 'twist'"
        if clip_reason:
            kind, reason = None, clip_reason
        terms.append(Term(name, kind, size, scale, clip, reason=reason, history=int(history)))
    missing = [
        "control rate: not recorded; the robot's is used (mjlab's velocity task: 0.005 s x "
        "decimation 4)"
    ]
    if "observation_terms_scale" not in md:
        missing.append("observation scales: not recorded (older mjlab); 1 (unscaled) assumed")
    if "observation_terms_clip" not in md:
        missing.append("observation clips: not recorded (older mjlab); unclipped assumed")
    if kp is None or kd is None:
        missing.append("PD gains: not recorded; the robot's robot.toml gains are used")
    found = [(k, _short(md[k])) for k in md if k != "run_path"]
    return facts.contract(
        NAME,
        "ONNX metadata (mjlab attach_metadata_to_onnx)",
        joint_names=names,
        terms=terms,
        default_pose=default,
        action_scale=action_scale,
        action_clip=None,
        kp=kp,
        kd=kd,
        control_rate=None,
        found=found,
        missing=missing,
        notes=(
            "terms mapped by their names in mjlab's velocity task (the metadata names no "
            "functions)",
            "action clip: none (mjlab's JointPositionAction clips nothing)",
        ),
    )


def _scale(per_term: dict, i: int, fail) -> float | tuple[float, ...]:
    if "observation_terms_scale" not in per_term:
        return 1.0
    text = per_term["observation_terms_scale"][i]
    try:
        values = tuple(float(x) for x in text.split(";"))
    except ValueError:
        raise fail(f"metadata 'observation_terms_scale' entry {i} = {text!r}") from None
    return values[0] if len(values) == 1 else values


def _history(per_term: dict, i: int, fail) -> float:
    """Steps of history of term ``i`` (0: none, also when the key is not recorded)."""
    if "observation_terms_history_length" not in per_term:
        return 0.0
    text = per_term["observation_terms_history_length"][i]
    try:
        return float(text or 0)
    except ValueError:
        raise fail(f"metadata 'observation_terms_history_length' entry {i} = {text!r}") from None


def _clip(per_term: dict, i: int, scale, fail) -> tuple[float | None, str]:
    """(symmetric clip of the scaled value or None, why it cannot be mapped or '')."""
    if "observation_terms_clip" not in per_term:
        return None, ""
    text = per_term["observation_terms_clip"][i]
    try:
        lo, hi = (float(x) for x in text.split(";"))
    except ValueError:
        raise fail(f"metadata 'observation_terms_clip' entry {i} = {text!r}: not min;max") from None
    if math.isinf(lo) and math.isinf(hi) and lo < 0 < hi:
        return None, ""
    return clip_before_scaling(lo, hi, scale)  # mjlab clips before scaling


def _short(text: str) -> str:
    return text if len(text) <= 100 else text[:97] + "..."
