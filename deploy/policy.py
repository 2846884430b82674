"""OnnxPolicy: load an exported policy, verify it against the robot, run it batch-first.

The runtime's only view of a policy. It needs neither torch nor the training code: an ONNX file
and the robot description are enough.

Loading refuses (with :class:`PolicyLoadError`, naming the file and the problem):
    - a missing, empty, truncated or corrupt ONNX file, or one the ONNX checker rejects;
    - external-data tensors whose ``location`` is absolute or resolves outside the model's folder
      (symbolic links included), or whose file is missing; checked before anything is read;
    - initializers or constants holding NaN or inf;
    - a graph with more than one data input (for example the state inputs of a recurrent policy:
      not supported, the message names the extra inputs), several outputs none of which is named
      ``action``, non-float32 input or output, or an input/output size that differs from the spec;
    - a spec that does not match the robot (``PolicySpec.check_robot``: robot name, joint names and
      order, control rate, description hash) or a model without our metadata when no spec is given;
    - a spec passed in that contradicts the one stored in the file;
    - a policy whose output for the zero observation is not finite.

Metadata written by ``policy-export`` (``model.metadata_props``, read with plain ONNX Runtime as
``InferenceSession(path).get_modelmeta().custom_metadata_map``): ``policy_spec`` (PolicySpec
JSON, with ``baked`` and ``parity`` filled), ``source_sha256``, ``tool_versions`` (JSON),
``parity`` (JSON), ``source_format``, ``exporter``. A foreign ONNX file without them is accepted
when ``spec`` is given: its single data input and its output are discovered from the graph.

Inference runs single-threaded (``intra_op_num_threads = inter_op_num_threads = 1``, sequential
execution: fastest for small MLPs at batch 1) through an IOBinding bound once to preallocated
numpy buffers; it is rebound only when the batch size changes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, numpy_helper

from deploy.spec import PolicySpec, SpecError
from robots import Robot

#: Metadata keys written by the exporter.
METADATA_SPEC = "policy_spec"
_FLOAT_TYPES = (
    TensorProto.FLOAT,
    TensorProto.DOUBLE,
    TensorProto.FLOAT16,
    TensorProto.BFLOAT16,
)


class PolicyLoadError(ValueError):
    """An ONNX policy cannot be used on this robot; the message names the file and the problem."""


def spec_differences(a: PolicySpec, b: PolicySpec) -> list[str]:
    """Top-level fields in which two specs differ, ignoring ``baked`` and ``parity``."""
    da, db = json.loads(a.to_json()), json.loads(b.to_json())
    keys = sorted((set(da) | set(db)) - {"baked", "parity"})
    return [k for k in keys if da.get(k) != db.get(k)]


def read_spec(spec: PolicySpec | str | os.PathLike) -> PolicySpec:
    """A PolicySpec, or one read from a JSON file.

    Raises:
        SpecError: unreadable file or invalid spec (the message names the file).
    """
    if isinstance(spec, PolicySpec):
        return spec
    path = Path(spec)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SpecError(f"{path}: cannot read the spec file: {exc.strerror or exc}") from None
    return PolicySpec.from_json(text, source=str(path))


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


def check_finite_weights(model: onnx.ModelProto, path: Path) -> None:
    """Refuse initializers and constants that hold NaN or inf.

    Raises:
        PolicyLoadError: naming the first offending tensor.
    """
    for label, t in _iter_model_tensors(model):
        if t.data_type not in _FLOAT_TYPES:
            continue
        try:
            arr = numpy_helper.to_array(t)
        except Exception as exc:  # noqa: BLE001 - malformed tensor content
            raise PolicyLoadError(f"{path}: {label}: unreadable tensor data: {exc}") from None
        bad = int(arr.size - np.count_nonzero(np.isfinite(arr)))
        if bad:
            raise PolicyLoadError(
                f"{path}: {label} holds {bad} non-finite value(s) (NaN or inf); refusing the model"
            )


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


class OnnxPolicy:
    """An exported policy, verified against a robot, run with ONNX Runtime.

    Args:
        path: The ``.onnx`` file.
        robot: The robot it will drive; the spec is checked against it.
        spec: Optional PolicySpec (or a spec JSON file). Required for a foreign ONNX file without
            ``policy_spec`` metadata; otherwise it must agree with the stored spec (``baked`` and
            ``parity`` aside).
        check_hash: Also compare the robot description hash (default True).

    Attributes:
        path: The file. spec: The PolicySpec in force. metadata: The file's custom metadata
            (``str -> str``; ``policy_spec``, ``parity``, ``tool_versions`` hold JSON).
        input_name, output_name: Graph input and output used. obs_dim, act_dim: Sizes.
        session: The ``onnxruntime.InferenceSession``.

    Raises:
        PolicyLoadError: see the module docstring.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        robot: Robot,
        spec: PolicySpec | str | os.PathLike | None = None,
        check_hash: bool = True,
    ):
        self.path = path = Path(path)
        model = self._read_model(path)
        if check_external_data(model, path):
            try:
                onnx.load_external_data_for_model(model, str(path.parent))
            except Exception as exc:  # noqa: BLE001
                raise PolicyLoadError(f"{path}: cannot read external data: {exc}") from None
        try:
            onnx.checker.check_model(model)
        except Exception as exc:  # noqa: BLE001 - onnx.checker.ValidationError
            raise PolicyLoadError(f"{path}: the ONNX checker rejects the model: {exc}") from None
        check_finite_weights(model, path)
        self.metadata: dict[str, str] = {p.key: p.value for p in model.metadata_props}
        self.spec = self._resolve_spec(path, spec)
        try:
            self.spec.check_robot(robot, check_hash=check_hash)
        except SpecError as exc:
            raise PolicyLoadError(f"{path}: {exc}") from None
        self.obs_dim, self.act_dim = self.spec.obs_dim, self.spec.act_dim
        self.input_name, self.output_name, self._fixed_batch = self._check_graph(model, path)

        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        try:
            # From the validated bytes: ONNX Runtime never reads the path again.
            self.session = ort.InferenceSession(
                model.SerializeToString(), options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own exception types
            raise PolicyLoadError(f"{path}: ONNX Runtime cannot load the model: {exc}") from None
        self._binding = self.session.io_binding()
        self._batch = -1
        self._obs = np.zeros((0, self.obs_dim), np.float32)
        self._action = np.zeros((0, self.act_dim), np.float32)
        probe_batch = self._fixed_batch or 1
        try:
            probe = self(np.zeros((probe_batch, self.obs_dim), np.float32))
        except Exception as exc:  # noqa: BLE001
            raise PolicyLoadError(
                f"{path}: running the model on a zero observation of shape "
                f"({probe_batch}, {self.obs_dim}) failed: {exc}"
            ) from None
        if not np.isfinite(probe).all():
            raise PolicyLoadError(f"{path}: the action for the zero observation is not finite")

    # ------------------------------------------------------------------ loading
    @staticmethod
    def _read_model(path: Path) -> onnx.ModelProto:
        if not path.is_file():
            raise PolicyLoadError(f"{path}: no such file")
        if path.stat().st_size == 0:
            raise PolicyLoadError(f"{path}: the file is empty")
        try:
            model = onnx.load(str(path), load_external_data=False)
        except Exception as exc:  # noqa: BLE001 - protobuf DecodeError and friends
            raise PolicyLoadError(
                f"{path}: not a valid ONNX file (truncated or corrupt?): {exc}"
            ) from None
        if not len(model.graph.node) or not len(model.graph.output):
            raise PolicyLoadError(f"{path}: the ONNX model has no graph (truncated or corrupt?)")
        return model

    def _resolve_spec(self, path: Path, spec: PolicySpec | str | os.PathLike | None) -> PolicySpec:
        stored = None
        if METADATA_SPEC in self.metadata:
            try:
                stored = PolicySpec.from_json(
                    self.metadata[METADATA_SPEC], source=f"{path}: metadata '{METADATA_SPEC}'"
                )
            except SpecError as exc:
                raise PolicyLoadError(str(exc)) from None
        given = None
        if spec is not None:
            try:
                given = read_spec(spec)
            except SpecError as exc:
                raise PolicyLoadError(f"{path}: {exc}") from None
        if stored is None and given is None:
            raise PolicyLoadError(
                f"{path}: no '{METADATA_SPEC}' metadata (not written by policy-export); pass the "
                "policy's spec (spec=PolicySpec or a spec JSON file)"
            )
        if stored is not None and given is not None:
            diff = spec_differences(stored, given)
            if diff:
                raise PolicyLoadError(
                    f"{path}: the spec passed in differs from the one stored in the file in {diff}"
                )
        return stored if stored is not None else given

    def _check_graph(self, model: onnx.ModelProto, path: Path) -> tuple[str, str, int]:
        graph = model.graph
        init = {t.name for t in graph.initializer} | {
            s.values.name for s in graph.sparse_initializer
        }
        inputs = [i for i in graph.input if i.name not in init]
        if not inputs:
            raise PolicyLoadError(f"{path}: the graph has no data input")
        if len(inputs) > 1:
            names = [i.name for i in inputs]
            first = "obs" if "obs" in names else names[0]
            extra = [n for n in names if n != first]
            raise PolicyLoadError(
                f"{path}: the graph has extra inputs {extra} besides '{first}' (recurrent state?); "
                "only feed-forward policies with one observation input are supported"
            )
        inp = inputs[0]
        outputs = list(graph.output)
        if len(outputs) == 1:
            out = outputs[0]
        else:
            named = [o for o in outputs if o.name == "action"]
            if not named:
                raise PolicyLoadError(
                    f"{path}: the graph has outputs {[o.name for o in outputs]}; expected one "
                    "output or one named 'action'"
                )
            out = named[0]
        for kind, vi, size, what in (
            ("input", inp, self.obs_dim, "observation"),
            ("output", out, self.act_dim, "action"),
        ):
            if vi.type.tensor_type.elem_type != TensorProto.FLOAT:
                raise PolicyLoadError(
                    f"{path}: graph {kind} '{vi.name}' is of type "
                    f"{TensorProto.DataType.Name(vi.type.tensor_type.elem_type)}, expected float32"
                )
            dims = _dims(vi)
            if vi.type.tensor_type.HasField("shape") and len(dims) != 2:
                raise PolicyLoadError(
                    f"{path}: graph {kind} '{vi.name}' has shape {dims}, expected [batch, {size}]"
                )
            if dims and isinstance(dims[-1], int) and dims[-1] != size:
                raise PolicyLoadError(
                    f"{path}: graph {kind} '{vi.name}' has size {dims[-1]}, the spec's {what} has "
                    f"{size} (shape {dims})"
                )
        in_dims = _dims(inp)
        fixed = in_dims[0] if in_dims and isinstance(in_dims[0], int) and in_dims[0] > 0 else 0
        return inp.name, out.name, fixed

    # ------------------------------------------------------------------ inference
    def _bind(self, batch: int) -> None:
        if self._fixed_batch and batch != self._fixed_batch:
            raise ValueError(
                f"{self.path}: the graph has a fixed batch size {self._fixed_batch}, got {batch}"
            )
        self._obs = np.zeros((batch, self.obs_dim), np.float32)
        self._action = np.zeros((batch, self.act_dim), np.float32)
        self._obs_value = ort.OrtValue.ortvalue_from_numpy(self._obs)
        self._action_value = ort.OrtValue.ortvalue_from_numpy(self._action)
        self._binding.clear_binding_inputs()
        self._binding.clear_binding_outputs()
        self._binding.bind_ortvalue_input(self.input_name, self._obs_value)
        self._binding.bind_ortvalue_output(self.output_name, self._action_value)
        self._batch = batch

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """The actions for a batch of observations.

        Args:
            obs: float32 (envs, obs_dim), the spec's normalized observation (other float dtypes
                are converted).

        Returns:
            float32 (envs, act_dim). The array is a preallocated buffer, overwritten by the next
            call: copy what you keep.

        Raises:
            ValueError: ``obs`` is not shaped (envs, obs_dim), or the graph has a fixed batch size
                and ``envs`` differs.
        """
        if obs.ndim != 2 or obs.shape[1] != self.obs_dim:
            raise ValueError(
                f"obs: expected shape (envs, {self.obs_dim}), got {tuple(np.shape(obs))}"
            )
        if obs.shape[0] != self._batch:
            self._bind(obs.shape[0])
        np.copyto(self._obs, obs, casting="same_kind")
        self.session.run_with_iobinding(self._binding)
        return self._action

    @property
    def parity(self) -> dict[str, Any]:
        """The export's parity figures (empty for a foreign model)."""
        return dict(self.spec.parity)

    def __repr__(self) -> str:
        return (
            f"OnnxPolicy('{self.path}', robot='{self.spec.robot}', obs_dim={self.obs_dim}, "
            f"act_dim={self.act_dim}, mode='{self.spec.action.mode}')"
        )
