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
