"""Policy files written the way mjlab, holosoma, Isaac Lab and rsl_rl write theirs (our own
generators, built from reading their exporters; none of their code is used or copied).

- mjlab (mujocolab/mjlab ``src/mjlab/rl/exporter_utils.py``): Isaac Lab's ONNX exporter (``obs``
  -> ``actions``, opset 11, no dynamic axes), then ``metadata_props`` appended, a list as
  comma-separated values, numbers at three decimals, a nested list's entries joined with ``;``,
  anything else ``str()``.
- holosoma (amazon-far/holosoma ``src/holosoma/holosoma/utils/inference_helpers.py``):
  ``actor_obs`` -> ``action``, opset 13, the TorchScript-based exporter; every metadata value
  ``json.dumps``'d: ``dof_names``, ``kp``, ``kd``, ``command_ranges``, ``robot_urdf``,
  ``robot_urdf_path``, ``experiment_config`` (``ExperimentConfig.to_serializable_dict``),
  ``iteration``.
- Isaac Lab (isaac-sim/IsaacLab ``isaaclab_rl/rsl_rl/exporter.py``, ``isaaclab/utils/io/yaml.py``,
  ``scripts/reinforcement_learning/rsl_rl/{train,play}.py``): ``<run>/exported/policy.onnx``
  (``obs`` -> ``actions``, opset 11, batch 1) and ``<run>/params/env.yaml``, ``agent.yaml``
  written by ``yaml.dump`` (not the safe dumper: tuples carry ``!!python/tuple``) of
  ``class_to_dict`` (functions and classes as ``"module:name"``).
- rsl_rl (leggedrobotics/rsl_rl ``OnPolicyRunner.export_policy_to_onnx``, ``as_onnx``): ``obs``
  -> ``actions``, opset 18, no metadata.

The go2 quantities come from the stacks' own Go1/Go2 configurations where they have one (mjlab's
``go1_constants.py`` gains and pose, Isaac Lab's ``UNITREE_GO2_CFG``), the joint names from
``sim2real/robots/go2``.
"""

from __future__ import annotations

import io
import json
import math
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
import yaml
from torch import nn

#: sim2real/robots/go2's joints (its order: FL, FR, RL, RR legs).
GO2 = tuple(
    f"{leg}_{part}_joint" for leg in ("FL", "FR", "RL", "RR") for part in ("hip", "thigh", "calf")
)
#: mjlab's Go1 order (its go1.xml: FR, FL, RR, RL legs): a permutation of go2's.
MJLAB_ORDER = tuple(
    f"{leg}_{part}_joint" for leg in ("FR", "FL", "RR", "RL") for part in ("hip", "thigh", "calf")
)
#: A holosoma-style dof order with the legs reversed (RR, RL, FR, FL): another permutation.
HOLOSOMA_ORDER = tuple(
    f"{leg}_{part}_joint" for leg in ("RR", "RL", "FR", "FL") for part in ("hip", "thigh", "calf")
)


class Actor(nn.Module):
    """An rsl_rl-style actor (Linear-ELU-Linear): output = tanh-free MLP, last layer scaled by
    ``gain`` (small: the robot stands at the default pose) plus ``bias``."""

    def __init__(self, obs_dim: int, act_dim: int, seed: int, gain: float, bias=None):
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.actor = nn.Sequential(nn.Linear(obs_dim, 16), nn.ELU(), nn.Linear(16, act_dim))
        with torch.no_grad():
            for p in self.actor.parameters():
                p.copy_(0.3 * torch.randn(p.shape, generator=g))
            self.actor[2].weight.mul_(gain)
            self.actor[2].bias.copy_(
                torch.zeros(act_dim) if bias is None else torch.as_tensor(bias, dtype=torch.float32)
            )
        self.normalizer = nn.Identity()  # Isaac Lab's exporter: Identity without a normalizer

    def forward(self, x):
        return self.actor(self.normalizer(x))


def _export(module: nn.Module, obs_dim: int, path: Path, opset: int, ins, outs) -> Path:
    """``torch.onnx.export`` as the stacks call it: batch 1, no dynamic axes, TorchScript-based."""
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module.eval(),
            (torch.zeros(1, obs_dim),),
            buf,
            export_params=True,
            opset_version=opset,
            input_names=ins,
            output_names=outs,
            dynamic_axes={},
            dynamo=False,
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(buf.getvalue())
    return path


