"""TorchScript sources (``torch.jit.save`` archives): :func:`load_torchscript`, and a stateless
module as a :class:`~sim2real.deploy.export.source.SourcePolicy` (needs ``--spec``). legged_gym's stateful
LSTM layout is lifted into explicit state by :mod:`sim2real.deploy.export.torchscript_lstm`; any other
stateful module is refused (:func:`sim2real.deploy.export.torchscript_lstm.check_stateless`).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import torch

from sim2real.deploy.export import torchscript_lstm as lstm_ts
from sim2real.deploy.export.errors import ExportError, _first_line
from sim2real.deploy.export.network import _probe, _require_spec, check_finite_tensors
from sim2real.deploy.export.source import SourcePolicy
from sim2real.deploy.spec.policy_spec import PolicySpec


def load_torchscript(path: Path, error=None):
    """``torch.jit.load`` of ``path`` on the CPU, its warnings silenced.

    Raises:
        error (default :class:`ExportError`): the file is not a loadable TorchScript module.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return torch.jit.load(str(path), map_location="cpu")
    except Exception as exc:  # noqa: BLE001
        raise (error or ExportError)(
            f"{path}: not a loadable TorchScript module (truncated or corrupt?): {_first_line(exc)}"
        ) from None


def _load_torchscript(path: Path, spec: PolicySpec | None) -> SourcePolicy:
    spec = _require_spec(spec, path, "TorchScript module")
    net = load_torchscript(path)
    net.eval()
    if lstm_ts.is_legged_gym_lstm(net):
        return lstm_ts.load_legged_gym_lstm(path, net, spec)
    check_finite_tensors(dict(net.state_dict()), str(path))
    lstm_ts.check_stateless(net, spec.obs_dim, path, ExportError)
    _probe(net, spec, path)
    return SourcePolicy(net=net, spec=spec, source_format="torchscript", scripted=True)
