"""LeRobot's policy folder, the ``pretrained_model/`` that ``lerobot-train`` writes, read without
lerobot (:func:`detect`, :func:`read`) into a :class:`LeRobotContract`; the same contract is stored
in the exported ONNX under :data:`METADATA_KEY` and read back from it (:func:`detect_onnx`,
:func:`read_onnx`).

The folder (lerobot 0.4.4, ``lerobot/utils/train_utils.py`` ``save_checkpoint``):

- ``config.json``: the policy's config (``type``, ``input_features``, ``output_features``,
  ``normalization_mapping``, ``n_obs_steps``, ``chunk_size``, ``n_action_steps``,
  ``temporal_ensemble_coeff``), written by ``PreTrainedConfig._save_pretrained``;
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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim2real.deploy.spec.foreign.contract import ForeignFormatError

NAME = "lerobot"
#: ``metadata_props`` key of the exported ONNX holding :meth:`LeRobotContract.to_json`.
METADATA_KEY = "lerobot_contract"
#: The policy types whose folder this reader knows (``config.json`` ``type``).
POLICY_TYPES = ("act",)
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


class LeRobotFormatError(ForeignFormatError):
    """A LeRobot folder or contract cannot be read; the one-line message names the file and field."""


@dataclass(frozen=True)
class Normalization:
    """How one feature is normalised before the network (or unnormalised after it).

    Attributes:
        mode: ``MEAN_STD``, ``MIN_MAX`` or ``IDENTITY`` (also a key without statistics).
        stats: ``mean``/``std`` or ``min``/``max``, float32, shaped as the feature (images:
            ``(C, 1, 1)``); empty for ``IDENTITY``.
        eps: The processor's ``eps`` (lerobot's default 1e-8).
    """

    mode: str
    stats: dict[str, np.ndarray] = field(default_factory=dict)
    eps: float = 1e-8

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Normalise ``x`` (numpy float32, the feature's shape with leading batch axes)."""
        s = self.stats
        if self.mode == "MEAN_STD":
            return (x - s["mean"]) / (s["std"] + np.float32(self.eps))
        if self.mode == "MIN_MAX":
            return 2 * (x - s["min"]) / self._span() - 1
        return x

    def invert(self, y: np.ndarray) -> np.ndarray:
        """Unnormalise ``y`` (the inverse lerobot's unnormalizer applies)."""
        s = self.stats
        if self.mode == "MEAN_STD":
            return y * s["std"] + s["mean"]
        if self.mode == "MIN_MAX":
            return (y + 1) / 2 * self._span() + s["min"]
        return y

    def _span(self) -> np.ndarray:
        d = self.stats["max"] - self.stats["min"]
        return np.where(d == 0, np.float32(self.eps), d).astype(np.float32)