def _append_metadata(path: Path, entries: dict[str, str]) -> None:
    model = onnx.load(str(path))
    for k, v in entries.items():
        entry = onnx.StringStringEntryProto()
        entry.key, entry.value = k, v
        model.metadata_props.append(entry)
    onnx.save(model, str(path))


# ------------------------------------------------------------------------------------ mjlab
def mjlab_csv(values) -> str:
    """mjlab's ``list_to_csv_str``: numbers at three decimals, strings as they are, a nested
    list's entries joined with ``;``."""

    def scalar(x):
        return f"{x:.3f}" if isinstance(x, int | float) else str(x)

    return ",".join(
        ";".join(map(scalar, x)) if isinstance(x, list | tuple) else scalar(x) for x in values
    )


#: mjlab's Go1 actuator constants (go1_constants.py): rotor inertia 0.000111842 kg m^2, gears 6
#: (hip, thigh) and 9 (calf), a 10 Hz natural frequency at damping ratio 2.
_ROTOR, _W = 0.000111842, 10 * 2.0 * 3.1415926535
MJLAB_KP = {"hip": _ROTOR * 36 * _W**2, "thigh": _ROTOR * 36 * _W**2, "calf": _ROTOR * 81 * _W**2}
MJLAB_KD = {
    "hip": 2 * 2.0 * _ROTOR * 36 * _W,
    "thigh": 2 * 2.0 * _ROTOR * 36 * _W,
    "calf": 2 * 2.0 * _ROTOR * 81 * _W,
}
#: mjlab's Go1 INIT_STATE joint_pos.
MJLAB_POSE = {"thigh": 0.9, "calf": -1.8, "R_hip": 0.1, "L_hip": -0.1}
#: mjlab's velocity-task actor terms with base_lin_vel (as Go1's and G1's keep it).
MJLAB_TERMS = (
    "base_lin_vel",
    "base_ang_vel",
    "projected_gravity",
    "joint_pos",
    "joint_vel",
    "actions",
    "command",
)


def _part(name: str) -> str:
    return name.split("_")[1]


def mjlab_pose(name: str) -> float:
    if _part(name) == "hip":
        return MJLAB_POSE["R_hip" if name[1] == "R" else "L_hip"]
    return MJLAB_POSE[_part(name)]


def mjlab_metadata(order=MJLAB_ORDER, terms=MJLAB_TERMS, scales=None, newer=True) -> dict:
    """``get_base_metadata``'s dict for a Go1-style robot with go2's joint names (before
    ``attach_metadata_to_onnx`` formats it). ``scales``: per-term multipliers (newer mjlab)."""
    effort = {"hip": 23.7, "thigh": 23.7, "calf": 35.55}
    md = {
        "run_path": "local",
        "joint_names": list(order),
        "joint_stiffness": [MJLAB_KP[_part(n)] for n in order],
        "joint_damping": [MJLAB_KD[_part(n)] for n in order],
        "default_joint_pos": [mjlab_pose(n) for n in order],
        "command_names": ["twist"],
        "observation_names": list(terms),
        # Go1's GO1_ACTION_SCALE: 0.25 * effort_limit / stiffness per joint
        "action_scale": [0.25 * effort[_part(n)] / MJLAB_KP[_part(n)] for n in order],
    }
    if newer:
        scales = scales or {}
        md["observation_terms_scale"] = [scales.get(t, 1.0) for t in terms]
        md["observation_terms_flatten_history_dim"] = [True for _ in terms]
        md["observation_terms_history_length"] = [0 for _ in terms]
        md["observation_terms_clip"] = [[-math.inf, math.inf] for _ in terms]
    return md


def write_mjlab(path: Path, metadata: dict, obs_dim: int, gain=1e-3, bias=None, seed=0) -> Path:
    """An mjlab velocity export: Isaac Lab's exporter, then ``attach_metadata_to_onnx``."""
    actor = Actor(obs_dim, len(metadata["joint_names"]), seed, gain, bias)
    _export(actor, obs_dim, path, 11, ["obs"], ["actions"])
    _append_metadata(
        path, {k: mjlab_csv(v) if isinstance(v, list) else str(v) for k, v in metadata.items()}
    )
    return path


