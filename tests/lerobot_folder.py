"""A LeRobot ACT policy folder written in a test's tmp_path the way lerobot 0.4.4 writes one
(``PreTrainedConfig._save_pretrained``'s config.json, ``DataProcessorPipeline.save_pretrained``'s
policy_preprocessor.json / policy_postprocessor.json and their statistics in safetensors files,
``<key>.<stat>`` tensors), without lerobot: for the contract reader's tests."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

CAMERAS = {"observation.images.front": [3, 48, 64], "observation.images.wrist": [3, 48, 64]}


def features(state: int = 6, action: int = 6, cameras=None):
    cameras = CAMERAS if cameras is None else cameras
    inputs = {"observation.state": {"type": "STATE", "shape": [state]}}
    inputs.update({k: {"type": "VISUAL", "shape": list(s)} for k, s in cameras.items()})
    return inputs, {"action": {"type": "ACTION", "shape": [action]}}


def stats(state: int = 6, action: int = 6, cameras=None) -> dict[str, np.ndarray]:
    """The flat ``<key>.<stat>`` tensors of a normalizer's state file."""
    cameras = CAMERAS if cameras is None else cameras
    out = {}
    for key, n in (("observation.state", state), ("action", action)):
        out[f"{key}.mean"] = np.linspace(-10, 10, n, dtype=np.float32)
        out[f"{key}.std"] = np.linspace(5, 20, n, dtype=np.float32)
        out[f"{key}.min"] = np.full(n, -90.0, np.float32)
        out[f"{key}.max"] = np.full(n, 90.0, np.float32)
    for key in cameras:
        out[f"{key}.mean"] = np.array([0.4, 0.45, 0.5], np.float32).reshape(3, 1, 1)
        out[f"{key}.std"] = np.array([0.2, 0.22, 0.25], np.float32).reshape(3, 1, 1)
    return out


def write_act_folder(
    folder: Path,
    *,
    chunk_size: int = 10,
    n_action_steps: int = 5,
    temporal_ensemble_coeff=None,
    norm_map=None,
    config_edits=None,
    pre_steps=None,
    drop_stats=(),
    train_env_fps=None,
) -> Path:
    """Write config.json, the two processor JSONs and their state files into ``folder``."""
    save_file = pytest.importorskip(
        "safetensors.numpy", reason="the extra 'export' (safetensors) is not installed"
    ).save_file
    folder.mkdir(parents=True, exist_ok=True)
    norm_map = norm_map or {"VISUAL": "MEAN_STD", "STATE": "MEAN_STD", "ACTION": "MEAN_STD"}
    inputs, outputs = features()
    cfg = {
        "type": "act",
        "n_obs_steps": 1,
        "input_features": inputs,
        "output_features": outputs,
        "device": "cpu",
        "use_amp": False,
        "chunk_size": chunk_size,
        "n_action_steps": n_action_steps,
        "normalization_mapping": norm_map,
        "vision_backbone": "resnet18",
        "pretrained_backbone_weights": None,
        "dim_model": 32,
        "temporal_ensemble_coeff": temporal_ensemble_coeff,
    }
    cfg.update(config_edits or {})
    (folder / "config.json").write_text(json.dumps(cfg, indent=4))
    flat = {k: v for k, v in stats().items() if k not in drop_stats}
    pre_file = "policy_preprocessor_step_3_normalizer_processor.safetensors"
    post_file = "policy_postprocessor_step_0_unnormalizer_processor.safetensors"
    save_file(flat, str(folder / pre_file))
    save_file({k: v for k, v in flat.items() if k.startswith("action.")}, str(folder / post_file))
    steps = pre_steps or [
        {"registry_name": "rename_observations_processor", "config": {"rename_map": {}}},
        {"registry_name": "to_batch_processor", "config": {}},
        {"registry_name": "device_processor", "config": {"device": "cpu", "float_dtype": None}},
        {
            "registry_name": "normalizer_processor",
            "config": {"eps": 1e-08, "features": {**inputs, **outputs}, "norm_map": norm_map},
            "state_file": pre_file,
        },
    ]
    (folder / "policy_preprocessor.json").write_text(
        json.dumps({"name": "policy_preprocessor", "steps": steps}, indent=2)
    )
    post = [
        {
            "registry_name": "unnormalizer_processor",
            "config": {"eps": 1e-08, "features": outputs, "norm_map": norm_map},
            "state_file": post_file,
        },
        {"registry_name": "device_processor", "config": {"device": "cpu", "float_dtype": None}},
    ]
    (folder / "policy_postprocessor.json").write_text(
        json.dumps({"name": "policy_postprocessor", "steps": post}, indent=2)
    )
    if train_env_fps is not None:
        (folder / "train_config.json").write_text(json.dumps({"env": {"fps": train_env_fps}}))
    return folder


