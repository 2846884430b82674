"""rl_sar's policy folder: ``config.yaml`` beside the policy, key ``<robot>/<stack>`` or
``<robot>/<group>/<stack>``, and the first ``base.yaml`` up whose one key is ``<robot>``
(fan-ziqi/rl_sar ``RL::ReadYamlBase``, ``ReadYamlRL``, ``ComputeObservation``, ``ComputeOutput``).
The policy: the ONNX graph beside config.yaml, or rl_sar's TorchScript ``policy.pt``
(``policy-export policy.pt``: :mod:`sim2real.deploy.export.folder_torchscript`; ``robot-import
--drive-from policy.pt``). Each file is one mapping under one key, read with a safe YAML loader;
config.yaml's keys win over base.yaml's. What it says, as rl_sar's code uses it:

- ``joint_mapping``: the motor slot of each policy joint (``q[i] = motor_state[joint_mapping[i]]``);
  ``joint_names``: the joint of each slot, in the slots' order (its Gazebo loop reads
  ``joint_controller_names[joint_mapping[i]]``), so policy joint ``i`` is
  ``joint_names[joint_mapping[i]]``. The names decide the joint order (a Go2-W's
  ``*_foot_joint`` is the MJCF's ``*_wheel_joint``), checked against robot.toml's ``[unitree]
  motor_index`` where the robot has one; a folder without names needs the robot's slots
  (:func:`sim2real.deploy.spec.foreign.mapping.slot_order`). ``dt`` x ``decimation``: the
  control period, s.
- ``observations`` in order, each scaled and then clipped to ``clip_obs``: ``ang_vel`` (body
  frame on a real robot; ``ang_vel_scale``), ``gravity_vec`` (projected gravity), ``commands``
  (``commands_scale``), ``lin_vel`` (``lin_vel_scale``), ``dof_pos`` (about ``default_dof_pos``,
  ``dof_pos_scale``; the entries of ``wheel_indices`` set to 0: a wheel's angle is never seen),
  ``dof_vel`` (``dof_vel_scale``), ``actions`` (the previous raw action);
  ``whole_body_tracking/motion_command``, ``motion_anchor_ori_b`` (the torso from the
  ``waist_joint_indices`` slots; :mod:`sim2real.deploy.spec.motion_blocks`), ``motion_file`` (the
  clip beside config.yaml at ``1 / (dt x decimation)`` Hz, its fsm's ``MotionLoader``, columns
  in the slots' order of ``joint_names``); ``RoboMimic_Deploy/phase``: ``motion_phase`` (:func:`_phase`).
  ``observations_history``: the frames read, 0 the newest (``observations_history_priority``
  ``time``: whole frames; ``term``: each term's frames in turn); empty: the present only.
- ``action_scale``, ``clip_actions_lower``/``_upper``: ``target = default_dof_pos + scale x
  action`` for a leg; for ``wheel_indices`` a speed target ``scale x action``, rad/s, the drive
  ``tau = rl_kd (v_target - dq)`` with ``rl_kp`` 0. ``rl_kp``, ``rl_kd``: the gains.
"""

from __future__ import annotations

from pathlib import Path

from sim2real.deploy.spec.foreign.contract import (
    ForeignContract,
    MotionSource,
    Term,
    positive_number,
)

NAME = "rl_sar"
CONFIG = Path("config.yaml")
ORDER_NOTE = (
    "rl_sar joint_mapping: the motor slot of each policy joint, joint_names[slot] its joint"
)
#: rl_sar's observation names -> (our kind, size (-1: one per joint), its scale key).
TERMS = {
    "ang_vel": ("base_angular_velocity", 3, "ang_vel_scale"),
    "ang_vel_body": ("base_angular_velocity", 3, "ang_vel_scale"),
    "gravity_vec": ("projected_gravity", 3, None),
    "commands": ("velocity_command", 3, "commands_scale"),
    "lin_vel": ("base_linear_velocity", 3, "lin_vel_scale"),
    "dof_pos": ("joint_position", -1, "dof_pos_scale"),
    "dof_vel": ("joint_velocity", -1, "dof_vel_scale"),
    "actions": ("last_action", -1, None),
    "whole_body_tracking/motion_command": ("motion_command", -2, None),
    "whole_body_tracking/motion_anchor_ori_b": ("motion_anchor_ori_b", 6, None),
    "RoboMimic_Deploy/phase": ("motion_phase", 1, None),
}
#: The motion's length ``T``, s, of each phase-clocked policy rl_sar ships, by its config key:
#: rl_sar's fsm sets it on entering the policy's state (``fsm_robot/fsm_g1.hpp``,
#: ``RLFSMStateRLRoboMimicCharleston::Enter``: ``rl.motion_length = 18.0``; RoboMimic_Deploy's
#: ``policy/dance/config/Dance.yaml``: ``motion_length: 18.0``).
MOTION_LENGTHS = {"g1/robomimic/charleston": 18.0}
#: config.yaml's key for the motion's length (RoboMimic_Deploy's ``Dance.yaml`` name; rl_sar
#: itself reads none).
LENGTH_KEY = "motion_length"
#: The waist slots rl_sar's anchor term reads (yaw, roll, pitch), from ``waist_joint_indices``.
WAIST_KEY = "waist_joint_indices"


