"""``policy-export --inspect`` of torch files: our checkpoint, rsl_rl, TorchScript, SB3 zips.

No Python is executed from the file: torch files load with ``weights_only=True``, SB3 zips are
read as a state dict and JSON, pickled class names inside SB3's ``data`` are read from the pickle
opcodes, TorchScript is loaded with ``torch.jit.load`` (as ``policy-export`` does) and its
``forward`` (TorchScript operators, no Python) run on one probe to read its sizes
(:func:`torchscript_io`): a module may wrap its network (rl_sar's RoboMimic export reshapes a
376-entry history into the 380 its inner network reads and scatters 23 outputs into 29), so its
first and last weight matrices do not give them.
Each returns :func:`~sim2real.deploy.export.inspect_policy.inspect_file`'s dict without ``file``, or raises
:class:`~sim2real.deploy.export.errors.InspectError` naming the file and why.
"""

from __future__ import annotations

import base64
import io
import json
import pickle
import pickletools
import re
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sim2real.deploy.export.errors import InspectError
from sim2real.deploy.export.inspect_report import spec_summary, tensor_entry


def _pickle_globals(data: bytes) -> list[str]:
    """``module.name`` of every class a pickle references, read from its opcodes (not run)."""
    names, strings = [], []
    try:
        for op, arg, _ in pickletools.genops(data):
            if op.name in ("SHORT_BINUNICODE", "BINUNICODE", "UNICODE", "BINUNICODE8"):
                strings.append(str(arg))
            elif op.name == "GLOBAL":
                names.append(str(arg).replace(" ", "."))
            elif op.name == "STACK_GLOBAL" and len(strings) >= 2:
                names.append(f"{strings[-2]}.{strings[-1]}")
    except Exception:  # noqa: BLE001 - a damaged pickle: what was read so far
        pass
    return names


def _linear_layers(sd: Mapping[str, Any], prefix: str) -> list[list[int]]:
    """``[out, in]`` of every ``<prefix><i>.weight`` matrix, in index order."""
    found = []
    for k, v in sd.items():
        m = re.fullmatch(re.escape(prefix) + r"(\d+)\.weight", k)
        if m and getattr(v, "ndim", 0) == 2:
            found.append((int(m.group(1)), [int(v.shape[0]), int(v.shape[1])]))
    return [shape for _, shape in sorted(found)]


