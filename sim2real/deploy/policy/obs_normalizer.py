"""The empirical observation normalizer a checkpoint may carry (e.g. SB3 ``VecNormalize``):
``clip((obs - mean) / sqrt(var + epsilon), -clip, clip)`` on the spec's observation, (obs_dim,)
statistics kept in float64. Invalid fields raise :class:`~sim2real.deploy.policy.torch_file.CheckpointError`
naming the field.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from sim2real.deploy.policy.torch_file import CheckpointError, finite_check


@dataclass(frozen=True, eq=False)
class ObservationNormalizer:
    """Empirical observation normalizer (e.g. SB3 ``VecNormalize``):
    ``clip((obs - mean) / sqrt(var + epsilon), -clip, clip)``, applied to the spec's observation.

    Attributes:
        mean: (obs_dim,) running mean of the observation.
        var: (obs_dim,) running variance (>= 0).
        epsilon: Added to ``var`` before the square root.
        clip: Symmetric clip of the result (> 0; ``inf`` for none).
    """

    mean: torch.Tensor
    var: torch.Tensor
    epsilon: float = 1e-8
    clip: float = 10.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", torch.as_tensor(np.asarray(self.mean, dtype=np.float64)))
        object.__setattr__(self, "var", torch.as_tensor(np.asarray(self.var, dtype=np.float64)))
        object.__setattr__(self, "epsilon", float(self.epsilon))
        object.__setattr__(self, "clip", float(self.clip))

    @property
    def obs_dim(self) -> int:
        return int(self.mean.shape[0])

    def validate(self, where: str = "obs_normalizer", obs_dim: int | None = None) -> None:
        """Check shapes and values.

        Raises:
            CheckpointError: naming the field (the message starts with ``where``).
        """
        for key in ("mean", "var"):
            t = getattr(self, key)
            if t.ndim != 1 or (obs_dim is not None and t.shape[0] != obs_dim):
                raise CheckpointError(
                    f"{where}.{key}: shape {tuple(t.shape)}, expected ({obs_dim or 'obs_dim'},)"
                )
        if self.mean.shape != self.var.shape:
            raise CheckpointError(
                f"{where}: mean {tuple(self.mean.shape)} and var {tuple(self.var.shape)} differ"
            )
        finite_check({"mean": self.mean, "var": self.var}, where)
        if (self.var < 0).any():
            raise CheckpointError(f"{where}.var: negative variance")
        if not (math.isfinite(self.epsilon) and self.epsilon >= 0):
            raise CheckpointError(f"{where}.epsilon: must be finite and >= 0, got {self.epsilon}")
        if not self.clip > 0:
            raise CheckpointError(f"{where}.clip: must be positive, got {self.clip}")
        if ((self.var + self.epsilon) <= 0).any():
            raise CheckpointError(f"{where}: var + epsilon is 0 for some entries (division by 0)")

    def denominator(self) -> torch.Tensor:
        """``sqrt(var + epsilon)``, float32 (obs_dim,), computed in float64."""
        return torch.sqrt(self.var.double() + self.epsilon).float()

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        """The normalized observation, float32, same shape as ``obs`` (float32 arithmetic)."""
        x = (np.asarray(obs, np.float32) - self.mean.float().numpy()) / self.denominator().numpy()
        return np.clip(x, -self.clip, self.clip).astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        """The ``obs_normalizer`` entry of a checkpoint."""
        return {
            "mean": self.mean.clone(),
            "var": self.var.clone(),
            "epsilon": self.epsilon,
            "clip": self.clip,
        }

    @classmethod
    def from_dict(cls, d: Any, where: str = "obs_normalizer") -> ObservationNormalizer:
        """Parse an ``obs_normalizer`` entry.

        Raises:
            CheckpointError: missing or invalid field.
        """
        if not isinstance(d, Mapping):
            raise CheckpointError(f"{where}: expected None or a dict, got {type(d).__name__}")
        for key in ("mean", "var", "epsilon", "clip"):
            if key not in d:
                raise CheckpointError(f"{where}.{key}: missing")
        try:
            norm = cls(
                mean=np.asarray(d["mean"], dtype=np.float64),
                var=np.asarray(d["var"], dtype=np.float64),
                epsilon=float(d["epsilon"]),
                clip=float(d["clip"]),
            )
        except (TypeError, ValueError, RuntimeError) as exc:
            raise CheckpointError(f"{where}: invalid value: {exc}") from None
        norm.validate(where)
        return norm
