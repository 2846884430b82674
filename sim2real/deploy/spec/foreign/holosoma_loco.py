"""holosoma_inference's G1 locomotion policies (``models/loco/g1_29dof/ppo_g1_29dof.onnx``,
``fastsac_g1_29dof.onnx`` of amazon-far/holosoma): the contract holosoma_inference runs them by.

The shipped files carry ``dof_names``, ``kp``, ``kd`` and ``command_ranges`` but no
``experiment_config``; holosoma_inference runs them with its own configuration (amazon-far/holosoma
fc600e7, ``holosoma_inference/config/config_values``), read here as it does:

- task ``locomotion``: ``rl_rate = 50`` Hz, ``policy_action_scale = 0.25`` (an ``action_scale`` in
  the metadata, newer exports, wins), ``gait_period = 1.0`` s; target ``= clip(action, -100, 100)
  * scale + default`` (``policies/base.py``);
- observation ``loco-g1-29dof``: group ``actor_obs`` = ``base_ang_vel`` 3 (scale 0.25),
  ``projected_gravity`` 3, ``command_lin_vel`` 2, ``command_ang_vel`` 1, ``dof_pos`` 29 (minus
  the default pose), ``dof_vel`` 29 (scale 0.05), ``actions`` 29, ``sin_phase`` 2, ``cos_phase``
  2 (the left foot's phase, then the right's, half a period later), history 1, unclipped,
  concatenated **in alphabetical order** (``BasePolicy.obs_terms_sorted``): 100 entries;
- the gait clock (``LocomotionPolicy.update_phase_time``): advanced before each observation,
  both feet held at pi while ``|(vx, vy)|`` and ``|yaw rate|`` are below 0.01, restarted at
  (0, pi) on the first tick above (:data:`TERMS`, :data:`PHASE_TERMS`, :data:`STAND_BELOW`, which
  :mod:`sim2real.deploy.spec.foreign.holosoma` maps training's terms with too);
- robot ``g1_29dof``: the default pose :data:`~sim2real.deploy.spec.foreign.holosoma_wbt.G1_DEFAULT`
  by its ``dof_names`` (the training configuration's ``init_state.default_joint_angles`` too).

A file is read so only when its ``dof_names`` are the G1 29-DoF's and its input is this
observation's 100 entries; any other file without ``experiment_config`` stays partial.
"""

from __future__ import annotations

import math

from sim2real.deploy.spec.foreign.contract import ForeignContract, Term, command_ranges
from sim2real.deploy.spec.foreign.holosoma_wbt import G1_DEFAULT, g1_contract, metadata_drive

#: holosoma's locomotion terms (``holosoma.managers.observation.terms.locomotion``) -> (our kind,
#: size (-1: one per joint), components of the 3-vector).
TERMS = {
    "base_lin_vel": ("base_linear_velocity", 3, ()),
    "base_ang_vel": ("base_angular_velocity", 3, ()),
    "projected_gravity": ("projected_gravity", 3, ()),
    "command_lin_vel": ("velocity_command", 2, (0, 1)),
    "command_ang_vel": ("velocity_command", 1, (2,)),
    "dof_pos": ("joint_position", -1, ()),
    "dof_vel": ("joint_velocity", -1, ()),
    "actions": ("last_action", -1, ()),
}
#: holosoma's gait clock terms -> the ``gait_phase`` components they read: the left foot's
#: phase p, then the right foot's, p + pi (holosoma_inference ``BasePolicy._init_phase_components``
#: starts them at 0 and pi; training's ``LocomotionGait`` offsets them by pi).
PHASE_TERMS = {"sin_phase": (0, 2), "cos_phase": (1, 3)}
#: The command below which holosoma's clock stands, m/s and rad/s: ``|(vx, vy)| < 0.01`` and
#: ``|yaw rate| < 0.01`` (``LocomotionGait.step`` in training, ``LocomotionPolicy.
#: update_phase_time`` in holosoma_inference; a constant there, not in the configuration).
STAND_BELOW = 0.01
#: task ``locomotion``: ``rl_rate`` (Hz), ``policy_action_scale``, ``gait_period`` (s).
RL_RATE = 50.0
ACTION_SCALE = 0.25
GAIT_PERIOD = 1.0
#: ``LocomotionPolicy.update_phase_time``: both feet's phase while standing, rad.
STAND_PHASE = math.pi
#: ``policies/base.py``: ``np.clip(policy_action, -100, 100)``.
ACTION_CLIP = 100.0
#: observation ``loco-g1-29dof`` ``actor_obs`` -> (scale, size; -1: one per joint); sorted below.
LOCO_TERMS = {
    "base_ang_vel": (0.25, 3),
    "projected_gravity": (1.0, 3),
    "command_lin_vel": (1.0, 2),
    "command_ang_vel": (1.0, 1),
    "dof_pos": (1.0, -1),
    "dof_vel": (0.05, -1),
    "actions": (1.0, -1),
    "sin_phase": (1.0, 2),
    "cos_phase": (1.0, 2),
}