# ------------------------------------------------------------------------------------ holosoma
def _obs_term(func: str, scale=1.0, noise=0.0, clip=None) -> dict:
    module = "holosoma.managers.observation.terms.locomotion"
    return {"func": f"{module}:{func}", "params": {}, "scale": scale, "noise": noise, "clip": clip}


#: holosoma locomotion terms (its G1 preset's, phase terms left out, base_lin_vel added as its
#: critic has it) with their scales.
HOLOSOMA_TERMS = {
    "base_ang_vel": _obs_term("base_ang_vel", 0.25),
    "base_lin_vel": _obs_term("base_lin_vel", 2.0),
    "projected_gravity": _obs_term("projected_gravity"),
    "command_lin_vel": _obs_term("command_lin_vel"),
    "command_ang_vel": _obs_term("command_ang_vel"),
    "dof_pos": _obs_term("dof_pos", noise=0.01),
    "dof_vel": _obs_term("dof_vel", 0.05, noise=0.1),
    "actions": _obs_term("actions"),
}


#: holosoma's G1 preset's gait clock terms (``config_values/loco/g1/observation.py``).
HOLOSOMA_PHASE_TERMS = {"sin_phase": _obs_term("sin_phase"), "cos_phase": _obs_term("cos_phase")}


def holosoma_gait(period: float = 1.0) -> dict:
    """The G1 preset's ``locomotion_gait`` command term (``config_values/loco/g1/command.py``:
    gait_period 1.0 s, its randomization width 0.2 Hz; ``stand_phase_value`` left at its
    default)."""
    return {
        "func": "holosoma.managers.command.terms.locomotion:LocomotionGait",
        "params": {"gait_period": period, "gait_period_randomization_width": 0.2},
    }


def holosoma_experiment(
    order, terms=HOLOSOMA_TERMS, pose=None, kp=20.0, kd=0.5, gait: dict | None = None
) -> dict:
    """The parts of ``ExperimentConfig.to_serializable_dict()`` the export reads, with the
    surrounding fields holosoma writes (abridged); ``gait``: a ``locomotion_gait`` command term
    (:func:`holosoma_gait`)."""
    pose = pose or dict(
        zip(GO2, (0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5), strict=True)
    )
    module_dict = {
        "actor": {"type": "MLP", "input_dim": ["actor_obs"], "output_dim": ["robot_action_dim"]},
        "critic": {"type": "MLP", "input_dim": ["critic_obs"], "output_dim": [1]},
    }
    setup_terms: dict = {"locomotion_gait": gait} if gait else {}
    setup_terms["locomotion_command"] = {
        "func": "holosoma.managers.command.terms.locomotion:LocomotionCommand",
        "params": {
            "command_ranges": {
                "lin_vel_x": [-1.0, 1.0],
                "lin_vel_y": [-1.0, 1.0],
                "ang_vel_yaw": [-1.0, 1.0],
            }
        },
    }
    return {
        "env_class": "holosoma.envs.locomotion.locomotion_manager.LeggedRobotLocomotionManager",
        "training": {"headless": True, "num_envs": 4096, "seed": 42, "export_onnx": True},
        "algo": {"_target_": "holosoma.agents.ppo.ppo.PPO", "config": {"module_dict": module_dict}},
        "simulator": {"config": {"sim": {"fps": 200, "control_decimation": 4, "substeps": 1}}},
        "observation": {
            "groups": {
                "actor_obs": {
                    "terms": dict(terms),
                    "concatenate": True,
                    "enable_noise": True,
                    "history_length": 1,
                },
                "critic_obs": {"terms": dict(terms), "concatenate": True, "history_length": 1},
            },
            "clip_observations": 100.0,
        },
        "action": {
            "terms": {
                "joint_control": {
                    "func": "holosoma.managers.action.terms.joint_control:JointPositionActionTerm",
                    "params": {},
                    "scale": 1.0,
                    "clip": None,
                }
            }
        },
        "robot": {
            "dof_names": list(order),
            "actions_dim": len(order),
            "dof_effort_limit_list": [23.7 if "calf" not in n else 45.43 for n in order],
            "init_state": {
                "pos": [0.0, 0.0, 0.35],
                "rot": [0.0, 0.0, 0.0, 1.0],
                "lin_vel": [0.0, 0.0, 0.0],
                "ang_vel": [0.0, 0.0, 0.0],
                "default_joint_angles": pose,
            },
            "control": {
                "control_type": "P",
                "stiffness": {"hip": kp, "thigh": kp, "calf": kp},
                "damping": {"hip": kd, "thigh": kd, "calf": kd},
                "action_scale": 0.25,
                "action_clip_value": 100.0,
                "clip_actions": True,
                "clip_torques": True,
                "action_scales_by_effort_limit_over_p_gain": False,
            },
        },
        "command": {"setup_terms": setup_terms},
    }


