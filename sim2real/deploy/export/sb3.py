"""Stable-Baselines3 PPO and SAC zips (``MlpPolicy``), read without unpickling: ``policy.pth`` (a
state dict, ``weights_only``) and the ``data`` JSON. The deterministic actor is rebuilt from the
state-dict shapes (:func:`sb3_actor`); the spaces must fit the spec (the action space the Box
[-1, 1]). A RecurrentPPO zip (``lstm_actor.*``) goes to :mod:`sim2real.deploy.export.sb3_recurrent`.
"""

from __future__ import annotations

import io
import json
import re
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from sim2real.deploy.export.errors import ExportError
from sim2real.deploy.export.network import _build_mlp, _linear_stack, _probe, _require_spec
from sim2real.deploy.export.sb3_activation import sb3_activation
from sim2real.deploy.export.source import SourcePolicy
from sim2real.deploy.policy.mlp_checkpoint import MLPActor
from sim2real.deploy.policy.torch_file import (
    load_failure_cause,
    load_weights_only,
    unsafe_globals_in,
)
from sim2real.deploy.spec.policy_spec import PolicySpec


def _parse_bounds(text: Any) -> np.ndarray | None:
    if not isinstance(text, str):
        return None
    nums = re.findall(r"[-+]?(?:inf|nan|\d+\.?\d*(?:e[-+]?\d+)?|\.\d+(?:e[-+]?\d+)?)", text)
    return np.array([float(x) for x in nums]) if nums else None


def _check_sb3_spaces(data: Mapping, spec: PolicySpec, path: Path) -> None:
    obs_space, act_space = data.get("observation_space"), data.get("action_space")
    for name, space, size in (
        ("observation_space", obs_space, spec.obs_dim),
        ("action_space", act_space, spec.act_dim),
    ):
        if not isinstance(space, Mapping):
            continue
        kind = str(space.get(":type:", ""))
        if kind and "Box" not in kind:
            raise ExportError(f"{path}: {name} is {kind}; only a flat Box is supported")
        shape = space.get("_shape")
        if shape is not None and list(shape) != [size]:
            what = "observation" if name == "observation_space" else "action"
            raise ExportError(
                f"{path}: {name} has shape {list(shape)}, the spec's {what} has ({size},)"
            )
    if isinstance(act_space, Mapping):
        low, high = _parse_bounds(act_space.get("low")), _parse_bounds(act_space.get("high"))
        if (
            low is not None
            and high is not None
            and (not np.allclose(low, -1.0) or not np.allclose(high, 1.0))
        ):
            raise ExportError(
                f"{path}: action_space bounds are low={low.tolist()}, high={high.tolist()}; SB3 "
                "clips or rescales actions to them, but the spec maps [-1, 1]: train on a "
                "Box(-1, 1) action space and let the spec scale it"
            )


def _load_sb3(path: Path, spec: PolicySpec | None, activation: str | None) -> SourcePolicy:
    spec = _require_spec(spec, path, "Stable-Baselines3 model")
    try:
        with zipfile.ZipFile(path) as zf:
            data_text = zf.read("data")
            policy_bytes = zf.read("policy.pth")
    except (zipfile.BadZipFile, KeyError, OSError, EOFError) as exc:
        raise ExportError(f"{path}: damaged Stable-Baselines3 archive: {exc}") from None
    try:
        data = json.loads(data_text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ExportError(f"{path}: entry 'data' is not valid JSON: {exc}") from None
    if not isinstance(data, Mapping):
        raise ExportError(f"{path}: entry 'data' is not a JSON object")
    try:
        sd = load_weights_only(io.BytesIO(policy_bytes))
    except Exception as exc:  # noqa: BLE001
        cause = "it holds pickled objects" if unsafe_globals_in(exc) else load_failure_cause(exc)
        raise ExportError(
            f"{path}: entry 'policy.pth' is not a readable state dict ({cause}); the archive is "
            "damaged or was not written by Stable-Baselines3"
        ) from None
    if not isinstance(sd, Mapping) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise ExportError(f"{path}: entry 'policy.pth' is not a state dict of tensors")
    extractor = [k for k in sd if re.match(r"(actor\.)?(pi_|vf_)?features_extractor\.", k)]
    if extractor:
        raise ExportError(
            f"{path}: the policy has a features extractor with parameters ({extractor[0]}, ...); "
            "only MlpPolicy (flat Box observations) is supported"
        )
    _check_sb3_spaces(data, spec, path)
    kwargs = data.get("policy_kwargs") if isinstance(data.get("policy_kwargs"), Mapping) else {}
    if any(k.startswith("lstm_actor.") for k in sd):
        from sim2real.deploy.export.sb3_recurrent import load_recurrent_ppo

        return load_recurrent_ppo(path, sd, data, spec, activation)
    sac = "actor.mu.weight" in sd
    if sac and data.get("use_sde"):
        raise ExportError(f"{path}: SAC with use_sde=True is not supported")
    act = activation or sb3_activation(data, "relu" if sac else "tanh", path)
    net, fmt = sb3_actor(sd, act, bool(kwargs.get("squash_output")), path)
    _probe(net, spec, path)
    return SourcePolicy(net=net, spec=spec, source_format=fmt)


def sb3_actor(
    sd: Mapping[str, torch.Tensor],
    activation: str,
    squash_output: bool = False,
    path: str | Path = "Stable-Baselines3 policy",
) -> tuple[MLPActor, str]:
    """The deterministic actor of a Stable-Baselines3 ``MlpPolicy`` state dict as an MLPActor.

    PPO: the Gaussian mean, ``mlp_extractor.policy_net`` then ``action_net`` (``tanh`` output when
    the policy squashes); SAC: ``tanh(mu(latent_pi(obs)))``.

    Args:
        sd: ``policy.state_dict()`` of an SB3 PPO or SAC model.
        activation: Hidden activation ('tanh', 'relu', 'elu'); SB3's defaults are tanh for PPO and
            relu for SAC. squash_output: PPO's ``squash_output``. path: Named in errors.

    Returns:
        ``(actor, source_format)`` with ``source_format`` 'sb3-ppo' or 'sb3-sac'.

    Raises:
        ExportError: neither a PPO nor a SAC actor, or layers that are not Linear with bias.
    """
    path = Path(path)
    if "actor.mu.weight" in sd:
        layers = _linear_stack(sd, "actor.latent_pi.", path)
        layers.append((sd["actor.mu.weight"], sd["actor.mu.bias"]))
        return _build_mlp(layers, activation, "tanh", path, "SAC actor"), "sb3-sac"
    if "action_net.weight" in sd:
        layers = _linear_stack(sd, "mlp_extractor.policy_net.", path)
        layers.append((sd["action_net.weight"], sd["action_net.bias"]))
        output = "tanh" if squash_output else None
        return _build_mlp(layers, activation, output, path, "PPO actor"), "sb3-ppo"
    raise ExportError(
        f"{path}: not a PPO (action_net) or SAC (actor.mu) policy; keys: {sorted(sd)[:8]}"
    )