def _rnn_state(sd: Mapping[str, Any], prefix: str) -> dict[str, Any] | None:
    """Kind, layers and hidden size of an ``nn.LSTM``/``nn.GRU`` stored under ``prefix``."""
    hh, ih = sd.get(f"{prefix}weight_hh_l0"), sd.get(f"{prefix}weight_ih_l0")
    if hh is None or ih is None or hh.ndim != 2 or ih.ndim != 2:
        return None
    hidden = int(hh.shape[1])
    kind = {4: "lstm", 3: "gru"}.get(int(hh.shape[0]) // max(hidden, 1), "unknown")
    layers = len([k for k in sd if k.startswith(f"{prefix}weight_ih_l")])
    return {"kind": kind, "layers": layers, "hidden": hidden, "input": int(ih.shape[1])}


def _state_io(rnn: dict[str, Any]) -> list[dict[str, Any]]:
    names = ("h", "c") if rnn["kind"] == "lstm" else ("h",)
    shape = [rnn["layers"], "batch", rnn["hidden"]]
    return [
        {"input": f"{n}_in", "output": f"{n}_out", "shape": shape, "dtype": "float32"}
        for n in names
    ]


def inspect_sb3(path: Path) -> dict[str, Any]:
    import torch

    try:
        with zipfile.ZipFile(path) as zf:
            data_text, policy_bytes = zf.read("data"), zf.read("policy.pth")
            version = (
                zf.read("_stable_baselines3_version").decode(errors="replace").strip()
                if "_stable_baselines3_version" in zf.namelist()
                else None
            )
    except (zipfile.BadZipFile, KeyError, OSError, EOFError) as exc:
        raise InspectError(f"{path}: damaged Stable-Baselines3 archive: {exc}") from None
    try:
        data = json.loads(data_text)
        sd = torch.load(io.BytesIO(policy_bytes), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001
        from sim2real.deploy.policy.torch_file import load_failure_cause

        raise InspectError(
            f"{path}: unreadable Stable-Baselines3 entries ('data' JSON, 'policy.pth'): "
            f"{load_failure_cause(exc)}"
        ) from None
    if not isinstance(data, Mapping) or not isinstance(sd, Mapping):
        raise InspectError(f"{path}: 'data' is not a JSON object or 'policy.pth' not a state dict")
    policy_class = _sb3_policy_class(data.get("policy_class"))
    obs_space, act_space = _sb3_space(data, "observation_space"), _sb3_space(data, "action_space")
    if any(k.startswith("lstm_actor.") for k in sd):
        algo, actor = "sb3-contrib RecurrentPPO", "mlp_extractor.policy_net."
    elif "actor.mu.weight" in sd:
        algo, actor = "Stable-Baselines3 SAC", "actor.latent_pi."
    elif "action_net.weight" in sd:
        algo, actor = "Stable-Baselines3 PPO (or A2C)", "mlp_extractor.policy_net."
    else:
        algo, actor = "Stable-Baselines3 (unknown policy)", ""
    layers = _linear_layers(sd, actor) if actor else []
    head = sd.get("actor.mu.weight", sd.get("action_net.weight"))
    if head is not None:
        layers.append([int(head.shape[0]), int(head.shape[1])])
    rnn = _rnn_state(sd, "lstm_actor.")
    obs_dim = (obs_space or {}).get("shape") or ([rnn["input"]] if rnn else None)
    act_dim = (act_space or {}).get("shape") or ([layers[-1][0]] if layers else None)
    kwargs = data.get("policy_kwargs") if isinstance(data.get("policy_kwargs"), Mapping) else {}
    return {
        "format": algo,
        "inputs": [tensor_entry("obs", ["batch", *(obs_dim or ["?"])], "float32")],
        "outputs": [tensor_entry("action", ["batch", *(act_dim or ["?"])], "float32")],
        "state": _state_io(rnn) if rnn else [],
        "metadata": {
            "policy_class": policy_class,
            "sb3_version": version,
            "num_timesteps": data.get("num_timesteps"),
            "use_sde": data.get("use_sde"),
            "policy_kwargs": {k: v for k, v in kwargs.items() if not isinstance(v, Mapping)}
            | {k: v for k, v in kwargs.items() if isinstance(v, Mapping) and ":type:" not in v},
        },
        "details": {
            "observation_space": obs_space,
            "action_space": act_space,
            "actor_layers [out, in]": layers,
            **({"lstm_actor": rnn} if rnn else {}),
        },
        "spec": None,
    }


def _sb3_policy_class(pc) -> str | None:
    """The policy class an SB3 archive's ``data`` names (its pickled ``:serialized:`` globals
    read, never unpickled), else its ``__module__``, else None."""
    if not (isinstance(pc, Mapping) and isinstance(pc.get(":serialized:"), str)):
        return None
    try:
        names = _pickle_globals(base64.b64decode(pc[":serialized:"]))
    except ValueError:
        names = []
    return names[-1] if names else pc.get("__module__")


def _sb3_space(data: Mapping, key: str) -> dict[str, Any] | None:
    """An SB3 archive's Gymnasium space ``key`` as ``{type, shape, low, high}`` (bounds cut at
    80 characters), or None."""
    s = data.get(key)
    if not isinstance(s, Mapping):
        return None
    kind = re.sub(r"^<class '(.*)'>$", r"\1", str(s.get(":type:", "")))
    out = {"type": kind.rsplit(".", 1)[-1], "shape": s.get("_shape")}
    for bound in ("low", "high"):
        if isinstance(s.get(bound), str):
            out[bound] = s[bound][:80]
    return out


def torchscript_io(net, width: int) -> tuple[int, int] | None:
    """``(obs, action)`` entries a TorchScript module's ``forward`` takes and answers, by running
    it on one ``(1, width)`` probe (``width``: its first weight matrix's input, the most it may
    read): the observation is as wide as the last probe entry the output depends on (the
    gradient of a random projection of the output, nonzero almost surely for an entry read),
    checked by running the module again on that width; the action the output's last axis.
    None: the module does not run on the probe (another input than one tensor, an error).

    A network that reads every entry (an MLP) keeps ``width``; one that slices its input
    (rl_sar's ``DanceWrapper``: 376 of a 380-wide probe) gets the slice's end."""
    import torch

    gen = torch.Generator().manual_seed(0)
    try:
        x = torch.randn(1, width, generator=gen, requires_grad=True)
        out = net(x)
        if not isinstance(out, torch.Tensor) or out.ndim < 1:
            return None
        (grad,) = torch.autograd.grad(
            out, x, torch.randn(out.shape, generator=gen), allow_unused=True
        )
        action = int(out.shape[-1])
        if grad is None:
            return width, action
        used = torch.nonzero(grad.reshape(-1)).reshape(-1)
        obs = int(used[-1]) + 1 if used.numel() else width
        if obs != width:
            with torch.no_grad():
                again = net(torch.zeros(1, obs))
            if tuple(again.shape) != tuple(out.shape):
                return width, action
        return obs, action
    except Exception:  # noqa: BLE001 - TorchScript raises its own error types
        return None


def inspect_torchscript(path: Path) -> dict[str, Any]:

    from sim2real.deploy.export.torchscript import load_torchscript
    from sim2real.deploy.export.torchscript_lstm import LAYOUT, STATE_BUFFERS, is_legged_gym_lstm

    net = load_torchscript(path, InspectError)
    buffers = {k: list(v.shape) for k, v in net.named_buffers()}
    children = {n: getattr(c, "original_name", type(c).__name__) for n, c in net.named_children()}
    try:
        schema = str(net.forward.schema)
    except Exception:  # noqa: BLE001
        schema = "?"
    params = [(k, v) for k, v in net.named_parameters() if v.ndim == 2]
    first = params[0][1] if params else None
    last = params[-1][1] if params else None
    if "memory" in children and "actor" in children:  # the LSTM layout: memory, then actor
        first = next((v for k, v in params if k.startswith("memory.")), first)
        last = next((v for k, v in reversed(params) if k.startswith("actor.")), last)
    state: list[dict[str, Any]] = []
    fmt = "TorchScript"
    details: dict[str, Any] = {"forward": schema, "submodules": children, "buffers": buffers}
    if is_legged_gym_lstm(net):
        fmt = (
            "TorchScript, legged_gym PolicyExporterLSTM layout (stateful: buffers updated in place)"
        )
        hidden = buffers.get(STATE_BUFFERS[0], [0, 0, 0])
        state = [
            {
                "input": f"{n}_in",
                "output": f"{n}_out",
                "shape": [hidden[0], "batch", hidden[-1]],
                "dtype": "float32",
                "lifted_from": f"buffer '{b}' {buffers.get(b)}",
            }
            for n, b in zip(("h", "c"), STATE_BUFFERS, strict=True)
        ]
        details["layout"] = LAYOUT
    elif buffers:
        details["note"] = "buffers present: policy-export refuses the file if forward modifies them"
    obs = int(first.shape[1]) if first is not None else "?"
    act = int(last.shape[0]) if last is not None else "?"
    if first is not None and not state:  # a stateless forward: read by running it once
        io = torchscript_io(net, obs)
        if io is not None and io != (obs, act):
            details["network layers (first in, last out)"] = [obs, act]
            obs, act = io
    return {
        "format": fmt,
        "inputs": [tensor_entry("obs", ["batch", obs], "float32")],
        "outputs": [tensor_entry("action", ["batch", act], "float32")],
        "state": state,
        "metadata": {},
        "details": details,
        "spec": None,
    }


def inspect_torch(path: Path) -> dict[str, Any]:
    from sim2real.deploy.policy.torch_file import (
        load_weights_only,
        unreadable_torch_file,
        unsafe_globals_in,
    )

    try:
        obj = load_weights_only(path)
    except pickle.UnpicklingError as exc:
        name = unsafe_globals_in(exc)
        if name is None:
            raise InspectError(unreadable_torch_file(path, exc)) from None
        return {
            "format": "pickled Python object (not unpickled)",
            "inputs": [],
            "outputs": [],
            "state": [],
            "metadata": {"class": name},
            "details": {
                "note": "policy-export unpickles it only with --trust-pickle (unpickling runs code)"
            },
            "spec": None,
        }
    except Exception as exc:  # noqa: BLE001 - torch raises many types for damaged files
        raise InspectError(unreadable_torch_file(path, exc)) from None
    if isinstance(obj, Mapping) and "format" in obj:
        return _our_checkpoint(path, obj)
    if isinstance(obj, Mapping) and isinstance(obj.get("model_state_dict"), Mapping):
        return _rsl_rl_checkpoint(obj)
    what = (
        f"a dict with keys {sorted(map(str, obj))[:8]}"
        if isinstance(obj, Mapping)
        else type(obj).__name__
    )
    return {
        "format": f"torch file of unrecognized content ({what})",
        "inputs": [],
        "outputs": [],
        "state": [],
        "metadata": {},
        "details": {},
        "spec": None,
    }


def _our_checkpoint(path: Path, obj: Mapping) -> dict[str, Any]:
    """The inspection of this toolkit's own checkpoint (a ``format`` field)."""
    arch = obj.get("architecture") if isinstance(obj.get("architecture"), Mapping) else {}
    norm = obj.get("obs_normalizer")
    info = obj.get("info") if isinstance(obj.get("info"), Mapping) else {}
    return {
        "format": f"our checkpoint ({obj.get('format')} v{obj.get('format_version')})",
        "inputs": [tensor_entry("obs", ["batch", arch.get("obs_dim", "?")], "float32")],
        "outputs": [tensor_entry("action", ["batch", arch.get("act_dim", "?")], "float32")],
        "state": [],
        "metadata": {k: v for k, v in info.items() if isinstance(v, str | int | float)},
        "details": {
            "architecture": dict(arch),
            "obs_normalizer": None
            if norm is None
            else {k: v for k, v in norm.items() if isinstance(v, int | float)},
        },
        "spec": spec_summary(obj["spec"], f"{path}: field 'spec'")
        if isinstance(obj.get("spec"), str)
        else None,
    }


def _rsl_rl_checkpoint(obj: Mapping) -> dict[str, Any]:
    """The inspection of an rsl_rl checkpoint (``model_state_dict``; recurrent or not)."""
    msd = obj["model_state_dict"]
    layers = _linear_layers(msd, "actor.")
    rnn = _rnn_state(msd, "memory_a.rnn.")
    norm = None
    if "actor_obs_normalizer._mean" in msd:
        norm = "actor_obs_normalizer (rsl_rl 3.x)"
    elif isinstance(obj.get("obs_norm_state_dict"), Mapping):
        norm = "obs_norm_state_dict (rsl_rl 1.x/2.x)"
    obs_dim = rnn["input"] if rnn else (layers[0][1] if layers else "?")
    return {
        "format": "rsl_rl checkpoint" + (" (ActorCriticRecurrent)" if rnn else ""),
        "inputs": [tensor_entry("obs", ["batch", obs_dim], "float32")],
        "outputs": [tensor_entry("action", ["batch", layers[-1][0] if layers else "?"], "float32")],
        "state": _state_io(rnn) if rnn else [],
        "metadata": {k: v for k, v in obj.items() if isinstance(v, str | int | float | bool)},
        "details": {
            "actor_layers [out, in]": layers,
            **({"memory_a.rnn": rnn} if rnn else {}),
            "observation_normalizer": norm,
            "fields": sorted(map(str, obj)),
        },
        "spec": None,
    }
