"""holosoma's whole-body tracking (WBT) export: the contract of ``models/wbt/*.onnx``.

holosoma's WBT exporter writes a graph with inputs ``obs`` (1, 154) and ``time_step`` (1, 1) and
outputs ``actions`` (1, 29), then the training clip baked in (``joint_pos``, ``joint_vel``,
``ref_pos_xyz``, ``ref_quat_xyzw``, each a ``Gather`` at ``time_step``); its metadata
(``json.dumps``'d) carries ``dof_names``, ``kp``, ``kd``, ``command_ranges`` and the URDF, but no
action scale, default pose, observation names, rate or reference body. Those are
holosoma_inference's (amazon-far/holosoma fc600e7, ``holosoma_inference/config/config_values``),
read here as it runs this file:

- task ``wbt``: ``rl_rate = 50`` Hz, ``policy_action_scale = 1.0`` (an ``action_scale`` in the
  metadata, newer exports, wins); target ``= clip(action, -100, 100) * scale + default``
  (``policies/base.py``, ``policies/wbt.py``);
- observation ``wbt``: group ``actor_obs`` = ``motion_command`` 58, ``motion_ref_ori_b`` 6,
  ``base_ang_vel`` 3, ``dof_pos`` 29 (minus the default pose), ``dof_vel`` 29, ``actions`` 29, all
  scales 1, history 1, concatenated **in alphabetical order** (``BasePolicy.obs_terms_sorted``):
  actions, base_ang_vel, dof_pos, dof_vel, motion_command, motion_ref_ori_b;
- robot ``g1_29dof``: :data:`G1_DEFAULT` by its ``dof_names``; ``motion.body_name_ref =
  torso_link``: ``motion_ref_ori_b`` is the torso's orientation error, our
  ``motion_anchor_ori_b`` (the torso from the base and the waist's yaw, roll, pitch);
- ``time_step`` feeds only the clip's outputs (the actions read ``obs`` alone; checked on the
  graph by :mod:`sim2real.deploy.tasks.motion.onnx_holosoma`): fed 0 here, the clip is read
  from the graph's tables by the motion task.

Only the G1 29-DoF configuration is known: a file whose ``dof_names`` are not its joints, or that
observes a term this mapping lacks, is refused by name.
"""

from __future__ import annotations

from sim2real.deploy.spec.foreign.contract import ForeignContract, MotionSource, Term

#: holosoma_inference ``config_values/robot.py`` ``g1_29dof.default_dof_angles``, rad, by joint.
G1_DEFAULT = {
    "left_hip_pitch_joint": -0.312, "left_hip_roll_joint": 0.0, "left_hip_yaw_joint": 0.0,
    "left_knee_joint": 0.669, "left_ankle_pitch_joint": -0.363, "left_ankle_roll_joint": 0.0,
    "right_hip_pitch_joint": -0.312, "right_hip_roll_joint": 0.0, "right_hip_yaw_joint": 0.0,
    "right_knee_joint": 0.669, "right_ankle_pitch_joint": -0.363, "right_ankle_roll_joint": 0.0,
    "waist_yaw_joint": 0.0, "waist_roll_joint": 0.0, "waist_pitch_joint": 0.0,
    "left_shoulder_pitch_joint": 0.2, "left_shoulder_roll_joint": 0.2,
    "left_shoulder_yaw_joint": 0.0, "left_elbow_joint": 0.6, "left_wrist_roll_joint": 0.0,
    "left_wrist_pitch_joint": 0.0, "left_wrist_yaw_joint": 0.0,
    "right_shoulder_pitch_joint": 0.2, "right_shoulder_roll_joint": -0.2,
    "right_shoulder_yaw_joint": 0.0, "right_elbow_joint": 0.6, "right_wrist_roll_joint": 0.0,
    "right_wrist_pitch_joint": 0.0, "right_wrist_yaw_joint": 0.0,
}  # fmt: skip
#: task ``wbt``: ``rl_rate`` (Hz) and ``policy_action_scale``.
RL_RATE = 50.0
ACTION_SCALE = 1.0
#: ``policies/wbt.py``: ``np.clip(policy_action, -100, 100)``.
ACTION_CLIP = 100.0
#: observation ``wbt`` ``actor_obs`` terms -> (our kind, size (-1: one per joint)); sorted below.
WBT_TERMS = {
    "motion_command": ("motion_command", -2),
    "motion_ref_ori_b": ("motion_anchor_ori_b", 6),
    "base_ang_vel": ("base_angular_velocity", 3),
    "dof_pos": ("joint_position", -1),
    "dof_vel": ("joint_velocity", -1),
    "actions": ("last_action", -1),
}
#: ``robot.motion.body_name_ref``'s joints: the torso of the G1 rides the waist (yaw, roll, pitch).
WAIST = ("waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint")
#: The clip's outputs the exporter adds to the graph.
CLIP_OUTPUTS = ("joint_pos", "joint_vel", "ref_quat_xyzw")


def _per_dof(md: dict, key: str, n: int, fail) -> tuple[float, ...] | None:
    """Metadata ``key`` as ``n`` numbers (None: absent or null); a ForeignFormatError otherwise."""
    value = md.get(key)
    if value is None:
        return None
    ok = isinstance(value, list) and len(value) == n
    if not (ok and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)):
        raise fail(f"metadata '{key}' is {str(value)[:60]}; expected {n} numbers (one per dof)")
    return tuple(float(v) for v in value)