def _sole(path: Path):
    """The one value of the one-key mapping in ``path``, and its key; (None, None) otherwise."""
    import yaml

    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError):
        return None, None
    if isinstance(doc, dict) and len(doc) == 1:
        key, value = next(iter(doc.items()))
        if isinstance(value, dict):
            return value, key
    return None, None


def _base(folder: Path, key) -> Path:
    """``policy/<robot>/base.yaml`` for the config key ``<robot>/<stack>`` (``../base.yaml``) or
    ``<robot>/<group>/<stack>`` (``../../base.yaml``: rl_sar's g1 ``robomimic/locomotion``,
    ``whole_body_tracking/dance_102``), as rl_sar reads the robot's base.yaml by the key's first
    part: the first folder up (as many as the key has parts) whose ``base.yaml`` has the one key
    ``<robot>``; else the one the key's depth names (refused when read)."""
    parts = str(key).split("/")
    depth = max(1, len(parts) - 1)
    for up in range(1, depth + 1):
        candidate = folder.joinpath(*[".."] * up, "base.yaml")
        if candidate.is_file() and _sole(candidate)[1] == parts[0]:
            return candidate
    return folder.joinpath(*[".."] * depth, "base.yaml")


def detect(facts) -> bool:
    """A graph with an rl_sar ``config.yaml`` beside it and the robot's ``base.yaml`` above it
    (:func:`_base`)."""
    folder = facts.path.resolve().parent
    if not (folder / CONFIG).is_file():
        return False
    cfg, key = _sole(folder / CONFIG)
    if cfg is None or "observations" not in cfg or "action_scale" not in cfg:
        return False
    return _base(folder, key).is_file()


def read(facts) -> ForeignContract:
    """The contract of a policy in an rl_sar folder (module docstring).

    Raises:
        ForeignFormatError: a file that is not one mapping under one key, a key missing or of
            the wrong length or kind (naming the file and the key).
    """
    fail = facts.failure(NAME)
    folder = facts.path.resolve().parent
    cfg, key = _sole(folder / CONFIG)
    base_path = _base(folder, key)
    base, base_key = _sole(base_path)
    if base is None:
        raise fail(f"{base_path}: expected one mapping under the robot's name")
    keys = _Keys({**base, **cfg}, cfg, folder / CONFIG, base_path, fail)
    merged, get, joints = keys.merged, keys.get, keys.joints
    slots = tuple(int(s) for s in get("joint_mapping"))
    n = keys.n = len(slots)
    where = str(folder / CONFIG)
    if facts.act_dim is not None and facts.act_dim != n:
        raise fail(f"{where}: 'joint_mapping' has {n} joints, the graph {facts.act_dim} actions")

    wheels = tuple(int(i) for i in merged.get("wheel_indices") or ())
    if any(not 0 <= i < n for i in wheels):
        raise fail(f"{where}: 'wheel_indices' {list(wheels)}: expected joint indices in 0..{n - 1}")
    clip = keys.action_clip()
    clip_obs = float(get("clip_obs", (int, float)))
    terms = tuple(_term(name, merged, clip_obs, wheels, n) for name in get("observations"))
    terms = tuple(_waist(t, merged, slots, fail, where) for t in terms)
    history, order, layout, length = _history(merged.get("observations_history"), merged, fail)
    if layout == "per_term":
        terms = tuple(
            Term(**{**t.__dict__, "history": length}) for t in terms
        )  # every term reads the same frames
    dt = float(keys.positive("dt", (int, float), "a number of seconds"))
    period = dt * int(keys.positive("decimation", (int,), "a whole number of physics steps"))
    terms = tuple(_phase(t, cfg, key, period, fail, where) for t in terms)
    names = keys.slot_names(slots)
    policy_names = None if names is None else [names[s] for s in slots]
    notes = _notes(slots, policy_names, merged, key, facts.path.name, wheels)
    motion = _motion(merged, folder, names, period, fail, where)
    if motion is not None:
        notes.append(motion.note)

    found = [
        ("config.yaml", where),
        ("base.yaml", f"{base_path} ({base_key})"),
        ("joint_mapping", str(list(slots))),
        ("joint_names[joint_mapping]", str(policy_names)),
        ("observations", ", ".join(t.name for t in terms)),
        ("observations_history", str(history)),
        ("action_scale", str(merged.get("action_scale"))),
        ("control period", f"dt x decimation = {period} s"),
    ]
    if motion is not None:
        found.append(("motion_file", f"{motion.file} at {motion.fps:g} Hz"))
    return facts.contract(
        NAME,
        where,
        joint_names=None,
        joint_order_rule="motor_slots",
        joint_order_note=ORDER_NOTE,
        joint_slots=slots,
        slot_names=names,
        terms=terms,
        default_pose=joints("default_dof_pos"),
        action_scale=joints("action_scale"),
        action_clip=clip,
        kp=joints("rl_kp"),
        kd=joints("rl_kd"),
        control_rate=1.0 / period,
        found=found,
        notes=notes,
        history_fill="zeros",
        history_order=order,
        history_layout=layout,
        history_length=length if layout == "per_frame" else 0,
        velocity_joints=wheels,
        motion=motion,
    )


