"""``policy-export --inspect FILE``: what a policy file is, without exporting or running it.

The first thing to run on a file you did not make. Formats (detected from the content, as
:func:`deploy.export.load_source` detects them, plus ONNX):

==================  ==========================================================================
format              what is reported
==================  ==========================================================================
ONNX                inputs and outputs (name, shape, dtype; initializers excluded), recurrent
                    state pairs (``<name>_in`` -> ``<name>_out``; Godot RL's ``state_ins`` ->
                    ``state_outs``), opset, producer, custom metadata, the embedded PolicySpec;
                    without one, the training stack's own contract (mjlab, holosoma metadata,
                    an Isaac Lab run folder: :mod:`deploy.spec.foreign`): what it records, how
                    its terms map, what is missing, and with ``--robot`` the PolicySpec
                    deploy-run would build
our checkpoint      architecture, normalizer, embedded PolicySpec, training info keys
TorchScript         buffers, submodules, ``forward`` signature; legged_gym's PolicyExporterLSTM
                    layout (its state buffers and the state I/O an export lifts them into)
SB3 / RecurrentPPO  algorithm (from the state-dict keys), policy class, spaces, policy_kwargs,
                    actor layers, the LSTM state of a RecurrentPPO policy
rsl_rl              actor layers, ``memory_a.rnn`` (LSTM / GRU) state, observation normalizer
pickled object      the class the pickle names (read with ``weights_only``; never unpickled)
==================  ==========================================================================

Nothing is executed from the file: torch files load with ``weights_only=True``, SB3 zips are
read as a state dict and JSON, pickled class names inside SB3's ``data`` are read from the pickle
opcodes. TorchScript is loaded with ``torch.jit.load`` (as ``policy-export`` does) but not run.

Shapes are lists; ``"batch"`` marks a dynamic batch axis of a torch source (what the export will
have), an ONNX file shows its own dimension names.
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

from robots.errors import Sim2RealError

#: Godot RL Agents' recurrent-state names (a dummy pair even for MLP policies).
GODOT_STATE = ("state_ins", "state_outs")


class InspectError(Sim2RealError, ValueError):
    """The file cannot be read as any policy format; the message names the file and why."""


# ---------------------------------------------------------------------- helpers
def _tensor(name: str, shape, dtype: str) -> dict[str, Any]:
    return {"name": name, "shape": list(shape), "dtype": dtype}


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


def _spec_summary(text: str, where: str) -> dict[str, Any]:
    """The embedded PolicySpec: its JSON, whether :class:`PolicySpec` accepts it, a summary."""
    from deploy.spec.policy_spec import PolicySpec

    try:
        raw = json.loads(text)
    except json.JSONDecodeError as exc:
        return {"valid": False, "error": f"{where}: not JSON: {exc}"}
    out: dict[str, Any] = {"json": raw, "valid": True}
    try:
        PolicySpec.from_json(text, source=where)
    except Exception as exc:  # noqa: BLE001 - SpecError and friends: reported, not raised
        out.update(valid=False, error=str(exc))
    if isinstance(raw, Mapping):
        blocks = raw.get("observation") or raw.get("observation_blocks") or []
        action = raw.get("action") if isinstance(raw.get("action"), Mapping) else {}
        out["summary"] = {
            "robot": raw.get("robot"),
            "control_rate": raw.get("control_rate"),
            "observation": [
                f"{b.get('name')}[{b.get('size')}]" for b in blocks if isinstance(b, Mapping)
            ],
            "action": f"{action.get('mode')} [{action.get('size')}], clip {action.get('clip')}",
        }
    return out


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


# ---------------------------------------------------------------------- formats
def _foreign(path: Path, model, robot) -> dict[str, Any] | None:
    """The file's foreign contract (:func:`deploy.spec.foreign.report.summary`), or None."""
    from deploy.spec import foreign
    from deploy.spec.foreign.report import summary

    facts = foreign.OnnxFacts.of(path, model)
    fmt = foreign.detect_format(facts)
    if fmt is None:
        return None
    try:
        return summary(fmt.read(facts), robot)
    except foreign.ForeignFormatError as exc:
        return {"format": fmt.NAME, "source": "the file", "error": str(exc)}