def write_holosoma(
    path: Path, experiment: dict, obs_dim: int, kp=20.0, kd=0.5, gain=1e-3, bias=None
) -> Path:
    """A holosoma PPO export: ``export_policy_as_onnx``, then ``attach_onnx_metadata`` of what
    ``PPO.export`` gathers (gains in ``dof_names`` order, as ``get_control_gains_from_config``
    matches them by substring)."""
    order = experiment["robot"]["dof_names"]
    actor = Actor(obs_dim, len(order), 1, gain, bias)
    _export(actor, obs_dim, path, 13, ["actor_obs"], ["action"])
    control = experiment["robot"]["control"]
    kp_list = [next(v for p, v in control["stiffness"].items() if p in n) for n in order]
    kd_list = [next(v for p, v in control["damping"].items() if p in n) for n in order]
    metadata = {
        "dof_names": order,
        "kp": kp_list,
        "kd": kd_list,
        "command_ranges": experiment["command"]["setup_terms"]["locomotion_command"]["params"][
            "command_ranges"
        ],
        "robot_urdf": "<robot name='go2'/>",
        "robot_urdf_path": "/holosoma/data/robots/go2/go2.urdf",
        "experiment_config": experiment,
        "iteration": 1000,
    }
    _append_metadata(path, {k: json.dumps(v) for k, v in metadata.items()})
    return path


def write_holosoma_inference(path: Path, order, kp, kd, obs_dim: int) -> Path:
    """A policy as holosoma_inference ships its G1 ones (``models/loco/g1_29dof/*.onnx``):
    ``actor_obs`` -> ``action``, opset 13, and only ``dof_names``, ``kp``, ``kd`` and
    ``command_ranges`` (with ``heading``) in the metadata, each ``json.dumps``'d; no
    ``experiment_config``."""
    _export(Actor(obs_dim, len(order), 2, 1e-3), obs_dim, path, 13, ["actor_obs"], ["action"])
    ranges = {"lin_vel_x": [-1.0, 1.0], "lin_vel_y": [-1.0, 1.0], "ang_vel_yaw": [-1.0, 1.0],
              "heading": [-3.14, 3.14]}  # fmt: skip
    metadata = {"dof_names": list(order), "kp": list(kp), "kd": list(kd), "command_ranges": ranges}
    _append_metadata(path, {k: json.dumps(v) for k, v in metadata.items()})
    return path


# ------------------------------------------------------------------------------------ Isaac Lab
def _isaac_obs(func: str, params=None, noise=None, scale=None, clip=None) -> dict:
    return {
        "func": f"isaaclab.envs.mdp.observations:{func}",
        "params": params or {},
        "modifiers": None,
        "noise": noise,
        "clip": clip,
        "scale": scale,
        "history_length": 0,
        "flatten_history_dim": True,
    }


def _noise(n: float) -> dict:
    return {
        "func": "isaaclab.utils.noise.noise_model:uniform_noise",
        "operation": "add",
        "n_min": -n,
        "n_max": n,
    }


