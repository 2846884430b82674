"""SB3-contrib ``RecurrentPPO`` zips (``MlpLstmPolicy``) for ``policy-export``.

Read without unpickling, as for PPO (:func:`sim2real.deploy.export.sb3._load_sb3`): ``policy.pth`` (the
``RecurrentActorCriticPolicy`` state dict, ``torch.load(weights_only=True)``) and the ``data``
JSON. The deterministic action of sb3-contrib's ``predict(obs, state, episode_start,
deterministic=True)`` is

    latent, (h, c) = lstm_actor(obs.unsqueeze(0), (h, c))      # sequence-first nn.LSTM
    action = action_net(mlp_extractor.policy_net(latent.squeeze(0)))

(the Gaussian mean; ``FlattenExtractor`` has no parameters and a Box observation is used as it
is), then clipped to the action space, which must be Box(-1, 1) (the spec's action clip is
baked in). ``episode_start`` zeroes an env's state before its step: :meth:`OnnxPolicy.reset`
does the same. The LSTM (``lstm_actor.weight_ih_l<k>``, ... ; layers and hidden size from the
shapes) becomes a :class:`sim2real.deploy.export.recurrent.RecurrentCore` with the policy net and
``action_net`` as its MLP; the critic (``lstm_critic``, ``value_net``) is not exported. The
hidden activation is ``policy_kwargs.activation_fn`` when recorded, else Tanh (SB3's default for
actor-critic policies); ``--activation`` overrides.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch

from sim2real.deploy.export.errors import ExportError
from sim2real.deploy.export.network import (
    _build_mlp,
    _linear_stack,
    check_finite_tensors,
    check_head,
)
from sim2real.deploy.export.recurrent import rnn_from_state_dict
from sim2real.deploy.export.sb3_activation import sb3_activation
from sim2real.deploy.export.source import recurrent_source
from sim2real.deploy.spec.policy_spec import PolicySpec

PREFIX = "lstm_actor."


def load_recurrent_ppo(
    path: Path,
    sd: Mapping[str, torch.Tensor],
    data: Mapping,
    spec: PolicySpec,
    activation: str | None,
):
    """The :class:`sim2real.deploy.export.SourcePolicy` of a RecurrentPPO ``MlpLstmPolicy`` zip.

    Args:
        path: The zip (for messages). sd: ``policy.pth`` state dict. data: The ``data`` JSON.
        spec: ``--spec``. activation: Hidden activation override.

    Raises:
        sim2real.deploy.export.ExportError: gSDE or squashed output, LSTM options that change its layout
            (``batch_first``, ``bidirectional``, ``proj_size``), malformed ``lstm_actor`` or
            actor layers, non-finite weights, sizes that do not fit the spec.
    """
    kwargs = data.get("policy_kwargs") if isinstance(data.get("policy_kwargs"), Mapping) else {}
    if data.get("use_sde") or kwargs.get("use_sde") or kwargs.get("squash_output"):
        raise ExportError(
            f"{path}: RecurrentPPO with use_sde or squash_output is not supported (the "
            "deterministic action must be the Gaussian mean)"
        )
    lstm_kwargs = (
        kwargs.get("lstm_kwargs") if isinstance(kwargs.get("lstm_kwargs"), Mapping) else {}
    )
    for key, plain in (("batch_first", False), ("bidirectional", False), ("proj_size", 0)):
        if lstm_kwargs.get(key, plain) != plain:
            raise ExportError(
                f"{path}: policy_kwargs.lstm_kwargs.{key} = {lstm_kwargs[key]!r} is not supported "
                "(a one-directional, sequence-first LSTM without projection is expected)"
            )
    weights = {k[len(PREFIX) :]: v for k, v in sd.items() if k.startswith(PREFIX)}
    check_finite_tensors(weights, f"{path}: {PREFIX.rstrip('.')}")
    rnn = rnn_from_state_dict(weights, spec.obs_dim, f"{path}: {PREFIX}", ExportError)
    if not isinstance(rnn, torch.nn.LSTM):
        raise ExportError(f"{path}: '{PREFIX}*' is not an LSTM (RecurrentPPO uses nn.LSTM)")
    if "action_net.weight" not in sd or "action_net.bias" not in sd:
        raise ExportError(
            f"{path}: RecurrentPPO policy without 'action_net' (keys: {sorted(sd)[:8]})"
        )
    layers = _linear_stack(sd, "mlp_extractor.policy_net.", path)
    layers.append((sd["action_net.weight"], sd["action_net.bias"]))
    names = ("the policy net", "the LSTM", "action_net")
    check_head(layers, rnn.hidden_size, spec.act_dim, path, names)
    act = activation or sb3_activation(data, "tanh", path)
    mlp = _build_mlp(layers, act, None, path, "RecurrentPPO actor")
    return recurrent_source(rnn, mlp, None, spec, path, "sb3-contrib RecurrentPPO")
