"""rsl_rl checkpoints (``{"model_state_dict": {"actor.0.weight", ...}, ...}``): the ``actor.*``
MLP (ELU by default) and the actor's ``EmpiricalNormalization`` (:func:`rsl_rl_normalizer`, eps
``RSL_RL_EPS``). An ``ActorCriticRecurrent`` (``memory_a.rnn.*``) goes to
:mod:`deploy.export.rsl_rl_recurrent`.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import torch
from torch import nn

from deploy.export.errors import ExportError
from deploy.export.network import (
    _build_mlp,
    _linear_stack,
    _probe,
    _require_spec,
    check_finite_tensors,
)
from deploy.export.source import NormalizeNoClip, SourcePolicy
from deploy.spec.policy_spec import PolicySpec

RSL_RL_EPS = 1e-2  # rsl_rl EmpiricalNormalization default eps (not stored in checkpoints)


def _load_rsl_rl(
    path: Path, obj: Mapping, spec: PolicySpec | None, activation: str | None
) -> SourcePolicy:
    spec = _require_spec(spec, path, "rsl_rl checkpoint")
    msd = obj["model_state_dict"]
    if not isinstance(msd, Mapping) or not all(isinstance(v, torch.Tensor) for v in msd.values()):
        raise ExportError(f"{path}: field 'model_state_dict' is not a state dict of tensors")
    if any(k.startswith("memory_a.rnn.") for k in msd):
        from deploy.export.rsl_rl_recurrent import load_rsl_rl_recurrent

        return load_rsl_rl_recurrent(path, obj, msd, spec, activation)
    recurrent = [k for k in msd if k.startswith(("memory_a.", "memory_c.", "actor.rnn"))]
    if recurrent:
        raise ExportError(
            f"{path}: recurrent rsl_rl policy ({recurrent[0]}, ...) of an unsupported layout; "
            "an ActorCriticRecurrent actor (memory_a.rnn LSTM or GRU + actor MLP) is expected"
        )
    actor_keys = {k: v for k, v in msd.items() if re.fullmatch(r"actor\.\d+\.(weight|bias)", k)}
    if not actor_keys:
        raise ExportError(
            f"{path}: field 'model_state_dict' has no 'actor.<i>.weight' layers "
            f"(keys: {sorted(msd)[:8]})"
        )
    layers = _linear_stack(actor_keys, "actor.", path)
    net = _build_mlp(layers, activation or "elu", None, path, "rsl_rl actor")
    norm = rsl_rl_normalizer(path, obj, msd, spec)
    _probe(net, spec, path)
    return SourcePolicy(
        net=net,
        spec=spec,
        source_format="rsl_rl",
        normalizer=norm,
        normalizer_kind=None
        if norm is None
        else f"rsl_rl EmpiricalNormalization (eps {RSL_RL_EPS})",
    )


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
