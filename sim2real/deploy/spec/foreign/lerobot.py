"""LeRobot's policy folder, the ``pretrained_model/`` that ``lerobot-train`` writes, read without
lerobot (:func:`detect`, :func:`read`) into a :class:`LeRobotContract`; the same contract is stored
in the exported ONNX under :data:`METADATA_KEY` and read back from it (:func:`detect_onnx`,
:func:`read_onnx`).

The folder (lerobot 0.4.4, ``lerobot/utils/train_utils.py`` ``save_checkpoint``):

- ``config.json``: the policy's config (``type``, ``input_features``, ``output_features``,
  ``normalization_mapping``, ``n_obs_steps``, ``chunk_size``, ``n_action_steps``,
  ``temporal_ensemble_coeff``; Diffusion Policy's ``horizon`` and sampler:
  :mod:`sim2real.deploy.spec.foreign.lerobot_diffusion`), written by
  ``PreTrainedConfig._save_pretrained``;
- ``model.safetensors``: the weights (read only by the export, through lerobot);
- ``policy_preprocessor.json`` / ``policy_postprocessor.json``: the processor pipelines, each step
  a ``registry_name`` with its ``config`` and, for the normalizer steps, a ``state_file`` of
  statistics (``<key>.<stat>`` tensors in a safetensors file), written by
  ``DataProcessorPipeline.save_pretrained`` (``lerobot/processor/pipeline.py``);
- ``train_config.json`` (``lerobot-train`` only): the run's config; ``env.fps`` when trained with
  an environment.

The normalisation is that of ``_NormalizationMixin._apply_transform``
(``lerobot/processor/normalize_processor.py``): ``MEAN_STD`` ``(x - mean) / (std + eps)``,
inverse ``x * std + mean``; ``MIN_MAX`` ``2 (x - min) / d - 1`` with ``d = max - min`` (``eps``
where ``d == 0``), inverse ``(x + 1) / 2 d + min``; ``IDENTITY`` or a key without statistics:
unchanged. Images enter lerobot's policies as float32 ``(C, H, W)`` in ``[0, 1]``, RGB
(``lerobot/policies/utils.py`` ``prepare_observation_for_inference``: ``/ 255``, ``permute(2, 0,
1)``; OpenCV cameras convert BGR to RGB, ``ColorMode.RGB`` being the default of
``OpenCVCameraConfig``).

Every refusal is a :class:`LeRobotFormatError` whose one line names the file and the field.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from sim2real.deploy.spec.foreign.contract import positive_number
from sim2real.deploy.spec.foreign.lerobot_contract import (
    METADATA_KEY,
    NAME,
    LeRobotContract,
    LeRobotFormatError,
    Normalization,
    describe,
)
from sim2real.deploy.spec.foreign.lerobot_diffusion import read_diffusion

__all__ = [
    "METADATA_KEY",
    "NAME",
    "LeRobotContract",
    "LeRobotFormatError",
    "Normalization",
    "describe",
    "detect",
    "detect_onnx",
    "read",
    "read_onnx",
]


def _positive(v) -> bool:
    return positive_number(v, (int, float))


#: The policy types whose folder this reader knows (``config.json`` ``type``).
POLICY_TYPES = ("act", "diffusion")
#: The processor steps a folder may hold (their ``registry_name``); any other is refused, as its
#: effect on the observation would be guessed.
KNOWN_STEPS = (
    "rename_observations_processor",
    "to_batch_processor",
    "device_processor",
    "normalizer_processor",
    "unnormalizer_processor",
)
NORM_MODES = ("MEAN_STD", "MIN_MAX", "IDENTITY")
STATE_KEY, ENV_STATE_KEY, ACTION_KEY = (
    "observation.state",
    "observation.environment_state",
    "action",
)
IMAGE_PREFIX = "observation.images."
PREPROCESSOR, POSTPROCESSOR = "policy_preprocessor.json", "policy_postprocessor.json"


def detect(folder: str | Path) -> bool:
    """Whether ``folder`` is a LeRobot policy folder: a directory with ``config.json`` (a JSON
    object whose ``type`` is a string and that has ``input_features``) and ``policy_preprocessor.json``."""
    folder = Path(folder)
    if not (folder.is_dir() and (folder / "config.json").is_file()):
        return False
    if not (folder / PREPROCESSOR).is_file():
        return False
    try:
        cfg = json.loads((folder / "config.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(cfg, dict) and isinstance(cfg.get("type"), str) and "input_features" in cfg


def read(folder: str | Path, fps: float | None = None) -> LeRobotContract:
    """Read a LeRobot policy folder.

    Args:
        folder: The ``pretrained_model`` directory.
        fps: The policy's rate (Hz) when ``train_config.json`` has no ``env.fps`` (a policy trained
            on a dataset alone: the dataset's ``meta/info.json`` ``fps``); when both are given they
            must agree.

    Raises:
        LeRobotFormatError: A missing file or field, an unknown policy type, processor step or
            normalisation mode, a feature of the wrong shape, missing statistics, or no fps.
    """
    folder = Path(folder)
    cfg_path = folder / "config.json"
    cfg = _load_json(cfg_path)
    ptype = cfg.get("type")
    if ptype not in POLICY_TYPES:
        raise LeRobotFormatError(
            f"{cfg_path}: type {ptype!r} is not read (expected one of {', '.join(POLICY_TYPES)})"
        )
    inputs = _features(cfg, "input_features", cfg_path)
    outputs = _features(cfg, "output_features", cfg_path)
    if ACTION_KEY not in outputs or outputs[ACTION_KEY][0] != "ACTION":
        raise LeRobotFormatError(f"{cfg_path}: output_features has no 'action' of type ACTION")
    (action_dim,) = _vector(outputs[ACTION_KEY], f"{cfg_path}: output_features.action")
    state_dim = env_dim = 0
    cameras: list[tuple[str, tuple[int, int, int]]] = []
    for key, (ftype, shape) in inputs.items():
        where = f"{cfg_path}: input_features.{key}"
        if ftype == "VISUAL":
            if not key.startswith(IMAGE_PREFIX) or len(shape) != 3 or shape[0] != 3:
                raise LeRobotFormatError(
                    f"{where}: a VISUAL feature must be '{IMAGE_PREFIX}<camera>' of shape "
                    f"[3, H, W], got {list(shape)}"
                )
            cameras.append((key, (int(shape[0]), int(shape[1]), int(shape[2]))))
        elif ftype == "STATE" and key == STATE_KEY:
            (state_dim,) = _vector((ftype, shape), where)
        elif ftype == "ENV" and key == ENV_STATE_KEY:
            (env_dim,) = _vector((ftype, shape), where)
        else:
            raise LeRobotFormatError(
                f"{where}: feature of type {ftype!r} is not read (expected {STATE_KEY} STATE, "
                f"{ENV_STATE_KEY} ENV or {IMAGE_PREFIX}<camera> VISUAL)"
            )
    norm_map = cfg.get("normalization_mapping")
    if not isinstance(norm_map, dict):
        raise LeRobotFormatError(f"{cfg_path}: normalization_mapping missing or not an object")
    if ptype == "diffusion":
        dp = read_diffusion(cfg, cfg_path, cameras, env_dim)
        ints = {"n_obs_steps": dp["n_obs_steps"], "n_action_steps": dp["n_action_steps"]}
        # the graph's chunk: the n_action_steps actions select_action executes, and the next one
        # when the horizon has it (async inference plays a chunk from its second action)
        room = dp["horizon"] - dp["n_obs_steps"] + 1
        ints["chunk_size"] = min(dp["n_action_steps"] + 1, room)
        coeff, horizon, diffusion = None, dp["horizon"], dp["diffusion"]
    else:
        ints, coeff = _act_ints(cfg, cfg_path)
        horizon = diffusion = None

    features = {k: v[0] for k, v in {**inputs, **outputs}.items()}
    pre_norm, rename = _processor(folder / PREPROCESSOR, "normalizer_processor", features, norm_map)
    post_norm, _ = _processor(folder / POSTPROCESSOR, "unnormalizer_processor", features, norm_map)
    normalization = {k: v for k, v in pre_norm.items() if k != ACTION_KEY}
    if ACTION_KEY not in post_norm:
        raise LeRobotFormatError(
            f"{folder / POSTPROCESSOR}: no unnormalizer_processor for 'action'"
        )
    normalization[ACTION_KEY] = post_norm[ACTION_KEY]
    return LeRobotContract(
        policy_type=ptype,
        state_dim=state_dim,
        env_state_dim=env_dim,
        cameras=tuple(cameras),
        action_dim=action_dim,
        normalization=normalization,
        n_obs_steps=ints["n_obs_steps"],
        chunk_size=ints["chunk_size"],
        n_action_steps=ints["n_action_steps"],
        temporal_ensemble_coeff=coeff,
        fps=_fps(folder, fps),
        rename_map=rename,
        source=str(folder),
        horizon=horizon,
        diffusion=diffusion,
    )


def _act_ints(cfg: dict, cfg_path: Path) -> tuple[dict[str, int], float | None]:
    """ACT's ``n_obs_steps``, ``chunk_size``, ``n_action_steps`` and ``temporal_ensemble_coeff``."""
    ints = {}
    for name in ("n_obs_steps", "chunk_size", "n_action_steps"):
        v = cfg.get(name)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise LeRobotFormatError(f"{cfg_path}: {name} must be an integer >= 1, got {v!r}")
        ints[name] = v
    if ints["n_obs_steps"] != 1:
        raise LeRobotFormatError(
            f"{cfg_path}: n_obs_steps {ints['n_obs_steps']} is not read (ACT takes 1: "
            "configuration_act.py refuses any other)"
        )
    if ints["n_action_steps"] > ints["chunk_size"]:
        raise LeRobotFormatError(
            f"{cfg_path}: n_action_steps {ints['n_action_steps']} exceeds chunk_size "
            f"{ints['chunk_size']}"
        )
    coeff = cfg.get("temporal_ensemble_coeff")
    if coeff is not None:
        if (
            isinstance(coeff, bool)
            or not isinstance(coeff, (int, float))
            or not math.isfinite(coeff)
        ):
            raise LeRobotFormatError(
                f"{cfg_path}: temporal_ensemble_coeff must be null or a finite number, got {coeff!r}"
            )
        if ints["n_action_steps"] != 1:
            raise LeRobotFormatError(
                f"{cfg_path}: temporal_ensemble_coeff needs n_action_steps 1, got "
                f"{ints['n_action_steps']} (configuration_act.py)"
            )
        coeff = float(coeff)
    return ints, coeff


