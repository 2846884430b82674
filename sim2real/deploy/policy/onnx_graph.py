"""The graph an :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy` runs, checked against its spec.

The observation input is the only data input, else the one named ``obs``; every other input
``<name>_in`` with an output ``<name>_out`` is recurrent state (:class:`StateTensor`: float32
``[layers, batch, hidden]``, torch's ``nn.LSTM`` / ``nn.GRU`` layout, the same shape both ways;
an initializer of the input's name is its declared initial state). Godot RL Agents' dummy
``state_ins`` -> ``state_outs`` (:data:`GODOT_STATE`) and the spec's ``constant_inputs`` are fed
constants. The action output is the only other output, else the one named ``action`` or
``actions``. Anything else raises :class:`~sim2real.deploy.spec.onnx_checks.PolicyLoadError` naming the
file, the tensor and what would make it load.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import PolicySpec

#: Godot RL Agents' dummy state: input and output names (fed zeros; the output is ignored).
GODOT_STATE = ("state_ins", "state_outs")


def _dims(value_info: onnx.ValueInfoProto) -> list[int | str | None]:
    shape = value_info.type.tensor_type.shape
    out: list[int | str | None] = []
    for d in shape.dim:
        if d.HasField("dim_value"):
            out.append(int(d.dim_value))
        elif d.HasField("dim_param"):
            out.append(d.dim_param)
        else:
            out.append(None)
    return out


@dataclass(frozen=True)
class StateTensor:
    """One recurrent state of a graph: input ``input`` fed by output ``output`` on the next call.

    Attributes:
        input, output: Graph input and output names. layers, hidden: Fixed sizes of the
            ``[layers, batch, hidden]`` float32 tensor. initial: The declared initial state
            ``(layers, 1 or batch, hidden)`` float32, or None (zeros).
    """

    input: str
    output: str
    layers: int
    hidden: int
    initial: np.ndarray | None = None


def _state_output_name(name: str) -> str | None:
    """``h_in`` -> ``h_out``: the output a state input pairs with (None: not a state name)."""
    return name[: -len("_in")] + "_out" if name.endswith("_in") and len(name) > 3 else None


def check_graph(
    model: onnx.ModelProto, path: Path, spec: PolicySpec
) -> tuple[str, str, int, tuple[StateTensor, ...], dict[str, tuple]]:
    """The graph's signature against ``spec``: ``(observation input, action output, fixed batch
    size or 0, recurrent states, constant inputs {name: (shape, dtype, value)})``.

    Raises:
        PolicyLoadError: an unknown extra input, no or several action outputs, non-float32 data,
            sizes that differ from the spec, a malformed recurrent state or constant input.
    """
    graph = model.graph
    init = {t.name: t for t in graph.initializer}
    init_names = set(init) | {s.values.name for s in graph.sparse_initializer}
    inputs = [i for i in graph.input if i.name not in init_names]
    if not inputs:
        raise PolicyLoadError(f"{path}: the graph has no data input")
    names = [i.name for i in inputs]
    image_names = {b.input for b in spec.images}
    _check_images(path, spec, inputs)
    vector = [i for i in inputs if i.name not in image_names] or inputs
    vnames = [i.name for i in vector]
    inp = vector[0] if len(vector) == 1 else vector[vnames.index("obs") if "obs" in vnames else 0]
    outputs = {o.name: o for o in graph.output}
    pairs: list[tuple[onnx.ValueInfoProto, onnx.ValueInfoProto]] = []
    unknown = []
    constants: dict[str, onnx.ValueInfoProto] = {}
    godot = inp.name == "obs" and GODOT_STATE[0] in names and GODOT_STATE[1] in outputs
    for i in graph.input:
        if (
            i.name == inp.name
            or i.name in image_names
            or (i.name in init_names and _state_output_name(i.name) not in outputs)
        ):
            continue
        out_name = _state_output_name(i.name)
        if i.name in spec.constant_inputs or (godot and i.name == GODOT_STATE[0]):
            constants[i.name] = i
        elif out_name in outputs:
            pairs.append((i, outputs[out_name]))
        else:
            unknown.append(i)
    if unknown:
        desc = ", ".join(f"'{i.name}' {_dims(i)}" for i in unknown)
        raise PolicyLoadError(
            f"{path}: the graph has extra input(s) {desc} besides the observation "
            f"'{inp.name}'. To load it: if the input is recurrent state, name it "
            "'<name>_in' with an output '<name>_out' of the same shape [layers, batch, "
            "hidden] (batch on axis 1); if it takes a constant (a mask, a dummy), add "
            '"constant_inputs": {"' + unknown[0].name + '": VALUE} to the --spec file; if it '
            "is a depth camera's image [batch, frames, rows, columns] or a colour camera's "
            '[batch, frames, 3, rows, columns], an "images" entry naming it (docs/cameras.md); '
            "or export the policy with policy-export"
        )
    constant_specs = {
        name: _constant_shape(path, vi, spec.constant_inputs.get(name, 0.0))
        for name, vi in constants.items()
    }
    missing = sorted(set(spec.constant_inputs) - set(constants))
    if missing:
        raise PolicyLoadError(
            f"{path}: the spec's constant_inputs name {missing}, which the graph does not have "
            f"as inputs (its inputs: {names})"
        )
    state_outs = {o.name for _, o in pairs} | ({GODOT_STATE[1]} if godot else set())
    out = _action_output(path, graph, state_outs)
    for kind, vi, size, what in (
        ("input", inp, spec.obs_dim, "observation"),
        ("output", out, spec.action.outputs, "action"),
    ):
        _check_size(path, spec, kind, vi, size, what)
    in_dims = _dims(inp)
    fixed = in_dims[0] if in_dims and isinstance(in_dims[0], int) and in_dims[0] > 0 else 0
    states = tuple(_check_state(path, i, o, fixed, init.get(i.name)) for i, o in pairs)
    return inp.name, out.name, fixed, states, constant_specs


def _check_images(path: Path, spec: PolicySpec, inputs) -> None:
    """Each of the spec's image blocks is a float32 graph input of its shape (``input_shape``
    after the batch: a depth block's (frames, rows, columns), an RGB block's (frames, 3, rows,
    columns) or (frames, rows, columns, 3)) (``PolicyLoadError`` naming the input, its shape
    and the spec's where not)."""
    by_name = {i.name: i for i in inputs}
    for k, block in enumerate(spec.images):
        vi = by_name.get(block.input)
        if vi is None:
            raise PolicyLoadError(
                f"{path}: the spec's images[{k}].input '{block.input}' is not a graph input "
                f"(its inputs: {list(by_name)})"
            )
        dims = _dims(vi)
        fixed = [(d, w) for d, w in zip(dims[1:], block.input_shape, strict=False)]
        if (
            vi.type.tensor_type.elem_type != TensorProto.FLOAT
            or len(dims) != 1 + len(block.input_shape)
            or any(isinstance(d, int) and d != want for d, want in fixed)
        ):
            raise PolicyLoadError(
                f"{path}: graph input '{block.input}' is "
                f"{TensorProto.DataType.Name(vi.type.tensor_type.elem_type).lower()} {dims}; the "
                f"spec's images[{k}] expects float {block.layout_names} = "
                f"[batch, {', '.join(str(d) for d in block.input_shape)}]"
            )


def _action_output(path: Path, graph, state_outs: set[str]):
    """The graph's one action output (besides the recurrent state outputs), or the one named
    ``action`` or ``actions`` (``PolicyLoadError`` where neither)."""
    actions = [o for o in graph.output if o.name not in state_outs]
    if len(actions) == 1:
        return actions[0]
    named = [o for o in actions if o.name in ("action", "actions")]
    if len(named) != 1:
        raise PolicyLoadError(
            f"{path}: the graph has outputs {[o.name for o in graph.output]}; expected one "
            "action output (besides recurrent state outputs '<name>_out'), or one named "
            "'action' or 'actions'"
        )
    return named[0]


def _check_size(path: Path, spec: PolicySpec, kind: str, vi, size: int, what: str) -> None:
    """The observation input or the action output: float32, ``[batch, size]`` as the spec
    says (``PolicyLoadError`` naming the spec's entries where not)."""
    _check_float32(path, kind, vi)
    dims = _dims(vi)
    if vi.type.tensor_type.HasField("shape") and len(dims) != 2:
        raise PolicyLoadError(
            f"{path}: graph {kind} '{vi.name}' has shape {dims}, expected [batch, {size}]"
        )
    if dims and isinstance(dims[-1], int) and dims[-1] != size:
        parts = (
            " + ".join(f"{b.name} {b.size}" for b in spec.observation_blocks)
            if kind == "input"
            else f"{spec.action.mode} x {spec.action.size} joints"
        )
        if kind == "input" and spec.history is not None:
            parts = f"{parts}, over a history of {spec.history.length} ticks"
        raise PolicyLoadError(
            f"{path}: graph {kind} '{vi.name}' has size {dims[-1]}, the spec's {what} "
            f"has {size} ({parts}; shape {dims}): the spec must describe the model's "
            f"{what} entry for entry"
        )


def _constant_shape(
    path: Path, vi: onnx.ValueInfoProto, value: float
) -> tuple[tuple[int | None, ...], np.dtype, float]:
    """(shape with None for the batch axis, dtype, value) of a constant input."""
    elem = vi.type.tensor_type.elem_type
    try:
        dtype = np.dtype(helper.tensor_dtype_to_np_dtype(elem))
    except Exception:  # noqa: BLE001 - unknown element type
        dtype = None
    if dtype is None or dtype.kind not in "fiub":
        raise PolicyLoadError(
            f"{path}: graph input '{vi.name}' has type "
            f"{TensorProto.DataType.Name(elem)}; a constant input must be numeric"
        )
    shape: list[int | None] = []
    for axis, d in enumerate(_dims(vi)):
        if isinstance(d, int) and d > 0:
            shape.append(d)
        elif axis == 0:
            shape.append(None)  # the batch
        else:
            raise PolicyLoadError(
                f"{path}: graph input '{vi.name}' has shape {_dims(vi)}: a constant input "
                "needs fixed sizes on every axis but the batch (axis 0)"
            )
    return tuple(shape), dtype, value


def _check_float32(path: Path, kind: str, vi: onnx.ValueInfoProto) -> None:
    if vi.type.tensor_type.elem_type != TensorProto.FLOAT:
        raise PolicyLoadError(
            f"{path}: graph {kind} '{vi.name}' is of type "
            f"{TensorProto.DataType.Name(vi.type.tensor_type.elem_type)}, expected float32"
        )


def _check_state(
    path: Path,
    vi_in: onnx.ValueInfoProto,
    vi_out: onnx.ValueInfoProto,
    fixed_batch: int,
    initializer: TensorProto | None,
) -> StateTensor:
    """One recurrent state pair: float32, ``[layers, batch, hidden]``, same shape both ways."""
    _check_float32(path, "input", vi_in)
    _check_float32(path, "output", vi_out)
    din, dout = _dims(vi_in), _dims(vi_out)
    layout = "a recurrent state is [layers, batch, hidden] (torch nn.LSTM/nn.GRU, batch on axis 1)"
    if len(din) != 3:
        raise PolicyLoadError(
            f"{path}: recurrent state input '{vi_in.name}' has shape {din}: no batch axis; {layout}"
        )
    batch = din[1]
    if isinstance(batch, int) and (fixed_batch == 0 or batch != fixed_batch):
        raise PolicyLoadError(
            f"{path}: recurrent state input '{vi_in.name}' has shape {din}: no batch axis "
            f"(axis 1 is fixed at {batch}, the observation's batch is "
            f"{fixed_batch or 'dynamic'}); {layout}"
        )
    if len(dout) != 3 or any(
        isinstance(a, int) and isinstance(b, int) and a != b for a, b in zip(din, dout, strict=True)
    ):
        raise PolicyLoadError(
            f"{path}: recurrent state output '{vi_out.name}' has shape {dout}, its input "
            f"'{vi_in.name}' has {din}; they must be equal"
        )
    layers, hidden = din[0], din[2]
    if not (isinstance(layers, int) and isinstance(hidden, int) and layers > 0 and hidden > 0):
        raise PolicyLoadError(
            f"{path}: recurrent state input '{vi_in.name}' has shape {din}; the layers and "
            "hidden sizes (axes 0 and 2) must be fixed"
        )
    initial = None
    if initializer is not None:
        initial = numpy_helper.to_array(initializer).astype(np.float32)
        if initial.ndim != 3 or initial.shape[0::2] != (layers, hidden):
            raise PolicyLoadError(
                f"{path}: the initial state '{vi_in.name}' has shape {list(initial.shape)}, "
                f"expected [{layers}, 1, {hidden}]"
            )
    return StateTensor(vi_in.name, vi_out.name, layers, hidden, initial)
