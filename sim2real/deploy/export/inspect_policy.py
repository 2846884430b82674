"""``policy-export --inspect FILE``: what a policy file is, without exporting or running it.

The first thing to run on a file you did not make; nothing in it is executed (torch formats:
:mod:`sim2real.deploy.export.inspect_torch`). Formats, detected from the content:

==================  ==========================================================================
format              what is reported
==================  ==========================================================================
ONNX                inputs and outputs (name, shape, dtype; initializers excluded), recurrent
                    state pairs (``<name>_in`` -> ``<name>_out``; Godot RL's ``state_ins`` ->
                    ``state_outs``), opset, producer, custom metadata, the embedded PolicySpec;
                    without one, the training stack's own contract (mjlab, holosoma metadata,
                    an Isaac Lab run folder: :mod:`sim2real.deploy.spec.foreign`): what it records, how
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
"""

from __future__ import annotations

import dataclasses
import zipfile
from pathlib import Path
from typing import Any

from sim2real.deploy.export.errors import InspectError
from sim2real.deploy.export.file_kind import check_file, zip_kind
from sim2real.deploy.export.inspect_report import spec_summary, tensor_entry
from sim2real.deploy.export.inspect_torch import inspect_sb3, inspect_torch, inspect_torchscript

#: Godot RL Agents' recurrent-state names (a dummy pair even for MLP policies).
GODOT_STATE = ("state_ins", "state_outs")


def _foreign(path: Path, model, robot) -> dict[str, Any] | None:
    """The file's foreign contract (:func:`sim2real.deploy.spec.foreign.report.summary`), or None."""
    from sim2real.deploy.spec import foreign
    from sim2real.deploy.spec.foreign.report import summary

    facts = foreign.OnnxFacts.of(path, model)
    stack = foreign.detect_stack(facts)
    if stack is None:
        return None
    try:
        return summary(foreign.read_contract(facts), robot)
    except foreign.ForeignFormatError as exc:
        return {"format": stack.name, "source": "the file", "error": str(exc)}


def _folder_foreign(path: Path, robot, result: dict[str, Any]) -> dict[str, Any] | None:
    """The contract a stack wrote beside a TorchScript file (rl_sar's ``config.yaml`` and
    ``../base.yaml``), as the export reads it (:func:`sim2real.deploy.spec.foreign.registry.
    read_folder_contract`): :func:`sim2real.deploy.spec.foreign.report.summary`'s dict, a
    ``{"format", "source", "error"}`` one when it cannot be read, or None (no contract beside
    it). The contract's observation and action sizes are the TorchScript's (``result``'s one
    input and one output, their last axis), where it has them."""
    from sim2real.deploy.spec import foreign
    from sim2real.deploy.spec.foreign.registry import read_folder_contract
    from sim2real.deploy.spec.foreign.report import summary

    try:
        contract = read_folder_contract(path)
    except foreign.ForeignFormatError as exc:
        return {"format": "the folder's", "source": str(path.parent), "error": str(exc)}
    if contract is None:
        return None

    def width(key: str) -> int | None:
        tensors = result.get(key) or []
        last = tensors[0]["shape"][-1] if len(tensors) == 1 and tensors[0]["shape"] else None
        return last if isinstance(last, int) else None

    sizes = {"obs_dim": width("inputs"), "act_dim": width("outputs")}
    contract = dataclasses.replace(
        contract, **{k: v for k, v in sizes.items() if getattr(contract, k) is None}
    )
    return summary(contract, robot)


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
        return tensor_entry(
            vi.name, dims, {"float": "float32", "double": "float64"}.get(dtype, dtype)
        )

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
    from sim2real.deploy.spec.foreign import lerobot

    if "policy_spec" in metadata:
        result["spec"] = spec_summary(metadata["policy_spec"], f"{path}: metadata 'policy_spec'")
    elif lerobot.detect_onnx(metadata):
        contract = lerobot.LeRobotContract.from_json(metadata[lerobot.METADATA_KEY], str(path))
        result["lerobot"] = lerobot.describe(contract)
        metadata[lerobot.METADATA_KEY] = "(below)"
    else:
        result["foreign"] = _foreign(path, model, robot)
    if any(s["input"] == GODOT_STATE[0] for s in state):
        result["details"]["layout"] = "Godot RL Agents (state_ins / state_outs)"
    return result


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
        ``foreign``: None or :func:`sim2real.deploy.spec.foreign.report.summary`'s dict (``{"format",
        "source", "error"}`` when the contract cannot be read); a TorchScript file too, the
        contract of its folder (rl_sar's ``config.yaml``), as ``policy-export`` reads it.

    Raises:
        InspectError: missing, empty, unreadable or unrecognized file (naming it and why).
    """
    path = Path(path)
    check_file(path, InspectError)
    with open(path, "rb") as f:
        head = f.read(4)
    if zipfile.is_zipfile(path):
        kind, names = zip_kind(path, InspectError)
        readers = {"sb3": inspect_sb3, "torchscript": inspect_torchscript, "torch": inspect_torch}
        if kind is None:
            raise InspectError(
                f"{path}: a zip archive that is no torch checkpoint, TorchScript module nor "
                f"Stable-Baselines3 model (entries: {names[:6]})"
            )
        result = readers[kind](path)
        if kind == "torchscript":  # the export reads its folder's contract: so does inspect
            result["foreign"] = _folder_foreign(path, robot, result)
    elif head[:1] == b"\x80" or head.startswith(b"PK\x03\x04"):  # a pickle, or a cut zip
        result = inspect_torch(path)
    else:
        result = _inspect_onnx(path, robot)  # protobuf has no magic number: try it
    return {"file": str(path), **result}