@dataclass(frozen=True)
class LeRobotContract:
    """What a LeRobot policy folder says its policy takes and gives.

    Attributes:
        policy_type: ``config.json`` ``type`` (``act``).
        state_dim: Entries of ``observation.state`` (0: none).
        env_state_dim: Entries of ``observation.environment_state`` (0: none).
        cameras: ``(key, (C, H, W))`` per camera, in ``config.json`` order (the order ACT's
            ``image_features`` tokenises them); images float32 in ``[0, 1]``, RGB, channel first.
        action_dim: Entries of ``action``.
        normalization: Per feature key (state, cameras, action): its :class:`Normalization`.
        n_obs_steps, chunk_size, n_action_steps: ``config.json``'s; a chunk is ``chunk_size``
            actions, ``n_action_steps`` of them executed per call of the network.
        temporal_ensemble_coeff: ``config.json``'s; None: the action queue; a number: every tick
            one call, ensembled with weights ``exp(-coeff * i)`` (``ACTTemporalEnsembler``).
        fps: The policy's rate (Hz): ``train_config.json`` ``env.fps``, or given at export.
        rename_map: The preprocessor's ``rename_observations_processor`` map (robot key ->
            policy key).
        source: The folder read.
    """

    policy_type: str
    state_dim: int
    env_state_dim: int
    cameras: tuple[tuple[str, tuple[int, int, int]], ...]
    action_dim: int
    normalization: dict[str, Normalization]
    n_obs_steps: int
    chunk_size: int
    n_action_steps: int
    temporal_ensemble_coeff: float | None
    fps: float | None
    rename_map: dict[str, str] = field(default_factory=dict)
    source: str = ""

    @property
    def camera_keys(self) -> tuple[str, ...]:
        """The cameras' feature keys (``observation.images.<name>``)."""
        return tuple(k for k, _ in self.cameras)

    def with_fps(self, fps: float) -> LeRobotContract:
        """A copy with the policy's rate ``fps`` (Hz, > 0)."""
        from dataclasses import replace

        if not _positive(fps):
            raise LeRobotFormatError(f"{self.source}: fps must be a number above 0, got {fps!r}")
        return replace(self, fps=float(fps))

    def to_json(self) -> str:
        """The contract as JSON (statistics as lists), as stored in the ONNX metadata."""
        return json.dumps(
            {
                "format": NAME,
                "policy_type": self.policy_type,
                "state_dim": self.state_dim,
                "env_state_dim": self.env_state_dim,
                "cameras": [
                    {
                        "key": k,
                        "shape": list(s),
                        "dtype": "float32",
                        "range": [0.0, 1.0],
                        "channels": "RGB",
                        "layout": "CHW",
                    }
                    for k, s in self.cameras
                ],
                "action_dim": self.action_dim,
                "normalization": {
                    k: {
                        "mode": n.mode,
                        "eps": n.eps,
                        "stats": {s: v.tolist() for s, v in n.stats.items()},
                    }
                    for k, n in self.normalization.items()
                },
                "n_obs_steps": self.n_obs_steps,
                "chunk_size": self.chunk_size,
                "n_action_steps": self.n_action_steps,
                "temporal_ensemble_coeff": self.temporal_ensemble_coeff,
                "fps": self.fps,
                "rename_map": self.rename_map,
            }
        )

    @classmethod
    def from_json(cls, text: str, source: str) -> LeRobotContract:
        """Read :meth:`to_json`'s text back; ``source`` names the file in errors."""
        try:
            d = json.loads(text)
            norm = {
                k: Normalization(
                    v["mode"],
                    {s: np.asarray(a, dtype=np.float32) for s, a in v["stats"].items()},
                    float(v["eps"]),
                )
                for k, v in d["normalization"].items()
            }
            return cls(
                policy_type=d["policy_type"],
                state_dim=int(d["state_dim"]),
                env_state_dim=int(d["env_state_dim"]),
                cameras=tuple((c["key"], tuple(int(x) for x in c["shape"])) for c in d["cameras"]),
                action_dim=int(d["action_dim"]),
                normalization=norm,
                n_obs_steps=int(d["n_obs_steps"]),
                chunk_size=int(d["chunk_size"]),
                n_action_steps=int(d["n_action_steps"]),
                temporal_ensemble_coeff=d["temporal_ensemble_coeff"],
                fps=d["fps"],
                rename_map=dict(d["rename_map"]),
                source=source,
            )
        except (ValueError, KeyError, TypeError) as e:
            raise LeRobotFormatError(
                f"{source}: metadata {METADATA_KEY!r} is not a LeRobot contract ({e})"
            ) from None


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
    )


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


def _positive(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) and v > 0


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


def describe(c: LeRobotContract) -> list[str]:
    """Lines for ``--inspect`` and the export's report."""
    ens = (
        f"temporal ensembling (coeff {c.temporal_ensemble_coeff}, a call every tick)"
        if c.temporal_ensemble_coeff is not None
        else f"action queue ({c.n_action_steps} of {c.chunk_size} actions per call)"
    )
    lines = [
        f"LeRobot {c.policy_type.upper()} policy ({c.source})",
        f"  state {c.state_dim}, action {c.action_dim}, chunk {c.chunk_size}; {ens}",
        f"  rate: {c.fps} Hz" if c.fps else "  rate: unknown (no train_config.json env.fps)",
    ]
    for key, shape in c.cameras:
        lines.append(f"  camera {key}: {shape[0]}x{shape[1]}x{shape[2]} float32 [0, 1] RGB CHW")
    for key, n in c.normalization.items():
        lines.append(f"  {key}: {n.mode}")
    return lines
