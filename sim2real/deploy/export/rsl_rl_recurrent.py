"""rsl_rl ``ActorCriticRecurrent`` checkpoints for ``policy-export``.

rsl_rl (``rsl-rl-lib`` 2.x/3.x) saves ``{"model_state_dict": ..., ...}`` with ``torch.save``; a
recurrent actor-critic keeps its actor's memory under ``memory_a.rnn.*`` (an ``nn.LSTM`` or
``nn.GRU``: ``weight_ih_l<k>``, ``weight_hh_l<k>``, ``bias_ih_l<k>``, ``bias_hh_l<k>``), then the
actor MLP ``actor.<i>.weight`` / ``.bias`` (ELU by default) on the RNN's output, and optionally the
``EmpiricalNormalization`` of the actor's observation
(:func:`sim2real.deploy.export.rsl_rl.rsl_rl_normalizer`). Its deterministic action (``act_inference``) is
``actor(memory_a(normalizer(obs)))``; the critic (``memory_c``, ``critic``) is not exported.

The kind is read from the shapes: ``weight_hh_l0`` is (4 hidden, hidden) for an LSTM and
(3 hidden, hidden) for a GRU. A state-dependent standard deviation (an actor whose last layer
returns mean and std) is refused: the spec's action size must be the actor's output size.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch

from sim2real.deploy.export.errors import ExportError
from sim2real.deploy.export.network import (
    _build_mlp,
    check_finite_tensors,
    check_head,
    rsl_rl_actor_layers,
)
from sim2real.deploy.export.recurrent import rnn_from_state_dict
from sim2real.deploy.export.rsl_rl_normalizer import RSL_RL_EPS, rsl_rl_normalizer
from sim2real.deploy.export.source import recurrent_source
from sim2real.deploy.spec.policy_spec import PolicySpec

RNN_PREFIX = "memory_a.rnn."


def load_rsl_rl_recurrent(
    path: Path,
    obj: Mapping,
    msd: Mapping[str, torch.Tensor],
    spec: PolicySpec,
    activation: str | None,
):
    """The :class:`sim2real.deploy.export.SourcePolicy` of an rsl_rl recurrent checkpoint.

    Args:
        path: The file (for messages). obj: The loaded checkpoint. msd: Its ``model_state_dict``.
        spec: The PolicySpec (``--spec``). activation: Hidden activation override (default elu).

    Raises:
        sim2real.deploy.export.ExportError: missing or malformed ``memory_a.rnn`` or ``actor`` layers,
            non-finite weights, sizes that do not fit the spec.
    """
    check_finite_tensors(
        {k: v for k, v in msd.items() if k.startswith(RNN_PREFIX)}, f"{path}: memory_a"
    )
    weights = {k[len(RNN_PREFIX) :]: v for k, v in msd.items() if k.startswith(RNN_PREFIX)}
    rnn = rnn_from_state_dict(weights, spec.obs_dim, f"{path}: {RNN_PREFIX}", ExportError)
    layers = rsl_rl_actor_layers(msd, path, "recurrent rsl_rl checkpoint without")
    names = ("the actor MLP", "the recurrent memory", "the actor")
    note = " (a state-dependent std is not supported)"
    check_head(layers, rnn.hidden_size, spec.act_dim, path, names, note)
    mlp = _build_mlp(layers, activation or "elu", None, path, "rsl_rl actor")
    norm = rsl_rl_normalizer(path, obj, msd, spec)
    kind = None if norm is None else f"rsl_rl EmpiricalNormalization (eps {RSL_RL_EPS})"
    return recurrent_source(rnn, mlp, norm, spec, path, "rsl_rl recurrent", kind)