def isaaclab_env(scale=0.25, stiffness=25.0, damping=0.5, terms=None) -> dict:
    """``class_to_dict`` of Isaac Lab's Go2 flat velocity environment (UnitreeGo2FlatEnvCfg;
    its robot UNITREE_GO2_CFG: DCMotor, stiffness 25, damping 0.5), abridged to the sections
    around what the export reads, tuples kept as tuples (``yaml.dump`` tags them)."""
    policy = {
        "concatenate_terms": True,
        "concatenate_dim": -1,
        "enable_corruption": True,
        "history_length": None,
        "flatten_history_dim": True,
    }
    policy.update(
        terms
        or {
            "base_lin_vel": _isaac_obs("base_lin_vel", noise=_noise(0.1)),
            "base_ang_vel": _isaac_obs("base_ang_vel", noise=_noise(0.2)),
            "projected_gravity": _isaac_obs("projected_gravity", noise=_noise(0.05)),
            "velocity_commands": _isaac_obs(
                "generated_commands", {"command_name": "base_velocity"}
            ),
            "joint_pos": _isaac_obs("joint_pos_rel", noise=_noise(0.01)),
            "joint_vel": _isaac_obs("joint_vel_rel", noise=_noise(1.5)),
            "actions": _isaac_obs("last_action"),
            "height_scan": None,
        }
    )
    return {
        "viewer": {"eye": (7.5, 7.5, 7.5), "lookat": (0.0, 0.0, 0.0)},
        "sim": {
            "physics_prim_path": "/physicsScene",
            "device": "cuda:0",
            "dt": 0.005,
            "render_interval": 4,
            "gravity": (0.0, 0.0, -9.81),
        },
        "ui_window_class_type": "isaaclab.envs.ui.manager_based_rl_env_window:ManagerBasedRLEnvWindow",
        "seed": 42,
        "decimation": 4,
        "scene": {
            "num_envs": 4096,
            "env_spacing": 2.5,
            "robot": {
                "class_type": "isaaclab.assets.articulation.articulation:Articulation",
                "prim_path": "/World/envs/env_.*/Robot",
                "init_state": {
                    "pos": (0.0, 0.0, 0.4),
                    "rot": (1.0, 0.0, 0.0, 0.0),
                    "lin_vel": (0.0, 0.0, 0.0),
                    "ang_vel": (0.0, 0.0, 0.0),
                    "joint_pos": {
                        ".*L_hip_joint": 0.1,
                        ".*R_hip_joint": -0.1,
                        "F[L,R]_thigh_joint": 0.8,
                        "R[L,R]_thigh_joint": 1.0,
                        ".*_calf_joint": -1.5,
                    },
                    "joint_vel": {".*": 0.0},
                },
                "soft_joint_pos_limit_factor": 0.9,
                "actuators": {
                    "base_legs": {
                        "class_type": "isaaclab.actuators.actuator_pd:DCMotor",
                        "joint_names_expr": [".*_hip_joint", ".*_thigh_joint", ".*_calf_joint"],
                        "effort_limit": 23.5,
                        "velocity_limit": 30.0,
                        "stiffness": stiffness,
                        "damping": damping,
                        "armature": None,
                        "friction": 0.0,
                        "saturation_effort": 23.5,
                    }
                },
            },
        },
        "observations": {"policy": policy},
        "actions": {
            "joint_pos": {
                "class_type": "isaaclab.envs.mdp.actions.joint_actions:JointPositionAction",
                "asset_name": "robot",
                "debug_vis": False,
                "clip": None,
                "joint_names": [".*"],
                "scale": scale,
                "offset": 0.0,
                "preserve_order": False,
                "use_default_offset": True,
            }
        },
        "commands": {
            "base_velocity": {
                "class_type": "isaaclab.envs.mdp.commands.velocity_command:UniformVelocityCommand",
                "resampling_time_range": (10.0, 10.0),
                "heading_command": True,
                "ranges": {
                    "lin_vel_x": (-1.0, 1.0),
                    "lin_vel_y": (-1.0, 1.0),
                    "ang_vel_z": (-1.0, 1.0),
                    "heading": (-math.pi, math.pi),
                },
            }
        },
        "joint_ids_example": slice(None),  # a slice: yaml.dump writes a Python object tag
    }