def obs_size(n: int) -> int:
    """Entries of the ``loco-g1-29dof`` observation for ``n`` joints."""
    return sum(n if size == -1 else size for _, size in LOCO_TERMS.values())


def is_g1_loco(facts, names: tuple[str, ...]) -> bool:
    """holosoma_inference's G1 locomotion file: the G1 29-DoF's ``dof_names`` and an input of
    the ``loco-g1-29dof`` observation's size."""
    g1 = set(names) == set(G1_DEFAULT) and len(names) == len(G1_DEFAULT)
    return g1 and facts.obs_dim == obs_size(len(names))


def read_g1_loco(facts, md: dict, names: tuple[str, ...], fail) -> ForeignContract:
    """The contract of holosoma_inference's G1 locomotion file (module docstring).

    Args:
        facts: The file's facts. md: Its metadata, each value JSON-decoded.
        names: ``dof_names`` (the G1 29-DoF's: :func:`is_g1_loco`). fail: ``fail(message)`` ->
            ForeignFormatError.

    Raises:
        ForeignFormatError: ``kp``, ``kd`` or a per-joint ``action_scale`` not one number per dof.
    """
    n = len(names)
    drive = metadata_drive(md, n, fail, ACTION_SCALE, "locomotion")
    terms = []
    for name in sorted(LOCO_TERMS):  # holosoma_inference concatenates the sorted terms
        factor, size = LOCO_TERMS[name]
        source = f"holosoma_inference observation loco-g1-29dof: {name}"
        if name in PHASE_TERMS:
            terms.append(
                Term(
                    name, "gait_phase", size, factor, None, PHASE_TERMS[name], source=source,
                    period=GAIT_PERIOD, stand_below=STAND_BELOW, stand_phase=STAND_PHASE,
                )
            )  # fmt: skip
        else:
            kind, _, components = TERMS[name]
            terms.append(Term(name, kind, size, factor, None, components, source=source))
    return g1_contract(
        facts,
        md,
        names,
        drive,
        "ONNX metadata (holosoma export) with holosoma_inference's locomotion configs",
        found=[("command_ranges", str(md.get("command_ranges")))],
        notes=[
            "observation: holosoma_inference observation loco-g1-29dof, terms sorted: "
            + ", ".join(sorted(LOCO_TERMS)),
            f"gait clock: period {GAIT_PERIOD:g} s (task locomotion), both feet at pi below "
            f"{STAND_BELOW:g} m/s and rad/s (LocomotionPolicy.update_phase_time)",
            "default pose: holosoma_inference robot g1_29dof",
        ],
        terms=terms,
        action_clip=ACTION_CLIP,
        control_rate=RL_RATE,
        command_ranges=command_ranges(md.get("command_ranges")),
    )
