"""The checks every source loader runs on the network it read, and the MLP rebuilt from a state
dict: finite tensors (:func:`check_finite_tensors`), a spec given for a format that carries none
(:func:`_require_spec`), the network's answer to the spec's observation (:func:`_probe`), and the
Linear layers of an ``nn.Sequential`` (:func:`_linear_stack`) as an
:class:`~sim2real.deploy.policy.mlp_checkpoint.MLPActor` (:func:`_build_mlp`).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from sim2real.deploy.export.errors import ExportError, _first_line
from sim2real.deploy.policy.mlp_checkpoint import MLPActor
from sim2real.deploy.policy.torch_file import first_non_finite
from sim2real.deploy.spec.policy_spec import PolicySpec


def check_finite_tensors(tensors: Mapping[str, Any], where: str) -> None:
    """Raise ExportError if a floating tensor of ``tensors`` (name -> value) holds NaN or inf
    (:func:`~sim2real.deploy.policy.torch_file.first_non_finite`); ``where`` names the source."""
    found = first_non_finite(tensors)
    if found is not None:
        name, bad, _ = found
        raise ExportError(f"{where}: tensor '{name}' holds {bad} non-finite value(s) (NaN or inf)")


def _first_in_features(net: nn.Module) -> int | None:
    for _, p in net.named_parameters():
        if p.ndim == 2:
            return int(p.shape[1])
    return None


def _probe(net: nn.Module, spec: PolicySpec, path: Path) -> None:
    """Run the network on zeros (2, obs_dim): it must accept the spec's observation and return
    a float tensor (2, act_dim)."""
    first = _first_in_features(net)
    if first is not None and first != spec.obs_dim:
        raise ExportError(
            f"{path}: wrong input size: the network takes {first} inputs, the spec's observation "
            f"has {spec.obs_dim}"
        )
    try:
        with torch.no_grad():
            y = net(torch.zeros(2, spec.obs_dim))
    except Exception as exc:  # noqa: BLE001 - arbitrary user modules
        raise ExportError(
            f"{path}: the network fails on an observation of shape (batch, {spec.obs_dim}) "
            f"(wrong input size?): {_first_line(exc)}"
        ) from None
    if not isinstance(y, torch.Tensor):
        raise ExportError(
            f"{path}: the network returns {type(y).__name__}, expected one tensor "
            f"(batch, {spec.act_dim})"
        )
    if tuple(y.shape) != (2, spec.act_dim) or not y.is_floating_point():
        raise ExportError(
            f"{path}: wrong output size: the network returns {y.dtype} {tuple(y.shape)} for a "
            f"batch of 2, the spec's action needs (2, {spec.act_dim})"
        )


def _require_spec(spec: PolicySpec | None, path: Path, what: str) -> PolicySpec:
    if spec is None:
        raise ExportError(
            f"{path}: a {what} carries no PolicySpec; pass its spec with --spec FILE.json "
            "(PolicySpec.to_json())"
        )
    return spec


def _linear_stack(
    sd: Mapping[str, torch.Tensor], prefix: str, path: Path
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The (weight, bias) pairs of an ``nn.Sequential`` of Linear layers and activations stored
    under ``prefix`` (``prefix0.weight``, ``prefix2.weight``, ...), in order."""
    keys = [k for k in sd if k.startswith(prefix)]
    index: dict[int, dict[str, torch.Tensor]] = {}
    for k in keys:
        m = re.fullmatch(re.escape(prefix) + r"(\d+)\.(weight|bias)", k)
        if not m:
            raise ExportError(
                f"{path}: unsupported layer '{k}' (only Linear layers and activations)"
            )
        index.setdefault(int(m.group(1)), {})[m.group(2)] = sd[k]
    layers = []
    for i in sorted(index):
        w, b = index[i].get("weight"), index[i].get("bias")
        if w is None or b is None or w.ndim != 2 or b.ndim != 1 or b.shape[0] != w.shape[0]:
            raise ExportError(
                f"{path}: '{prefix}{i}' is not a Linear layer with bias "
                f"(weight {None if w is None else tuple(w.shape)}, "
                f"bias {None if b is None else tuple(b.shape)})"
            )
        layers.append((w, b))
    return layers


def _build_mlp(
    layers: list[tuple[torch.Tensor, torch.Tensor]],
    activation: str,
    output: str | None,
    path: Path,
    where: str,
) -> MLPActor:
    for i, (w, b) in enumerate(layers):
        check_finite_tensors(
            {f"{where} layer {i} weight": w, f"{where} layer {i} bias": b}, str(path)
        )
    try:
        return MLPActor.from_linear_layers(layers, activation, output).eval()
    except ValueError as exc:
        raise ExportError(f"{path}: {where}: {exc}") from None


def rsl_rl_actor_layers(
    msd: Mapping[str, torch.Tensor], path: Path, missing: str
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The (weight, bias) pairs of an rsl_rl actor, the ``actor.<i>`` Linear layers of the
    checkpoint's ``model_state_dict`` ``msd`` (its other keys ignored), in order.

    Raises:
        ExportError: no such layer (``missing`` begins the message: "... has no"), or a layer
            that is not Linear with bias.
    """
    actor = {k: v for k, v in msd.items() if re.fullmatch(r"actor\.\d+\.(weight|bias)", k)}
    if not actor:
        raise ExportError(f"{path}: {missing} 'actor.<i>.weight' layers (keys: {sorted(msd)[:8]})")
    return _linear_stack(actor, "actor.", path)


def check_head(
    layers: list[tuple[torch.Tensor, torch.Tensor]],
    inputs: int,
    outputs: int,
    path: Path,
    names: tuple[str, str, str],
    note: str = "",
) -> None:
    """Check that the Linear stack ``layers`` (weight (out, in), bias) after a recurrent memory
    takes the memory's ``inputs`` values and returns the spec's ``outputs`` (its action size).
    ``names``: (the stack, the memory, the stack's last layer) as the messages name them;
    ``note`` ends the output-size message.

    Raises:
        ExportError: either size differs.
    """
    net, memory, last = names
    if layers[0][0].shape[1] != inputs:
        raise ExportError(
            f"{path}: {net} takes {layers[0][0].shape[1]} inputs, {memory} gives {inputs}"
        )
    if layers[-1][0].shape[0] != outputs:
        raise ExportError(
            f"{path}: wrong output size: {last} returns {layers[-1][0].shape[0]} values, the "
            f"spec's action has {outputs}{note}"
        )
