"""Recurrent policies for ``policy-export``: the graph with explicit state, and the RNN it is
rebuilt from.

A recurrent source (an rsl_rl ``ActorCriticRecurrent``, :mod:`sim2real.deploy.export.rsl_rl_recurrent`; a
RecurrentPPO zip, :mod:`sim2real.deploy.export.sb3_recurrent`; legged_gym's LSTM TorchScript,
:mod:`sim2real.deploy.export.torchscript_lstm`) loads into a :class:`RecurrentCore` (an ``nn.LSTM`` or
``nn.GRU`` followed by the actor MLP; :func:`rnn_from_state_dict`;
:func:`sim2real.deploy.export.source.recurrent_source` makes them a source policy).
Around it, :class:`RecurrentPolicyModule` adds the observation normalizer (if any) and the action
clip, and :func:`recurrent_signature` names the graph :class:`sim2real.deploy.policy.onnx_policy.OnnxPolicy`
runs::

    obs   float32 [batch, obs_dim]            -> action float32 [batch, act_dim]
    h_in  float32 [layers, batch, hidden]     -> h_out  float32 [layers, batch, hidden]
    c_in  float32 [layers, batch, hidden]     -> c_out  (LSTM only)

(torch's RNN state layout, batch on axis 1; the initial state is zeros.) The parity gate runs
over sequences with the state carried on both sides: :func:`sim2real.deploy.export.parity.sequence_parity`
and the closed-loop replay with a :class:`RecurrentStepper`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn


@dataclass(frozen=True)
class StateLayout:
    """The recurrent state of a core: ``kind`` 'lstm' (``h``, ``c``) or 'gru' (``h``), each
    tensor ``[layers, batch, hidden]``."""

    kind: str
    layers: int
    hidden: int

    @property
    def names(self) -> tuple[str, ...]:
        return ("h", "c") if self.kind == "lstm" else ("h",)

    def zeros(self, batch: int) -> tuple[torch.Tensor, ...]:
        """Zero state tensors (layers, batch, hidden) float32."""
        return tuple(torch.zeros(self.layers, batch, self.hidden) for _ in self.names)


class RecurrentStepper:
    """A recurrent module stepped with its state carried per env, as
    :class:`sim2real.deploy.policy.onnx_policy.OnnxPolicy` carries it: ``stepper(obs)`` (batch, obs_dim)
    -> action (batch, act_dim) numpy; a new batch size starts from zeros; ``reset(mask)`` zeroes
    envs. The torch side of a recurrent parity run, and the float32 / float64 pair of
    :mod:`sim2real.deploy.export.noise_floor`.

    Args:
        module: Called as ``module(obs, *state)`` -> ``(action, *state)``.
        layout: The state's :class:`StateLayout`; default ``module.layout``.
        dtype: Observations and state cast to it; default as they come (float32).
    """

    def __init__(
        self, module: nn.Module, layout: StateLayout | None = None, dtype: torch.dtype | None = None
    ):
        self.module, self.dtype = module, dtype
        self.layout = module.layout if layout is None else layout
        self.state: tuple[torch.Tensor, ...] = ()
        self.batch = -1

    def reset(self, envs: np.ndarray | None = None) -> None:
        """Zero the state of the envs in the boolean mask ``envs`` (default all)."""
        index = slice(None) if envs is None else torch.from_numpy(np.asarray(envs, dtype=bool))
        for t in self.state:
            t[:, index, :] = 0.0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if obs.shape[0] != self.batch:
            self.batch, self.state = obs.shape[0], self._cast(self.layout.zeros(obs.shape[0]))
        with torch.no_grad():
            action, *state = self.module(*self._cast((torch.from_numpy(obs),)), *self.state)
        self.state = tuple(state)
        return action.numpy()

    def _cast(self, tensors: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, ...]:
        return tensors if self.dtype is None else tuple(t.to(self.dtype) for t in tensors)


class RecurrentCore(nn.Module):
    """``rnn`` (``nn.LSTM`` / ``nn.GRU``, sequence-first) then ``mlp``: normalized observation and
    state -> raw action and new state."""

    def __init__(self, rnn: nn.LSTM | nn.GRU, mlp: nn.Module):
        super().__init__()
        self.rnn, self.mlp = rnn, mlp
        kind = "lstm" if isinstance(rnn, nn.LSTM) else "gru"
        self.layout = StateLayout(kind, rnn.num_layers, rnn.hidden_size)


class RecurrentPolicyModule(nn.Module):
    """normalizer -> rnn -> mlp -> action clip, with explicit state.

    ``forward(obs, h)`` (GRU) or ``forward(obs, h, c)`` (LSTM): obs (batch, obs_dim), state
    tensors (layers, batch, hidden); returns ``(action, h_out)`` or ``(action, h_out, c_out)``.
    """

    def __init__(self, core: RecurrentCore, normalizer: nn.Module | None, clip: float):
        super().__init__()
        self.normalizer = normalizer if normalizer is not None else nn.Identity()
        self.rnn, self.mlp = core.rnn, core.mlp
        self.layout = core.layout
        self.clip = float(clip)

    def forward(self, obs: torch.Tensor, h: torch.Tensor, c: torch.Tensor | None = None):
        x = self.normalizer(obs).unsqueeze(0)
        if self.layout.kind == "lstm":
            y, (h, c) = self.rnn(x, (h, c))
            action = torch.clamp(self.mlp(y.squeeze(0)), -self.clip, self.clip)
            return action, h, c
        y, h = self.rnn(x, h)
        return torch.clamp(self.mlp(y.squeeze(0)), -self.clip, self.clip), h


def recurrent_signature(
    module: RecurrentPolicyModule, obs_dim: int
) -> tuple[tuple, list[str], list[str], dict]:
    """The graph's signature for the TorchScript-based exporter (:func:`sim2real.deploy.export.to_onnx`):
    inputs ``obs``, ``h_in`` (and ``c_in``), outputs ``action``, ``h_out`` (and ``c_out``),
    dynamic batch (axis 0 of ``obs`` and ``action``, axis 1 of the state).

    Returns:
        ``(example inputs, input names, output names, dynamic axes)``; the example has a batch
        of 2.
    """
    lay = module.layout
    example = (torch.zeros(2, obs_dim), *lay.zeros(2))
    ins = ["obs", *(f"{n}_in" for n in lay.names)]
    outs = ["action", *(f"{n}_out" for n in lay.names)]
    axes = {"obs": {0: "batch"}, "action": {0: "batch"}}
    axes.update({name: {1: "batch"} for name in ins[1:] + outs[1:]})
    return example, ins, outs, axes


def rnn_from_state_dict(
    weights: dict[str, torch.Tensor], input_size: int, where: str, error
) -> nn.LSTM | nn.GRU:
    """Rebuild a one-directional, sequence-first ``nn.LSTM`` or ``nn.GRU`` from its parameters.

    Args:
        weights: ``weight_ih_l<k>``, ``weight_hh_l<k>`` (and ``bias_ih_l<k>``, ``bias_hh_l<k>``,
            all or none), prefix removed. input_size: Expected input features (the spec's
            observation size). where: Named in messages (file and prefix). error: The exception
            class to raise.

    The kind comes from ``weight_hh_l0``: (4 hidden, hidden) is an LSTM, (3 hidden, hidden) a GRU.

    Raises:
        error: other parameter names (bidirectional ``_reverse``, projections), missing or
            malformed matrices, a kind neither LSTM nor GRU, another input size.
    """
    import re

    for name in weights:
        if not re.fullmatch(r"(weight|bias)_(ih|hh)_l\d+", name):
            raise error(
                f"{where}{name}: unsupported recurrent parameter (a one-directional LSTM or GRU "
                "without projection is expected)"
            )
    hh, ih = weights.get("weight_hh_l0"), weights.get("weight_ih_l0")
    if hh is None or ih is None or hh.ndim != 2 or ih.ndim != 2:
        raise error(f"{where}weight_ih_l0 / weight_hh_l0: missing or not matrices")
    hidden = int(hh.shape[1])
    gates = int(hh.shape[0]) // hidden if hidden else 0
    if gates not in (3, 4) or gates * hidden != hh.shape[0]:
        raise error(
            f"{where}weight_hh_l0 has shape {tuple(hh.shape)}: neither an LSTM (4 hidden, "
            "hidden) nor a GRU (3 hidden, hidden)"
        )
    if ih.shape[1] != input_size:
        raise error(
            f"{where}: wrong input size: the recurrent layer takes {ih.shape[1]} inputs, the "
            f"spec's observation has {input_size}"
        )
    layers = len([k for k in weights if k.startswith("weight_ih_l")])
    bias = any(k.startswith("bias_") for k in weights)
    cls = nn.LSTM if gates == 4 else nn.GRU
    rnn = cls(input_size=input_size, hidden_size=hidden, num_layers=layers, bias=bias)
    try:
        rnn.load_state_dict({k: v.to(torch.float32) for k, v in weights.items()})
    except RuntimeError as exc:
        first = str(exc).strip().splitlines()[0]
        raise error(f"{where}*: the parameters do not form a {cls.__name__}: {first}") from None
    return rnn.eval()
