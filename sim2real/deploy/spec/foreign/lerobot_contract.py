"""The contract of a LeRobot policy (:class:`LeRobotContract`, :class:`Normalization`), as
:mod:`sim2real.deploy.spec.foreign.lerobot` reads it from the folder ``lerobot-train`` writes and
as the exported ONNX stores it (:meth:`LeRobotContract.to_json` under :data:`METADATA_KEY`), and
its description for ``--inspect`` (:func:`describe`). The normalisation is that of lerobot's
``_NormalizationMixin._apply_transform`` (``lerobot/processor/normalize_processor.py``, 0.4.4).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from sim2real.deploy.spec.foreign.contract import ForeignFormatError, positive_number

NAME = "lerobot"
#: ``metadata_props`` key of the exported ONNX holding :meth:`LeRobotContract.to_json`.
METADATA_KEY = "lerobot_contract"


def _positive(v) -> bool:
    return positive_number(v, (int, float))


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
        horizon: Diffusion Policy's ``horizon`` (actions the denoiser generates per call, from
            the oldest observation of the history); None for ACT. A Diffusion Policy export's
            chunk is the ``chunk_size`` actions from index ``n_obs_steps - 1`` of it:
            ``n_action_steps`` (those ``select_action`` executes) and one more when the horizon
            has it (async inference skips a chunk's first action).
        diffusion: Diffusion Policy's sampler (None for ACT): ``scheduler`` (``DDPM``/``DDIM``),
            ``num_train_timesteps``, ``num_inference_steps``, ``beta_schedule``,
            ``prediction_type``, ``clip_sample``, ``clip_sample_range``, ``crop_shape`` (rows,
            columns or None), and, once exported, ``timesteps`` (the denoising steps' timesteps)
            and ``noise_inputs`` ({graph input: shape}: ``noise`` the initial sample
            (1, horizon, action_dim) and, for DDPM, ``variance_noise`` (steps, 1, horizon,
            action_dim), standard normal; DDIM's eta is 0, no noise after the first).
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
    horizon: int | None = None
    diffusion: dict | None = None

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
                "horizon": self.horizon,
                "diffusion": self.diffusion,
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
                horizon=None if d.get("horizon") is None else int(d["horizon"]),
                diffusion=d.get("diffusion"),
            )
        except (ValueError, KeyError, TypeError) as e:
            raise LeRobotFormatError(
                f"{source}: metadata {METADATA_KEY!r} is not a LeRobot contract ({e})"
            ) from None


def describe(c: LeRobotContract) -> list[str]:
    """Lines for ``--inspect`` and the export's report."""
    ens = (
        f"temporal ensembling (coeff {c.temporal_ensemble_coeff}, a call every tick)"
        if c.temporal_ensemble_coeff is not None
        else f"action queue ({c.n_action_steps} of {c.chunk_size} actions per call)"
    )
    if c.diffusion is not None:
        d = c.diffusion
        ens = (
            f"action queue ({c.n_action_steps} of a horizon of {c.horizon} per call, from "
            f"index {c.n_obs_steps - 1}); {c.n_obs_steps} observations of history; "
            f"{d['scheduler']} sampler, {d['num_inference_steps']} denoising steps of "
            f"{d['num_train_timesteps']}"
        )
    lines = [
        f"LeRobot {c.policy_type.upper()} policy ({c.source})",
        f"  state {c.state_dim}"
        + (f", environment state {c.env_state_dim}" if c.env_state_dim else "")
        + f", action {c.action_dim}, chunk {c.chunk_size}; {ens}",
        f"  rate: {c.fps} Hz" if c.fps else "  rate: unknown (no train_config.json env.fps)",
    ]
    for key, shape in c.cameras:
        lines.append(f"  camera {key}: {shape[0]}x{shape[1]}x{shape[2]} float32 [0, 1] RGB CHW")
    if c.diffusion is not None and c.diffusion.get("crop_shape"):
        rows, cols = c.diffusion["crop_shape"]
        lines.append(f"  images centre-cropped to {rows}x{cols} in the graph (crop_shape)")
    if c.diffusion is not None and c.diffusion.get("noise_inputs"):
        shapes = ", ".join(f"{k} {v}" for k, v in c.diffusion["noise_inputs"].items())
        lines.append(f"  noise inputs (standard normal, drawn per call by the runtime): {shapes}")
    for key, n in c.normalization.items():
        lines.append(f"  {key}: {n.mode}")
    return lines
