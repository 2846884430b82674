"""rsl_rl checkpoints (``{"model_state_dict": {"actor.0.weight", ...}, ...}``): the ``actor.*``
MLP (ELU by default) and the actor's ``EmpiricalNormalization`` (:func:`rsl_rl_normalizer`, eps
``RSL_RL_EPS``). An ``ActorCriticRecurrent`` (``memory_a.rnn.*``) goes to
:mod:`sim2real.deploy.export.rsl_rl_recurrent`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch

from sim2real.deploy.export.errors import ExportError
from sim2real.deploy.export.network import (
    _build_mlp,
    _probe,
    _require_spec,
    rsl_rl_actor_layers,
)
from sim2real.deploy.export.rsl_rl_normalizer import RSL_RL_EPS, rsl_rl_normalizer
from sim2real.deploy.export.source import SourcePolicy
from sim2real.deploy.spec.policy_spec import PolicySpec


def _load_rsl_rl(
    path: Path, obj: Mapping, spec: PolicySpec | None, activation: str | None
) -> SourcePolicy:
    spec = _require_spec(spec, path, "rsl_rl checkpoint")
    msd = obj["model_state_dict"]
    if not isinstance(msd, Mapping) or not all(isinstance(v, torch.Tensor) for v in msd.values()):
        raise ExportError(f"{path}: field 'model_state_dict' is not a state dict of tensors")
    if any(k.startswith("memory_a.rnn.") for k in msd):
        from sim2real.deploy.export.rsl_rl_recurrent import load_rsl_rl_recurrent

        return load_rsl_rl_recurrent(path, obj, msd, spec, activation)
    recurrent = [k for k in msd if k.startswith(("memory_a.", "memory_c.", "actor.rnn"))]
    if recurrent:
        raise ExportError(
            f"{path}: recurrent rsl_rl policy ({recurrent[0]}, ...) of an unsupported layout; "
            "an ActorCriticRecurrent actor (memory_a.rnn LSTM or GRU + actor MLP) is expected"
        )
    layers = rsl_rl_actor_layers(msd, path, "field 'model_state_dict' has no")
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