def detect_onnx(metadata: dict[str, str]) -> bool:
    """Whether an ONNX file's ``metadata_props`` hold a LeRobot contract."""
    return METADATA_KEY in metadata


def read_onnx(path: str | Path) -> LeRobotContract:
    """The :class:`LeRobotContract` stored in an exported ONNX file's metadata."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    md = {p.key: p.value for p in model.metadata_props}
    if METADATA_KEY not in md:
        raise LeRobotFormatError(f"{path}: no {METADATA_KEY!r} metadata (not a LeRobot export)")
    return LeRobotContract.from_json(md[METADATA_KEY], str(path))


def _load_json(path: Path) -> dict:
    if not path.is_file():
        raise LeRobotFormatError(f"{path}: missing (a LeRobot policy folder has it)")
    try:
        data = json.loads(path.read_text())
    except ValueError as e:
        raise LeRobotFormatError(f"{path}: not JSON ({e})") from None
    if not isinstance(data, dict):
        raise LeRobotFormatError(f"{path}: expected a JSON object")
    return data


def _features(cfg: dict, name: str, path: Path) -> dict[str, tuple[str, tuple[int, ...]]]:
    table = cfg.get(name)
    if not isinstance(table, dict) or not table:
        raise LeRobotFormatError(f"{path}: {name} missing or empty")
    out = {}
    for key, f in table.items():
        shape = f.get("shape") if isinstance(f, dict) else None
        ok = (
            isinstance(shape, list)
            and shape
            and all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in shape)
        )
        if not ok or not isinstance(f.get("type"), str):
            raise LeRobotFormatError(
                f"{path}: {name}.{key} must be {{'type': str, 'shape': [positive ints]}}, got {f!r}"
            )
        out[key] = (f["type"], tuple(shape))
    return out


def _vector(feature: tuple[str, tuple[int, ...]], where: str) -> tuple[int]:
    shape = feature[1]
    if len(shape) != 1:
        raise LeRobotFormatError(f"{where}: shape must be [n], got {list(shape)}")
    return (int(shape[0]),)


def _processor(path: Path, step_name: str, features: dict[str, str], norm_map: dict):
    """The normalisation per feature key of the pipeline at ``path`` (its ``step_name`` step),
    and its rename map."""
    pipe = _load_json(path)
    steps = pipe.get("steps")
    if not isinstance(steps, list):
        raise LeRobotFormatError(f"{path}: steps missing or not a list")
    rename: dict[str, str] = {}
    norm: dict[str, Normalization] = {}
    for i, step in enumerate(steps):
        reg = step.get("registry_name") if isinstance(step, dict) else None
        if reg not in KNOWN_STEPS:
            raise LeRobotFormatError(
                f"{path}: steps[{i}].registry_name {reg!r} is not read (expected one of "
                f"{', '.join(KNOWN_STEPS)})"
            )
        conf = step.get("config") or {}
        if reg == "rename_observations_processor":
            rename = dict(conf.get("rename_map") or {})
        if reg != step_name:
            continue
        step_map = conf.get("norm_map", norm_map)
        eps = conf.get("eps", 1e-8)
        state_file = step.get("state_file")
        stats = _stats(path.parent / state_file, path, i) if state_file else {}
        keys = conf.get("features") or {}
        for key, f in keys.items():
            ftype = f.get("type") if isinstance(f, dict) else None
            mode = step_map.get(ftype, "IDENTITY")
            if mode not in NORM_MODES:
                raise LeRobotFormatError(
                    f"{path}: steps[{i}].config.norm_map.{ftype} {mode!r} is not read (expected "
                    f"one of {', '.join(NORM_MODES)})"
                )
            if key not in features:
                raise LeRobotFormatError(
                    f"{path}: steps[{i}].config.features.{key} is not a feature of config.json"
                )
            kstats = stats.get(key, {})
            need = {"MEAN_STD": ("mean", "std"), "MIN_MAX": ("min", "max")}.get(mode, ())
            if mode != "IDENTITY" and not kstats:
                # lerobot leaves a key without statistics unchanged: said here, not guessed.
                norm[key] = Normalization("IDENTITY", {}, float(eps))
                continue
            missing = [s for s in need if s not in kstats]
            if missing:
                raise LeRobotFormatError(
                    f"{path.parent / state_file}: {key}.{missing[0]} missing ({mode} needs "
                    f"{' and '.join(need)})"
                )
            norm[key] = Normalization(mode, {s: kstats[s] for s in need}, float(eps))
    return norm, rename


def _stats(path: Path, pipeline: Path, index: int) -> dict[str, dict[str, np.ndarray]]:
    """``<key>.<stat>`` tensors of a processor's safetensors state file, grouped by key."""
    if not path.is_file():
        raise LeRobotFormatError(f"{pipeline}: steps[{index}].state_file {path.name} missing")
    try:
        from safetensors.numpy import load_file
    except ImportError:
        raise LeRobotFormatError(
            f"{path}: reading LeRobot statistics needs the safetensors package "
            "(pip install 'sim2real-deploy[export]')"
        ) from None
    try:
        flat = load_file(str(path))
    except Exception as e:  # safetensors raises its own SafetensorError
        raise LeRobotFormatError(f"{path}: not a safetensors file ({e})") from None
    out: dict[str, dict[str, np.ndarray]] = {}
    for name, arr in flat.items():
        key, _, stat = name.rpartition(".")
        if not np.all(np.isfinite(arr)):
            raise LeRobotFormatError(f"{path}: {name} has non-finite entries")
        out.setdefault(key, {})[stat] = np.asarray(arr, dtype=np.float32)
    return out


def _fps(folder: Path, given: float | None) -> float | None:
    tc = folder / "train_config.json"
    found = None
    if tc.is_file():
        env = _load_json(tc).get("env")
        if isinstance(env, dict) and env.get("fps") is not None:
            if not _positive(env["fps"]):
                raise LeRobotFormatError(
                    f"{tc}: env.fps must be a number above 0, got {env['fps']!r}"
                )
            found = float(env["fps"])
    if given is not None:
        if not _positive(given):
            raise LeRobotFormatError(f"{folder}: fps must be a number above 0, got {given!r}")
        if found is not None and abs(found - given) > 1e-9:
            raise LeRobotFormatError(f"{tc}: env.fps {found} disagrees with the fps given, {given}")
        return float(given)
    return found