def metadata_drive(md: dict, n: int, fail, default_scale: float, task: str):
    """``(kp, kd, action scale, its note)`` from holosoma's ONNX metadata: ``kp`` and ``kd`` one
    number per dof (None: absent); ``action_scale`` a number, one per dof, or absent (then
    ``default_scale``, holosoma_inference task ``task``'s ``policy_action_scale``).

    Raises:
        ForeignFormatError (``fail``): ``kp``, ``kd`` or a per-dof ``action_scale`` not ``n``
            numbers.
    """
    kp, kd = _per_dof(md, "kp", n, fail), _per_dof(md, "kd", n, fail)
    raw = md.get("action_scale")
    if raw is None:
        return (
            kp,
            kd,
            default_scale,
            f"action scale {default_scale:g}: holosoma_inference task {task}",
        )
    if isinstance(raw, int | float) and not isinstance(raw, bool):
        return kp, kd, float(raw), "action scale: metadata 'action_scale'"
    return kp, kd, _per_dof(md, "action_scale", n, fail), "metadata 'action_scale'"


def g1_contract(
    facts, md: dict, names, drive, description: str, found: list, notes: list, **more
) -> ForeignContract:
    """What both holosoma_inference G1 readers (WBT, locomotion) build: joints ``names`` at
    :data:`G1_DEFAULT`, the drive ``drive`` of :func:`metadata_drive`, a zero-filled history,
    ``found`` after the ``dof_names``, ``kp`` and ``kd`` entries, ``notes`` after the scale's;
    ``more``: the rest of the contract (its terms, ``action_clip``, ``control_rate``, ...)."""
    kp, kd, scale, scale_note = drive
    return facts.contract(
        "holosoma",
        description,
        joint_names=names,
        default_pose=tuple(G1_DEFAULT[j] for j in names),
        action_scale=scale,
        kp=kp,
        kd=kd,
        history_fill="zeros",
        found=[
            ("dof_names", f"{len(names)} joints"),
            ("kp", str(md.get("kp"))),
            ("kd", str(md.get("kd"))),
            *found,
        ],
        notes=[scale_note, *notes],
        **more,
    )


def is_wbt(facts) -> bool:
    """A holosoma WBT export: a ``time_step`` input and the baked clip's outputs."""
    return "time_step" in facts.inputs and all(o in facts.outputs for o in CLIP_OUTPUTS)


def read_wbt(facts, md: dict, names: tuple[str, ...], fail) -> ForeignContract:
    """The contract of a holosoma WBT export (module docstring).

    Args:
        facts: The file's facts. md: Its metadata, each value JSON-decoded.
        names: ``dof_names``. fail: ``fail(message)`` -> ForeignFormatError.

    Raises:
        ForeignFormatError: ``dof_names`` that are not the G1 29-DoF's joints (the only
            configuration holosoma_inference ships for WBT), ``kp``/``kd``/``action_scale`` not one
            number per dof.
    """
    if set(names) != set(G1_DEFAULT) or len(names) != len(G1_DEFAULT):
        raise fail(
            f"metadata 'dof_names' ({len(names)} joints) are not the G1 29-DoF's joints of "
            "holosoma_inference's robot config g1_29dof, the only WBT configuration it ships "
            "(its default pose and reference body are not in the file)"
        )
    n = len(names)
    drive = metadata_drive(md, n, fail, ACTION_SCALE, "wbt (not in the file)")
    waist = tuple(names.index(j) for j in WAIST)
    terms = []
    for name in sorted(WBT_TERMS):  # holosoma_inference concatenates the sorted terms
        kind, size = WBT_TERMS[name]
        size = 2 * n if size == -2 else size
        terms.append(
            Term(
                name, kind, size, 1.0, None, relative=True,
                joints=waist if kind == "motion_anchor_ori_b" else (),
                source=f"holosoma_inference observation wbt: {name}",
            )
        )  # fmt: skip
    motion = MotionSource(
        file=str(facts.path),
        fps=RL_RATE,
        columns=names,
        timing="holosoma_onnx",
        note=(
            f"the clip baked in the graph ({', '.join(CLIP_OUTPUTS)} at time_step), one frame a "
            f"policy tick ({RL_RATE:g} Hz), the observation reading the frame of the tick before "
            "(holosoma_inference WholeBodyTrackingPolicy.rl_inference)"
        ),
    )
    return g1_contract(
        facts,
        md,
        names,
        drive,
        "ONNX metadata and graph (holosoma WBT export) with holosoma_inference's wbt configs",
        found=[("graph", "inputs obs, time_step; outputs actions, " + ", ".join(CLIP_OUTPUTS))],
        notes=[
            "observation: holosoma_inference observation wbt, terms sorted: "
            + ", ".join(sorted(WBT_TERMS)),
            "default pose: holosoma_inference robot g1_29dof; reference body torso_link",
            motion.note,
        ],
        terms=terms,
        action_clip=ACTION_CLIP,
        control_rate=RL_RATE,
        motion=motion,
        constant_inputs={"time_step": 0.0},
    )
