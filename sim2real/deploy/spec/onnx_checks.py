"""Checks of an ONNX file before anything runs it: a readable model (:func:`read_model`), external
data that stays in the model's folder, and finite weights (:func:`check_finite_weights`).

Each raises :class:`PolicyLoadError` naming the file (and the tensor).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np
import onnx
from onnx import TensorProto, numpy_helper

from sim2real.robots.errors import Sim2RealError

_FLOAT_TYPES = (
    TensorProto.FLOAT,
    TensorProto.DOUBLE,
    TensorProto.FLOAT16,
    TensorProto.BFLOAT16,
)


class PolicyLoadError(Sim2RealError, ValueError):
    """An ONNX policy cannot be used on this robot; the message names the file and the problem."""


def _iter_graph_tensors(graph: onnx.GraphProto, where: str) -> Iterator[tuple[str, TensorProto]]:
    """Every tensor stored in a graph (initializers, sparse initializers, constant attributes),
    subgraphs included, with a readable name."""
    for t in graph.initializer:
        yield f"{where}initializer '{t.name}'", t
    for s in graph.sparse_initializer:
        yield f"{where}sparse initializer '{s.values.name}'", s.values
        yield f"{where}sparse initializer '{s.values.name}' (indices)", s.indices
    for node in graph.node:
        for attr in node.attribute:
            label = f"{where}node '{node.name or node.op_type}' attribute '{attr.name}'"
            if attr.HasField("t"):
                yield label, attr.t
            for t in attr.tensors:
                yield label, t
            if attr.HasField("sparse_tensor"):
                yield label, attr.sparse_tensor.values
            if attr.HasField("g"):
                yield from _iter_graph_tensors(attr.g, f"{label} subgraph: ")
            for g in attr.graphs:
                yield from _iter_graph_tensors(g, f"{label} subgraph: ")


def _iter_model_tensors(model: onnx.ModelProto) -> Iterator[tuple[str, TensorProto]]:
    yield from _iter_graph_tensors(model.graph, "")
    for f in model.functions:
        for node in f.node:
            for attr in node.attribute:
                if attr.HasField("t"):
                    yield f"function '{f.name}' node '{node.name}'", attr.t


def _is_absolute(location: str) -> bool:
    return (
        PurePosixPath(location).is_absolute()
        or PureWindowsPath(location).is_absolute()
        or bool(PureWindowsPath(location).drive)
        or location.startswith(("\\", "/"))
    )


def check_external_data(model: onnx.ModelProto, path: Path) -> bool:
    """Refuse external-data references that leave the model's folder.

    Returns:
        True if the model has external-data tensors (all of them safe).

    Raises:
        PolicyLoadError: a location that is empty, absolute, resolves outside ``path``'s folder
            (through ``..`` or a symbolic link) or names a missing file.
    """
    folder = path.parent.resolve()
    found = False
    for label, t in _iter_model_tensors(model):
        if t.data_location != TensorProto.EXTERNAL and not len(t.external_data):
            continue
        found = True
        entries = {e.key: e.value for e in t.external_data}
        location = entries.get("location", "")
        if not location:
            raise PolicyLoadError(f"{path}: {label} is stored externally without a location")
        if _is_absolute(location):
            raise PolicyLoadError(
                f"{path}: {label} points to external data at an absolute path ('{location}'); "
                "only files inside the model's folder are accepted"
            )
        target = (folder / location).resolve()
        if not target.is_relative_to(folder):
            raise PolicyLoadError(
                f"{path}: {label} points to external data outside the model's folder "
                f"('{location}' resolves to {target})"
            )
        if not target.is_file():
            raise PolicyLoadError(f"{path}: {label}: external data file '{location}' is missing")
    return found


#: Operators whose tensor inputs are weights: a NaN or inf there is a broken file, whatever the
#: observation. Non-finite constants elsewhere (attention masks, ``Where`` fills, ``-inf`` of a
#: max-pool) are by design; the model is judged by its answers (the load probe) instead.
WEIGHT_OPS = frozenset(
    {
        "MatMul",
        "Gemm",
        "Conv",
        "ConvTranspose",
        "MatMulInteger",
        "ConvInteger",
        "LSTM",
        "GRU",
        "RNN",
    }
)
#: Operators a weight may pass through on its way to a weight operator.
_WEIGHT_PASS_THROUGH = frozenset(
    {
        "Identity",
        "Transpose",
        "Cast",
        "Reshape",
        "Squeeze",
        "Unsqueeze",
        "Flatten",
        "DequantizeLinear",
    }
)


def _all_nodes(model: onnx.ModelProto) -> Iterator[onnx.NodeProto]:
    """Every node of the model: graph, subgraphs (If/Loop/Scan bodies), functions."""

    def walk(graph: onnx.GraphProto) -> Iterator[onnx.NodeProto]:
        for node in graph.node:
            yield node
            for attr in node.attribute:
                if attr.HasField("g"):
                    yield from walk(attr.g)
                for g in attr.graphs:
                    yield from walk(g)

    yield from walk(model.graph)
    for f in model.functions:
        yield from f.node


def _stored_tensors(model: onnx.ModelProto) -> Iterator[tuple[str, str, TensorProto]]:
    """(label, value name, tensor) of every initializer, sparse initializer and ``Constant``."""

    def walk(graph: onnx.GraphProto, where: str) -> Iterator[tuple[str, str, TensorProto]]:
        for t in graph.initializer:
            yield f"{where}initializer '{t.name}'", t.name, t
        for sp in graph.sparse_initializer:
            yield f"{where}sparse initializer '{sp.values.name}'", sp.values.name, sp.values
        for node in graph.node:
            for attr in node.attribute:
                if node.op_type == "Constant" and node.output and attr.HasField("t"):
                    label = f"{where}constant '{node.output[0]}' (node '{node.name or 'Constant'}')"
                    yield label, node.output[0], attr.t
                if node.op_type == "Constant" and node.output and attr.HasField("sparse_tensor"):
                    label = f"{where}constant '{node.output[0]}' (node '{node.name or 'Constant'}')"
                    yield label, node.output[0], attr.sparse_tensor.values
                label = (
                    f"{where}node '{node.name or node.op_type}' attribute '{attr.name}' subgraph: "
                )
                if attr.HasField("g"):
                    yield from walk(attr.g, label)
                for g in attr.graphs:
                    yield from walk(g, label)

    yield from walk(model.graph, "")
    for f in model.functions:
        for node in f.node:
            if node.op_type == "Constant" and node.output:
                for attr in node.attribute:
                    if attr.HasField("t"):
                        yield (
                            f"function '{f.name}' constant '{node.output[0]}'",
                            node.output[0],
                            attr.t,
                        )


def check_finite_weights(model: onnx.ModelProto, path: Path) -> None:
    """Refuse NaN or inf in the weights: initializers and constants that feed one of
    :data:`WEIGHT_OPS` (directly, or through a reshape, transpose, cast or dequantization).
    Other non-finite constants are accepted (masks and fills are -inf or NaN by design).

    Raises:
        PolicyLoadError: naming the first offending tensor and the operator it feeds.
    """
    consumers: dict[str, list[onnx.NodeProto]] = {}
    for node in _all_nodes(model):
        for name in node.input:
            consumers.setdefault(name, []).append(node)

    def weight_op(name: str, depth: int = 0) -> str | None:
        for node in consumers.get(name, ()):
            if node.op_type in WEIGHT_OPS:
                return node.op_type
            if node.op_type in _WEIGHT_PASS_THROUGH and node.input[0] == name and depth < 16:
                for out in node.output:
                    found = weight_op(out, depth + 1)
                    if found:
                        return found
        return None

    for label, name, t in _stored_tensors(model):
        if t.data_type not in _FLOAT_TYPES:
            continue
        op = weight_op(name)
        if op is None:
            continue
        try:
            arr = numpy_helper.to_array(t)
        except Exception as exc:  # noqa: BLE001 - malformed tensor content
            raise PolicyLoadError(f"{path}: {label}: unreadable tensor data: {exc}") from None
        bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
        if bad:
            raise PolicyLoadError(
                f"{path}: {label} holds {bad} non-finite value(s) (NaN or inf) and feeds a {op} "
                "(a weight); refusing the model"
            )


def read_model(path: Path) -> onnx.ModelProto:
    """The ONNX model of ``path``, its external data not loaded yet.

    Raises:
        PolicyLoadError: a missing, empty, unreadable or graphless file (a torch file is told to
            be exported first).
    """
    if not path.is_file():
        raise PolicyLoadError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise PolicyLoadError(f"{path}: the file is empty")
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # noqa: BLE001 - protobuf DecodeError and friends
        with open(path, "rb") as f:
            head = f.read(4)
        if head.startswith(b"PK\x03\x04") or head[:1] == b"\x80":  # zip or pickle
            raise PolicyLoadError(
                f"{path}: not an ONNX file but a zip archive or pickle (a torch checkpoint, "
                "TorchScript or Stable-Baselines3 file?); the runtime runs ONNX: export it "
                f"first with `policy-export {path}`"
            ) from None
        raise PolicyLoadError(
            f"{path}: not a valid ONNX file (truncated or corrupt?): {exc}"
        ) from None
    if not len(model.graph.node) or not len(model.graph.output):
        raise PolicyLoadError(f"{path}: the ONNX model has no graph (truncated or corrupt?)")
    return model
