"""What a source-format loader returns: :class:`SourcePolicy` (the network, its PolicySpec, the
observation normalizer around it), and the torch modules its graph is assembled from: the
observation normalizers (:func:`normalizer_module`) and the spec's action clip
(:class:`ActionClip`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import nn

from sim2real.deploy.export.errors import ExportError
from sim2real.deploy.export.recurrent import RecurrentCore, RecurrentPolicyModule
from sim2real.deploy.policy.obs_normalizer import ObservationNormalizer
from sim2real.deploy.spec.policy_spec import PolicySpec


class Normalize(nn.Module):
    """``clamp((obs - mean) / denom, -clip, clip)``: an empirical observation normalizer."""

    def __init__(self, mean: torch.Tensor, denom: torch.Tensor, clip: float):
        super().__init__()
        self.register_buffer("mean", mean.detach().to(torch.float32).reshape(-1).clone())
        self.register_buffer("denom", denom.detach().to(torch.float32).reshape(-1).clone())
        self.clip = float(clip)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.clamp((obs - self.mean) / self.denom, -self.clip, self.clip)


class NormalizeNoClip(nn.Module):
    """``(obs - mean) / denom`` (rsl_rl's EmpiricalNormalization has no clip)."""

    def __init__(self, mean: torch.Tensor, denom: torch.Tensor):
        super().__init__()
        self.register_buffer("mean", mean.detach().to(torch.float32).reshape(-1).clone())
        self.register_buffer("denom", denom.detach().to(torch.float32).reshape(-1).clone())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return (obs - self.mean) / self.denom


class ActionClip(nn.Module):
    """``clamp(action, -clip, clip)``: the spec's action clip, baked into the graph."""

    def __init__(self, clip: float):
        super().__init__()
        self.clip = float(clip)

    def forward(self, action: torch.Tensor) -> torch.Tensor:
        return torch.clamp(action, -self.clip, self.clip)


def normalizer_module(norm: ObservationNormalizer) -> nn.Module:
    """The graph module of an :class:`ObservationNormalizer`."""
    if math.isinf(norm.clip):
        return NormalizeNoClip(norm.mean, norm.denominator())
    return Normalize(norm.mean, norm.denominator(), norm.clip)


@dataclass
class SourcePolicy:
    """A loaded source: the network (normalized observation -> raw action) and what goes around.

    Attributes:
        net: The network, eval mode, float32. spec: Its PolicySpec. source_format: The format.
        normalizer: Observation normalizer module (or None). normalizer_kind: Its description.
        scripted: ``net`` is TorchScript (the graph module is scripted too).
    """

    net: nn.Module
    spec: PolicySpec
    source_format: str
    normalizer: nn.Module | None = None
    normalizer_kind: str | None = None
    scripted: bool = False
    extra_hashes: dict[str, str] = field(default_factory=dict)
    #: recurrent sources that can run as they are (a stateful TorchScript file): a factory of
    #: the batch-1 reference of :func:`sim2real.deploy.export.parity.source_sequence_parity`
    sequence_reference: Any = None

    @property
    def recurrent(self) -> bool:
        """The net is a :class:`sim2real.deploy.export.recurrent.RecurrentCore` (explicit state I/O)."""
        return isinstance(self.net, RecurrentCore)

    def module(self) -> nn.Module:
        """normalizer -> net -> action clip, eval mode; scripted when the net is TorchScript.
        A recurrent net gives a :class:`sim2real.deploy.export.recurrent.RecurrentPolicyModule`."""
        if self.recurrent:
            return RecurrentPolicyModule(self.net, self.normalizer, self.spec.action.clip).eval()
        parts = [] if self.normalizer is None else [self.normalizer]
        seq = nn.Sequential(*parts, self.net, ActionClip(self.spec.action.clip)).eval()
        if self.scripted:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                seq = torch.jit.script(seq)
        return seq


def recurrent_source(
    rnn, mlp, normalizer, spec: PolicySpec, path, label: str, normalizer_kind=None
):
    """An RNN and its actor MLP as the export's :class:`SourcePolicy`
    (:class:`~sim2real.deploy.export.recurrent.RecurrentCore`), once its action for the zero observation
    is finite.

    Args:
        rnn: ``nn.LSTM`` or ``nn.GRU`` (batch_first False). mlp: The actor after it.
        normalizer: Observation normalizer module or None. spec: The PolicySpec.
        path: The source file (for messages). label: The source's name in ``source_format``,
            e.g. ``'rsl_rl recurrent'``. normalizer_kind: The normalizer's description.

    Raises:
        sim2real.deploy.export.ExportError: the action for the zero observation is not finite.
    """
    core = RecurrentCore(rnn, mlp).eval()
    probe = RecurrentPolicyModule(core, normalizer, spec.action.clip).eval()
    with torch.no_grad():
        action, *_ = probe(torch.zeros(2, spec.obs_dim), *core.layout.zeros(2))
    if not torch.isfinite(action).all():
        raise ExportError(f"{path}: the action for the zero observation is not finite")
    layout = core.layout
    return SourcePolicy(
        net=core,
        spec=spec,
        source_format=f"{label} ({layout.kind}, {layout.layers} layer(s), hidden {layout.hidden})",
        normalizer=normalizer,
        normalizer_kind=normalizer_kind,
    )