def write_chunk_onnx(
    path: Path,
    *,
    chunk_size: int = 4,
    n_action_steps: int = 2,
    coeff=None,
    fps: float = 30.0,
    step_deg: float = 2.0,
    gain: float = 0.5,
    image_shape=(3, 8, 8),
    camera_key: str = "observation.images.front",
    cameras=None,
) -> Path:
    """A stand-in for an exported ACT with the export's inputs, output and contract (built with
    onnx.helper, no lerobot): action i of a chunk is ``gain`` x the state plus ``i * step_deg`` on
    every entry (plus 0 x the camera image's mean; ``image_shape`` None: no camera; ``camera_key``
    its camera's key; ``cameras``: several, ``((key, shape), ...)`` in the graph's order, in
    their place), so a chunk is a ramp and each new chunk starts
    again from the state: a target that jumps back at every chunk boundary, and an arm that settles
    where ``gain`` x state + the ramp holds it (LeRobot's units: degrees, gripper percent)."""
    import onnx
    from onnx import TensorProto, helper

    from sim2real.deploy.spec.foreign import lerobot as lr

    offsets = (np.arange(chunk_size, dtype=np.float32)[:, None] * step_deg) * np.ones(
        (1, 6), np.float32
    )
    nodes = [
        helper.make_node("Mul", ["observation.state", "gain"], ["sg"]),
        helper.make_node("Unsqueeze", ["sg", "axis1"], ["s1"]),
        helper.make_node("Add", ["s1", "offsets"], ["ramp"]),
    ]
    if cameras is None:
        cameras = () if image_shape is None else ((camera_key, tuple(image_shape)),)
    cameras = tuple((k, tuple(sh)) for k, sh in cameras)
    if not cameras:  # a state-only policy
        nodes.append(helper.make_node("Identity", ["ramp"], ["action_chunk"]))
    else:
        last = "ramp"
        for i, (key, _) in enumerate(cameras):
            out = "action_chunk" if i == len(cameras) - 1 else f"r{i}"
            nodes += [
                helper.make_node("ReduceMean", [key], [f"m{i}"], keepdims=0),
                helper.make_node("Mul", [f"m{i}", "zero"], [f"z{i}"]),
                helper.make_node("Add", [last, f"z{i}"], [out]),
            ]
            last = out
    inits = [
        helper.make_tensor("axis1", TensorProto.INT64, [1], [1]),
        helper.make_tensor(
            "offsets", TensorProto.FLOAT, [1, chunk_size, 6], offsets.reshape(-1).tolist()
        ),
        helper.make_tensor("gain", TensorProto.FLOAT, [], [gain]),
    ] + [helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0])] * bool(cameras)
    graph = helper.make_graph(
        nodes,
        "chunk_ramp",
        [helper.make_tensor_value_info("observation.state", TensorProto.FLOAT, [1, 6])]
        + [
            helper.make_tensor_value_info(key, TensorProto.FLOAT, [1, *shape])
            for key, shape in cameras
        ],
        [helper.make_tensor_value_info("action_chunk", TensorProto.FLOAT, [1, chunk_size, 6])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    identity = lr.Normalization("IDENTITY")
    contract = lr.LeRobotContract(
        policy_type="act",
        state_dim=6,
        env_state_dim=0,
        cameras=cameras,
        action_dim=6,
        normalization={
            "observation.state": identity,
            "action": identity,
            **{key: identity for key, _ in cameras},
        },
        n_obs_steps=1,
        chunk_size=chunk_size,
        n_action_steps=n_action_steps,
        temporal_ensemble_coeff=coeff,
        fps=fps,
    )
    prop = model.metadata_props.add()
    prop.key, prop.value = lr.METADATA_KEY, contract.to_json()
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def write_diffusion_onnx(
    path: Path,
    *,
    n_obs_steps: int = 2,
    horizon: int = 8,
    n_action_steps: int = 4,
    steps: int = 5,
    fps: float = 25.0,
    noise_deg: float = 0.1,
    image_shape=None,
) -> Path:
    """A stand-in for an exported Diffusion Policy (DDPM) with the export's inputs, output and
    contract (built with onnx.helper, no lerobot): ``observation.state`` and
    ``observation.environment_state`` ``[1, n_obs_steps, n]``, ``noise`` ``[1, horizon, 6]``,
    ``variance_noise`` ``[steps, 1, horizon, 6]``; each action of the chunk is the newest state
    of the history plus ``noise_deg`` x the initial noise at its index of the executed slice
    (``n_obs_steps - 1`` on), plus 0 x the goal and the variance noise: an arm held where it is,
    with a jitter drawn at every call (LeRobot's units: degrees, gripper percent).
    ``image_shape`` (3, H, W): an ``observation.images.front`` ``[1, n_obs_steps, 3, H, W]``
    input too (plus 0 x its mean)."""
    import onnx
    from onnx import TensorProto, helper

    from sim2real.deploy.spec.foreign import lerobot as lr

    # the export's chunk: n_action_steps and the next one when the horizon has it
    chunk = min(n_action_steps + 1, horizon - n_obs_steps + 1)
    start, end = n_obs_steps - 1, n_obs_steps - 1 + chunk
    nodes = [
        helper.make_node("Gather", ["observation.state", "last"], ["s"], axis=1),  # (1, 6)
        helper.make_node("Unsqueeze", ["s", "axis1"], ["s1"]),  # (1, 1, 6)
        helper.make_node("Slice", ["noise", "start", "end", "axis1"], ["z"]),
        helper.make_node("Mul", ["z", "amp"], ["za"]),
        helper.make_node("Add", ["s1", "za"], ["a"]),
        helper.make_node("ReduceMean", ["observation.environment_state"], ["g"], keepdims=0),
        helper.make_node("ReduceMean", ["variance_noise"], ["v"], keepdims=0),
        helper.make_node("Add", ["g", "v"], ["gv_"]),
        helper.make_node(
            "ReduceMean",
            ["observation.images.front"] if image_shape else ["v"],
            ["im"],
            keepdims=0,
        ),
        helper.make_node("Add", ["gv_", "im"], ["gv"]),
        helper.make_node("Mul", ["gv", "zero"], ["gv0"]),
        helper.make_node("Add", ["a", "gv0"], ["action_chunk"]),
    ]
    inits = [
        helper.make_tensor("last", TensorProto.INT64, [], [n_obs_steps - 1]),
        helper.make_tensor("axis1", TensorProto.INT64, [1], [1]),
        helper.make_tensor("start", TensorProto.INT64, [1], [start]),
        helper.make_tensor("end", TensorProto.INT64, [1], [end]),
        helper.make_tensor("amp", TensorProto.FLOAT, [], [noise_deg]),
        helper.make_tensor("zero", TensorProto.FLOAT, [], [0.0]),
    ]
    f = TensorProto.FLOAT
    graph = helper.make_graph(
        nodes,
        "diffusion_stand_in",
        [
            helper.make_tensor_value_info("observation.state", f, [1, n_obs_steps, 6]),
            helper.make_tensor_value_info("observation.environment_state", f, [1, n_obs_steps, 3]),
            helper.make_tensor_value_info("noise", f, [1, horizon, 6]),
            helper.make_tensor_value_info("variance_noise", f, [steps, 1, horizon, 6]),
        ]
        + [
            helper.make_tensor_value_info(
                "observation.images.front", f, [1, n_obs_steps, *image_shape]
            )
            for _ in [image_shape] * bool(image_shape)
        ],
        [helper.make_tensor_value_info("action_chunk", f, [1, chunk, 6])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    identity = lr.Normalization("IDENTITY")
    contract = lr.LeRobotContract(
        policy_type="diffusion",
        state_dim=6,
        env_state_dim=3,
        cameras=(("observation.images.front", tuple(image_shape)),) if image_shape else (),
        action_dim=6,
        normalization={k: identity for k in ("observation.state", "action")}
        | {"observation.environment_state": identity}
        | ({"observation.images.front": identity} if image_shape else {}),
        n_obs_steps=n_obs_steps,
        chunk_size=chunk,
        n_action_steps=n_action_steps,
        temporal_ensemble_coeff=None,
        fps=fps,
        horizon=horizon,
        diffusion={
            "scheduler": "DDPM",
            "num_train_timesteps": steps,
            "num_inference_steps": steps,
            "beta_schedule": "squaredcos_cap_v2",
            "prediction_type": "epsilon",
            "clip_sample": True,
            "clip_sample_range": 1.0,
            "crop_shape": None,
            "timesteps": list(range(steps - 1, -1, -1)),
            "noise_inputs": {"noise": [1, horizon, 6], "variance_noise": [steps, 1, horizon, 6]},
        },
    )
    prop = model.metadata_props.add()
    prop.key, prop.value = lr.METADATA_KEY, contract.to_json()
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path