def _inspect_onnx(path: Path, robot=None) -> dict[str, Any]:
    import onnx
    from onnx import TensorProto

    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # noqa: BLE001 - protobuf DecodeError and friends
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InspectError(
            f"{path}: not a policy file: neither a torch file (zip archive or pickle) nor a "
            f"valid ONNX model (truncated or corrupt?): {first}"
        ) from None
    graph = model.graph
    if not len(graph.node) or not len(graph.output):
        raise InspectError(f"{path}: the ONNX model has no graph (truncated or corrupt?)")
    init = {t.name for t in graph.initializer} | {s.values.name for s in graph.sparse_initializer}

    def info(vi) -> dict[str, Any]:
        tt = vi.type.tensor_type
        dims = []
        for d in tt.shape.dim:
            dims.append(
                int(d.dim_value)
                if d.HasField("dim_value")
                else (d.dim_param if d.HasField("dim_param") else None)
            )
        dtype = TensorProto.DataType.Name(tt.elem_type).lower() if tt.elem_type else "?"
        return _tensor(vi.name, dims, {"float": "float32", "double": "float64"}.get(dtype, dtype))

    inputs = [info(i) for i in graph.input if i.name not in init]
    outputs = [info(o) for o in graph.output]
    out_by_name = {o["name"]: o for o in outputs}
    state = []
    for i in graph.input:
        out_name = i.name[:-3] + "_out" if i.name.endswith("_in") and len(i.name) > 3 else None
        if i.name == GODOT_STATE[0]:
            out_name = GODOT_STATE[1]
        if out_name in out_by_name:
            entry = {
                "input": i.name,
                "output": out_name,
                "shape": info(i)["shape"],
                "dtype": info(i)["dtype"],
            }
            if out_by_name[out_name]["shape"] != entry["shape"]:
                entry["output_shape"] = out_by_name[out_name]["shape"]
            if i.name in init:
                entry["declared_initial_state"] = True
            state.append(entry)
    metadata = {p.key: p.value for p in model.metadata_props}
    result: dict[str, Any] = {
        "format": "ONNX",
        "inputs": inputs,
        "outputs": outputs,
        "state": state,
        "metadata": metadata,
        "details": {
            "opsets": {(o.domain or "ai.onnx"): int(o.version) for o in model.opset_import},
            "ir_version": int(model.ir_version),
            "producer": f"{model.producer_name} {model.producer_version}".strip(),
            "nodes": len(graph.node),
            "initializers": len(graph.initializer),
        },
    }
    if "policy_spec" in metadata:
        result["spec"] = _spec_summary(metadata["policy_spec"], f"{path}: metadata 'policy_spec'")
    else:
        result["foreign"] = _foreign(path, model, robot)
    if any(s["input"] == GODOT_STATE[0] for s in state):
        result["details"]["layout"] = "Godot RL Agents (state_ins / state_outs)"
    return result


def _inspect_sb3(path: Path) -> dict[str, Any]:
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
        from deploy.policy.mlp_checkpoint import load_failure_cause

        raise InspectError(
            f"{path}: unreadable Stable-Baselines3 entries ('data' JSON, 'policy.pth'): "
            f"{load_failure_cause(exc)}"
        ) from None
    if not isinstance(data, Mapping) or not isinstance(sd, Mapping):
        raise InspectError(f"{path}: 'data' is not a JSON object or 'policy.pth' not a state dict")
    policy_class = None
    pc = data.get("policy_class")
    if isinstance(pc, Mapping) and isinstance(pc.get(":serialized:"), str):
        try:
            names = _pickle_globals(base64.b64decode(pc[":serialized:"]))
        except ValueError:
            names = []
        policy_class = names[-1] if names else pc.get("__module__")

    def space(key: str) -> dict[str, Any] | None:
        s = data.get(key)
        if not isinstance(s, Mapping):
            return None
        kind = re.sub(r"^<class '(.*)'>$", r"\1", str(s.get(":type:", "")))
        out = {"type": kind.rsplit(".", 1)[-1], "shape": s.get("_shape")}
        for bound in ("low", "high"):
            if isinstance(s.get(bound), str):
                out[bound] = s[bound][:80]
        return out

    obs_space, act_space = space("observation_space"), space("action_space")
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
        "inputs": [_tensor("obs", ["batch", *(obs_dim or ["?"])], "float32")],
        "outputs": [_tensor("action", ["batch", *(act_dim or ["?"])], "float32")],
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


def _inspect_torchscript(path: Path) -> dict[str, Any]:

    from deploy.export.torchscript import load_torchscript
    from deploy.export.torchscript_lstm import LAYOUT, STATE_BUFFERS, is_legged_gym_lstm

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
    return {
        "format": fmt,
        "inputs": [
            _tensor("obs", ["batch", int(first.shape[1]) if first is not None else "?"], "float32")
        ],
        "outputs": [
            _tensor("action", ["batch", int(last.shape[0]) if last is not None else "?"], "float32")
        ],
        "state": state,
        "metadata": {},
        "details": details,
        "spec": None,
    }