def write_isaaclab_run(
    run: Path, env: dict, obs_dim: int, act_dim: int, opset=11, gain=1e-3, bias=None
) -> Path:
    """An Isaac Lab run folder: ``params/env.yaml``, ``params/agent.yaml`` (rsl_rl's runner
    config, ``clip_actions`` null) and ``exported/policy.onnx``; returns the ONNX path."""
    params = run / "params"
    params.mkdir(parents=True, exist_ok=True)
    with open(params / "env.yaml", "w") as f:
        yaml.dump(env, f, default_flow_style=False, sort_keys=False)
    agent = {
        "seed": 42,
        "device": "cuda:0",
        "num_steps_per_env": 24,
        "clip_actions": None,
        "experiment_name": "unitree_go2_flat",
    }
    with open(params / "agent.yaml", "w") as f:
        yaml.dump(agent, f, default_flow_style=False, sort_keys=False)
    actor = Actor(obs_dim, act_dim, 2, gain, bias)
    return _export(actor, obs_dim, run / "exported" / "policy.onnx", opset, ["obs"], ["actions"])


def isaaclab_order() -> tuple[str, ...]:
    """Isaac Lab's Go2 articulation order (PhysX, breadth first): hips, thighs, calves."""
    return tuple(
        f"{leg}_{part}_joint"
        for part in ("hip", "thigh", "calf")
        for leg in ("FL", "FR", "RL", "RR")
    )


def run_graph(path: Path, x: np.ndarray) -> np.ndarray:
    """The graph run by plain ONNX Runtime on ``x`` (batch, obs)."""
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return session.run(None, {session.get_inputs()[0].name: x.astype(np.float32)})[0]


# ------------------------------------------------------------------- Unitree's deploy.yaml
def unitree_deploy(slots, default, scale=0.25, stiffness=25.0, damping=0.5, terms=None) -> dict:
    """A ``params/deploy.yaml`` as unitree_rl_lab / unitree_rl_mjlab write it (their
    ``deploy/robots/go2/config/policy/velocity/v0/params/deploy.yaml``): ``joint_ids_map`` the
    motor slot of each policy joint, ``stiffness`` and ``damping`` in the motor slots' order (one
    number here), every other per-joint list in the policy's order."""
    n = len(slots)

    def term(scale=1.0, size=3):
        return {"params": {}, "clip": None, "scale": [scale] * size, "history_length": 1}

    return {
        "joint_ids_map": list(slots),
        "step_dt": 0.02,
        "stiffness": [stiffness] * n,
        "damping": [damping] * n,
        "default_joint_pos": list(default),
        "commands": {
            "base_velocity": {
                "ranges": {
                    "lin_vel_x": [-0.5, 1.0],
                    "lin_vel_y": [-0.5, 0.5],
                    "ang_vel_z": [-1.0, 1.0],
                    "heading": None,
                }
            }
        },
        "actions": {
            "JointPositionAction": {
                "clip": None,
                "joint_names": [".*"],
                "scale": [scale] * n,
                "offset": list(default),
                "joint_ids": None,
            }
        },
        "observations": terms
        or {
            "base_ang_vel": term(0.25),
            "projected_gravity": term(),
            "velocity_commands": {**term(), "params": {"command_name": "base_velocity"}},
            "joint_pos_rel": term(1.0, n),
            "joint_vel_rel": term(0.05, n),
            "last_action": term(1.0, n),
        },
    }


def write_unitree_policy(folder: Path, cfg: dict, obs_dim: int, gain=1e-3, bias=None) -> Path:
    """``<folder>/params/deploy.yaml`` and ``<folder>/exported/policy.onnx``, its weights in
    ``policy.onnx.data`` (ONNX external data, as their published policies ship); returns the
    ONNX path."""
    (folder / "params").mkdir(parents=True, exist_ok=True)
    with open(folder / "params" / "deploy.yaml", "w") as f:
        yaml.safe_dump(cfg, f, default_flow_style=None, sort_keys=False)
    act_dim = len(cfg["joint_ids_map"])
    path = _export(
        Actor(obs_dim, act_dim, 3, gain, bias),
        obs_dim,
        folder / "exported" / "policy.onnx",
        18,
        ["obs"],
        ["actions"],
    )
    model = onnx.load(str(path))
    onnx.save(
        model, str(path), save_as_external_data=True, location="policy.onnx.data", size_threshold=0
    )
    return path
