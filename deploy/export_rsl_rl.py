"""rsl_rl ``ActorCriticRecurrent`` checkpoints for ``policy-export``.

rsl_rl (``rsl-rl-lib`` 2.x/3.x) saves ``{"model_state_dict": ..., ...}`` with ``torch.save``; a
recurrent actor-critic keeps its actor's memory under ``memory_a.rnn.*`` (an ``nn.LSTM`` or
``nn.GRU``: ``weight_ih_l<k>``, ``weight_hh_l<k>``, ``bias_ih_l<k>``, ``bias_hh_l<k>``), then the
actor MLP ``actor.<i>.weight`` / ``.bias`` (ELU by default) on the RNN's output, and optionally the
``EmpiricalNormalization`` of the actor's observation (:func:`deploy.export.rsl_rl_normalizer`).
Its deterministic action (``act_inference``) is
``actor(memory_a(normalizer(obs)))``; the critic (``memory_c``, ``critic``) is not exported.

The kind is read from the shapes: ``weight_hh_l0`` is (4 hidden, hidden) for an LSTM and
(3 hidden, hidden) for a GRU. A state-dependent standard deviation (an actor whose last layer
returns mean and std) is refused: the spec's action size must be the actor's output size.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import torch
from torch import nn

from deploy.export_recurrent import RecurrentCore, RecurrentPolicyModule
from deploy.spec import PolicySpec

RNN_PREFIX = "memory_a.rnn."


def _rnn_from_state_dict(
    sd: Mapping[str, torch.Tensor], obs_dim: int, path: Path, error
) -> nn.LSTM | nn.GRU:
    """Rebuild ``memory_a.rnn`` (LSTM or GRU) from its state dict entries."""
    weights = {k[len(RNN_PREFIX) :]: v for k, v in sd.items() if k.startswith(RNN_PREFIX)}
    for name in weights:
        if not re.fullmatch(r"(weight|bias)_(ih|hh)_l\d+", name):
            raise error(
                f"{path}: unsupported recurrent parameter '{RNN_PREFIX}{name}' (a one-directional "
                "LSTM or GRU with biases is expected)"
            )
    hh = weights.get("weight_hh_l0")
    ih = weights.get("weight_ih_l0")
    if hh is None or ih is None or hh.ndim != 2 or ih.ndim != 2:
        raise error(f"{path}: '{RNN_PREFIX}weight_ih_l0' / 'weight_hh_l0' missing or not matrices")
    hidden = int(hh.shape[1])
    gates = int(hh.shape[0]) // hidden if hidden else 0
    if gates not in (3, 4) or gates * hidden != hh.shape[0]:
        raise error(
            f"{path}: '{RNN_PREFIX}weight_hh_l0' has shape {tuple(hh.shape)}: neither an LSTM "
            "(4 hidden, hidden) nor a GRU (3 hidden, hidden)"
        )
    if ih.shape[1] != obs_dim:
        raise error(
            f"{path}: wrong input size: the recurrent actor takes {ih.shape[1]} inputs, the "
            f"spec's observation has {obs_dim}"
        )
    layers = len([k for k in weights if k.startswith("weight_ih_l")])
    cls = nn.LSTM if gates == 4 else nn.GRU
    rnn = cls(input_size=obs_dim, hidden_size=hidden, num_layers=layers)
    try:
        rnn.load_state_dict({k: v.to(torch.float32) for k, v in weights.items()})
    except RuntimeError as exc:
        first = str(exc).strip().splitlines()[0]
        raise error(f"{path}: '{RNN_PREFIX}*' does not form a {cls.__name__}: {first}") from None
    return rnn.eval()


def load_rsl_rl_recurrent(
    path: Path,
    obj: Mapping,
    msd: Mapping[str, torch.Tensor],
    spec: PolicySpec,
    activation: str | None,
):
    """The :class:`deploy.export.SourcePolicy` of an rsl_rl recurrent checkpoint.

    Args:
        path: The file (for messages). obj: The loaded checkpoint. msd: Its ``model_state_dict``.
        spec: The PolicySpec (``--spec``). activation: Hidden activation override (default elu).

    Raises:
        deploy.export.ExportError: missing or malformed ``memory_a.rnn`` or ``actor`` layers,
            non-finite weights, sizes that do not fit the spec.
    """
    from deploy import export as ex  # deploy.export imports this module lazily

    ex.check_finite_tensors(
        {k: v for k, v in msd.items() if k.startswith(RNN_PREFIX)}, f"{path}: memory_a"
    )
    rnn = _rnn_from_state_dict(msd, spec.obs_dim, path, ex.ExportError)
    actor_keys = {k: v for k, v in msd.items() if re.fullmatch(r"actor\.\d+\.(weight|bias)", k)}
    if not actor_keys:
        raise ex.ExportError(
            f"{path}: recurrent rsl_rl checkpoint without 'actor.<i>.weight' layers "
            f"(keys: {sorted(msd)[:8]})"
        )
    layers = ex._linear_stack(actor_keys, "actor.", path)
    if layers[0][0].shape[1] != rnn.hidden_size:
        raise ex.ExportError(
            f"{path}: the actor MLP takes {layers[0][0].shape[1]} inputs, the recurrent memory "
            f"gives {rnn.hidden_size}"
        )
    if layers[-1][0].shape[0] != spec.act_dim:
        raise ex.ExportError(
            f"{path}: wrong output size: the actor returns {layers[-1][0].shape[0]} values, the "
            f"spec's action has {spec.act_dim} (a state-dependent std is not supported)"
        )
    mlp = ex._build_mlp(layers, activation or "elu", None, path, "rsl_rl actor")
    norm = ex.rsl_rl_normalizer(path, obj, msd, spec)
    core = RecurrentCore(rnn, mlp).eval()
    probe = RecurrentPolicyModule(core, norm, spec.action.clip).eval()
    with torch.no_grad():
        action, *_ = probe(torch.zeros(2, spec.obs_dim), *core.layout.zeros(2))
    if not torch.isfinite(action).all():
        raise ex.ExportError(f"{path}: the action for the zero observation is not finite")
    return ex.SourcePolicy(
        net=core,
        spec=spec,
        source_format=f"rsl_rl recurrent ({core.layout.kind}, {core.layout.layers} layer(s), "
        f"hidden {core.layout.hidden})",
        normalizer=norm,
        normalizer_kind=None
        if norm is None
        else f"rsl_rl EmpiricalNormalization (eps {ex.RSL_RL_EPS})",
    )
