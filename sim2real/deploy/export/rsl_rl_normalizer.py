"""rsl_rl's observation normalizer (``EmpiricalNormalization``) read from a checkpoint, shared
by its feed-forward and recurrent readers."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch
from torch import nn

from sim2real.deploy.export.errors import ExportError
from sim2real.deploy.export.network import check_finite_tensors
from sim2real.deploy.export.source import NormalizeNoClip
from sim2real.deploy.spec.policy_spec import PolicySpec

#: rsl_rl ``EmpiricalNormalization``'s default eps (``rsl_rl/modules/normalizer.py``; not stored
#: in checkpoints).
RSL_RL_EPS = 1e-2


def rsl_rl_normalizer(
    path: Path, obj: Mapping, msd: Mapping[str, torch.Tensor], spec: PolicySpec
) -> nn.Module | None:
    """rsl_rl's actor ``EmpiricalNormalization`` as a graph module ``(obs - _mean) / (_std +
    RSL_RL_EPS)``, or None when the checkpoint has none.

    Raises:
        ExportError: statistics without ``_mean`` / ``_std``, of the wrong size, non-finite or
            negative.
    """
    stats, where = None, None
    if "actor_obs_normalizer._mean" in msd:
        stats = {
            k.split(".", 1)[1]: v for k, v in msd.items() if k.startswith("actor_obs_normalizer.")
        }
        where = "model_state_dict 'actor_obs_normalizer'"
    elif isinstance(obj.get("obs_norm_state_dict"), Mapping):
        stats, where = obj["obs_norm_state_dict"], "field 'obs_norm_state_dict'"
    norm = None
    if stats is not None:
        if "_mean" not in stats or ("_std" not in stats and "_var" not in stats):
            raise ExportError(f"{path}: {where} needs '_mean' and '_std' (or '_var')")
        mean = stats["_mean"].reshape(-1).to(torch.float32)
        std = stats["_std"] if "_std" in stats else torch.sqrt(stats["_var"])
        std = std.reshape(-1).to(torch.float32)
        check_finite_tensors({"_mean": mean, "_std": std}, f"{path}: {where}")
        if mean.shape != (spec.obs_dim,) or std.shape != (spec.obs_dim,):
            raise ExportError(
                f"{path}: {where} has {mean.shape[0]} entries, the spec's observation has "
                f"{spec.obs_dim}"
            )
        if (std < 0).any():
            raise ExportError(f"{path}: {where} has negative standard deviations")
        norm = NormalizeNoClip(mean, std + RSL_RL_EPS)
    return norm
