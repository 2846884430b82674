"""The activation function a Stable-Baselines3 zip records, shared by its feed-forward and
recurrent readers."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

from sim2real.deploy.export.errors import ExportError


def sb3_activation(data: Mapping, default: str, path: Path) -> str:
    """The actor's activation a Stable-Baselines3 zip records (``data``'s
    ``policy_kwargs.activation_fn``): ``'tanh'``, ``'relu'`` or ``'elu'``; ``default`` when it
    records none (SB3's own defaults: Tanh for PPO, ReLU for SAC).

    Raises:
        sim2real.deploy.export.ExportError: another activation (``--activation`` overrides it).
    """
    kwargs = data.get("policy_kwargs") or {}
    text = kwargs.get("activation_fn") if isinstance(kwargs, Mapping) else None
    if not text:
        return default
    m = re.search(r"\.(\w+)'>", str(text))
    name = m.group(1) if m else str(text)
    mapping = {"Tanh": "tanh", "ReLU": "relu", "ELU": "elu"}
    if name not in mapping:
        raise ExportError(
            f"{path}: policy_kwargs.activation_fn = {name} is not supported (Tanh, ReLU, ELU); "
            "pass --activation to override"
        )
    return mapping[name]