def _notes(slots, policy_names, merged: dict, key: str, file: str, wheels) -> list[str]:
    """What the contract's joint order, joints, model, torque limits and wheels mean here."""
    notes = [
        f"joint order: {ORDER_NOTE} {list(slots)}",
        f"policy joints by rl_sar's joint_names: {policy_names}"
        if policy_names is not None
        else "no joint_names: the robot's motor slots give the joints",
        f"model_name '{merged.get('model_name')}' of {key}; read here: {file}",
        f"torque_limits {merged.get('torque_limits')}: the robot's effort limits apply",
    ]
    if wheels:
        notes.append(f"wheel_indices {list(wheels)}: speed targets, their dof_pos entries 0")
    return notes


class _Keys:
    """The keys of an rl_sar folder: its config.yaml over its base.yaml (``merged``), each read
    checked, a failure naming the file that holds the key; ``n`` the policy's joints."""

    def __init__(self, merged: dict, cfg: dict, config: Path, base_path: Path, fail):
        self.merged, self.cfg, self.config, self.base_path = merged, cfg, config, base_path
        self.fail, self.n = fail, 0

    def _file(self, name: str) -> Path:
        return self.config if name in self.cfg else self.base_path

    def get(self, name: str, kind=(list,)):
        value = self.merged.get(name)
        if not isinstance(value, kind) or isinstance(value, bool):
            raise self.fail(
                f"{self._file(name)}: '{name}': expected a {kind[0].__name__}, got {value!r}"
            )
        return value

    def positive(self, name: str, kind, expected: str) -> float:
        """A number above 0 (``dt``, s; ``decimation``, ticks): the control period is their
        product and the rate its inverse, so 0 or below is refused naming the file and key."""
        value = self.get(name, kind)
        if not value > 0:
            raise self.fail(f"{self._file(name)}: '{name}': expected {expected} > 0, got {value!r}")
        return value

    def joints(self, name: str) -> tuple[float, ...]:
        value = self.get(name)
        if len(value) != self.n:
            raise self.fail(
                f"{self.config}: '{name}': expected {self.n} numbers (one per joint), got {value!r}"
            )
        return tuple(float(v) for v in value)

    def action_clip(self) -> float | None:
        """The one symmetric clip of every action (None: no clip keys)."""
        lower, upper = self.merged.get("clip_actions_lower"), self.merged.get("clip_actions_upper")
        if lower is None and upper is None:
            return None
        low, high = self.joints("clip_actions_lower"), self.joints("clip_actions_upper")
        if len(set(high)) != 1 or any(lo != -high[0] for lo in low):
            raise self.fail(
                f"{self.config}: 'clip_actions_lower'/'clip_actions_upper': only one symmetric "
                f"clip of every action maps, got {list(low)} / {list(high)}"
            )
        return high[0]

    def slot_names(self, slots: tuple[int, ...]) -> tuple[str, ...] | None:
        """rl_sar's ``joint_names`` (None: none given), a name for every slot read."""
        if self.merged.get("joint_names") is None:
            return None
        names = tuple(str(x) for x in self.get("joint_names"))
        past = [s for s in slots if not 0 <= s < len(names)]
        if past:
            raise self.fail(
                f"{self._file('joint_names')}: 'joint_names' has {len(names)} names, "
                f"'joint_mapping' reads slots {past}: expected a name for every slot"
            )
        return names