def _inspect_torch(path: Path) -> dict[str, Any]:
    from deploy.policy.mlp_checkpoint import (
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
        arch = obj.get("architecture") if isinstance(obj.get("architecture"), Mapping) else {}
        norm = obj.get("obs_normalizer")
        info = obj.get("info") if isinstance(obj.get("info"), Mapping) else {}
        return {
            "format": f"our checkpoint ({obj.get('format')} v{obj.get('format_version')})",
            "inputs": [_tensor("obs", ["batch", arch.get("obs_dim", "?")], "float32")],
            "outputs": [_tensor("action", ["batch", arch.get("act_dim", "?")], "float32")],
            "state": [],
            "metadata": {k: v for k, v in info.items() if isinstance(v, str | int | float)},
            "details": {
                "architecture": dict(arch),
                "obs_normalizer": None
                if norm is None
                else {k: v for k, v in norm.items() if isinstance(v, int | float)},
            },
            "spec": _spec_summary(obj["spec"], f"{path}: field 'spec'")
            if isinstance(obj.get("spec"), str)
            else None,
        }
    if isinstance(obj, Mapping) and isinstance(obj.get("model_state_dict"), Mapping):
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
            "inputs": [_tensor("obs", ["batch", obs_dim], "float32")],
            "outputs": [_tensor("action", ["batch", layers[-1][0] if layers else "?"], "float32")],
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


def inspect_file(path: str | Path, robot=None) -> dict[str, Any]:
    """What ``path`` is, as plain data.

    Args:
        path: The policy file. robot: Optional :class:`robots.Robot`: an ONNX file's foreign
            contract is also mapped onto it.

    Returns:
        ``{"file", "format", "inputs", "outputs", "state", "metadata", "details", "spec"}``:
        ``inputs``/``outputs`` lists of ``{"name", "shape", "dtype"}``; ``state`` a list of
        ``{"input", "output", "shape", "dtype", ...}`` (empty: not recurrent); ``spec`` None or
        ``{"json", "valid", "summary"[, "error"]}``; an ONNX file without our spec also has
        ``foreign``: None or :func:`deploy.spec.foreign.report.summary`'s dict (``{"format",
        "source", "error"}`` when the contract cannot be read).

    Raises:
        InspectError: missing, empty, unreadable or unrecognized file (naming it and why).
    """
    path = Path(path)
    if not path.exists():
        raise InspectError(f"{path}: no such file")
    if not path.is_file():
        raise InspectError(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise InspectError(f"{path}: the file is empty")
    with open(path, "rb") as f:
        head = f.read(4)
    if zipfile.is_zipfile(path):
        try:
            with zipfile.ZipFile(path) as zf:
                names = zf.namelist()
        except (zipfile.BadZipFile, OSError) as exc:
            raise InspectError(f"{path}: damaged zip archive: {exc}") from None
        if "policy.pth" in names and "data" in names:
            result = _inspect_sb3(path)
        elif any(n.endswith("constants.pkl") or "/code/" in n for n in names):
            result = _inspect_torchscript(path)
        elif any(n.endswith("data.pkl") for n in names):
            result = _inspect_torch(path)
        else:
            raise InspectError(
                f"{path}: a zip archive that is no torch checkpoint, TorchScript module nor "
                f"Stable-Baselines3 model (entries: {names[:6]})"
            )
    elif head[:1] == b"\x80" or head.startswith(b"PK\x03\x04"):  # a pickle, or a cut zip
        result = _inspect_torch(path)
    else:
        result = _inspect_onnx(path, robot)  # protobuf has no magic number: try it
    return {"file": str(path), **result}


def _shape(shape: list) -> str:
    return "[" + ", ".join(str(d) for d in shape) + "]"


def format_report(info: Mapping[str, Any]) -> str:
    """:func:`inspect_file`'s result as text for a terminal."""
    lines = [f"{info['file']}: {info['format']}"]
    for key in ("inputs", "outputs"):
        if info.get(key):
            lines.append(f"  {key}:")
            lines += [
                f"    {t['name']:<12} {t['dtype']:<8} {_shape(t['shape'])}" for t in info[key]
            ]
    if info.get("state"):
        lines.append("  recurrent state:")
        for s in info["state"]:
            extra = ""
            if "output_shape" in s:
                extra += f"  (output shape {_shape(s['output_shape'])} differs!)"
            if s.get("declared_initial_state"):
                extra += "  (declared initial state)"
            if "lifted_from" in s:
                extra += f"  (from {s['lifted_from']})"
            lines.append(
                f"    {s['input']} -> {s['output']}  {s['dtype']} {_shape(s['shape'])}{extra}"
            )
    else:
        lines.append("  recurrent state: none")
    meta = {k: v for k, v in (info.get("metadata") or {}).items() if k != "policy_spec"}
    if meta:
        lines.append("  metadata:")
        for k, v in meta.items():
            text = v if isinstance(v, str) else json.dumps(v, default=str)
            lines.append(f"    {k}: {text if len(text) <= 160 else text[:157] + '...'}")
    for k, v in (info.get("details") or {}).items():
        text = v if isinstance(v, str) else json.dumps(v, default=str)
        lines.append(f"  {k}: {text}")
    spec = info.get("spec")
    if spec:
        state = "valid" if spec.get("valid") else f"INVALID: {spec.get('error')}"
        lines.append(f"  policy spec ({state}):")
        for k, v in (spec.get("summary") or {}).items():
            lines.append(f"    {k}: {', '.join(v) if isinstance(v, list) else v}")
        if spec.get("json") is not None:
            lines.append("    json: " + json.dumps(spec["json"], sort_keys=True))
    elif info.get("foreign"):
        from deploy.spec.foreign.report import format_lines

        lines += format_lines(info["foreign"])
    else:
        lines.append("  policy spec: none (give one with --spec FILE.json)")
    return "\n".join(lines)