def _term(name: str, cfg: dict, clip_obs: float, wheels: tuple[int, ...], n: int) -> Term:
    """One observation (module docstring): its kind, multiplier and clip (after scaling); ``n``
    the policy's joints."""
    if name not in TERMS:
        reason = (
            "the angular velocity in the world frame (rl_sar's ROS 1 Gazebo)"
            if name == "ang_vel_world"
            else "not an observation this toolkit maps"
        )
        return Term(name, None, 0, reason=reason)
    kind, size, scale_key = TERMS[name]
    size = 2 * n if size == -2 else size  # the clip's angles and velocities
    raw = 1.0 if scale_key is None else cfg.get(scale_key, 1.0)
    scale = tuple(float(x) for x in raw) if isinstance(raw, list) else float(raw)
    if isinstance(scale, tuple) and len(set(scale)) == 1:
        scale = scale[0]
    return Term(
        name, kind, size, scale, clip_obs, relative=True,
        zero_joints=wheels if kind == "joint_position" else (),
    )  # fmt: skip


def _waist(term: Term, cfg: dict, slots: tuple[int, ...], fail, where: str) -> Term:
    """The anchor term with its joints: the policy joints of the ``waist_joint_indices`` slots
    (yaw, roll, pitch; rl_sar's ``InverseJointMapping``); other terms as they are."""
    if term.kind != "motion_anchor_ori_b":
        return term
    waist = cfg.get(WAIST_KEY)
    if not (isinstance(waist, list) and len(waist) == 3 and all(s in slots for s in waist)):
        raise fail(
            f"{where}: '{WAIST_KEY}': expected the 3 motor slots of the waist's yaw, roll and "
            f"pitch joints (of {list(slots)}), got {waist!r}"
        )
    return Term(**{**term.__dict__, "joints": tuple(slots.index(int(s)) for s in waist)})


def _phase(term: Term, cfg: dict, key, period: float, fail, where: str) -> Term:
    """The ``RoboMimic_Deploy/phase`` term with its motion's length and first-tick offset (module
    docstring); other terms as they are. Without a known length the term cannot be mapped (its
    reason says where to give one); a ``motion_length`` that is not a positive number is
    refused naming the file and key."""
    if term.kind != "motion_phase":
        return term
    if LENGTH_KEY in cfg:
        length, source = cfg[LENGTH_KEY], f"{where} '{LENGTH_KEY}'"
        if not positive_number(length, (int, float)):
            raise fail(
                f"{where}: '{LENGTH_KEY}': expected the motion's length, s > 0, got {length!r}"
            )
    elif str(key) in MOTION_LENGTHS:
        length = MOTION_LENGTHS[str(key)]
        source = f"rl_sar's fsm for {key} (rl.motion_length)"
    else:
        return Term(
            term.name, None, 1,
            reason=(
                f"the motion's length T: rl_sar sets it in its fsm (rl.motion_length), not in "
                f"config.yaml; give '{LENGTH_KEY}: T' (s) in {where}"
            ),
        )  # fmt: skip
    length = float(length)
    return Term(
        **{
            **term.__dict__,
            "period": length,
            "offset": -period / length,
            "source": f"t / T, T = {length:g} s from {source}; first tick t = {period:g} s",
        }
    )


def _motion(cfg: dict, folder: Path, names, period: float, fail, where: str):
    """The clip ``motion_file`` names (module docstring), or None without one."""
    name = cfg.get("motion_file")
    if name is None:
        return None
    if not isinstance(name, str) or not name:
        raise fail(f"{where}: 'motion_file': expected a file name beside config.yaml, got {name!r}")
    if names is None:
        raise fail(
            f"{where}: 'motion_file' {name}: its columns are the motor slots' joints, and no "
            "'joint_names' names them"
        )
    fps = 1.0 / period
    note = (
        f"motion_file {name}: played at 1 / (dt x decimation) = {fps:g} Hz as rl_sar's fsm "
        "plays it (a rate in its name is not what rl_sar reads); its joint columns in the "
        "motor slots' order of joint_names"
    )
    return MotionSource(str(folder / name), fps, tuple(names), "rl_sar", note)


def _history(value, cfg: dict, fail) -> tuple[list, str, str, int]:
    """``(as read, order, layout, length)`` of ``observations_history`` (0 the newest frame):
    empty, ``[0, 1, ..]`` (newest first) or ``[.., 1, 0]`` (oldest first)."""
    frames = list(value or [])
    if not frames:
        return frames, "oldest_first", "per_frame", 0
    length = max(frames) + 1
    if frames == list(range(length)):
        order = "newest_first"
    elif frames == list(range(length))[::-1]:
        order = "oldest_first"
    else:
        raise fail(
            f"'observations_history' {frames}: only every frame from the newest (0) up, in "
            "either order, maps"
        )
    priority = cfg.get("observations_history_priority", "time")
    if priority not in ("time", "term"):
        raise fail(f"'observations_history_priority' {priority!r}: expected 'time' or 'term'")
    return frames, order, "per_frame" if priority == "time" else "per_term", length
