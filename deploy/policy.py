"""OnnxPolicy: load an exported policy, verify it against the robot, run it batch-first.

The runtime's only view of a policy. It needs neither torch nor the training code: an ONNX file
and the robot description are enough.

Loading refuses (with :class:`PolicyLoadError`, naming the file and the problem):
    - a missing, empty, truncated or corrupt ONNX file, or one the ONNX checker rejects;
    - external-data tensors whose ``location`` is absolute or resolves outside the model's folder
      (symbolic links included), or whose file is missing; checked before anything is read;
    - initializers or constants holding NaN or inf;
    - a graph input other than the observation and recurrent state inputs (the message names the
      input and its shape, and what would make it load), several action outputs none of which is
      named ``action`` or ``actions``, non-float32 input or output, or an input/output size that
      differs from the spec;
    - a recurrent state input without a batch axis (not ``[layers, batch, hidden]``), or whose
      state output has another shape than the input (declared, or when run);
    - a spec that does not match the robot (``PolicySpec.check_robot``: robot name, joint names and
      order, control rate, description hash) or a model without our metadata when no spec is given;
    - a spec passed in that contradicts the one stored in the file;
    - a policy whose output for the zero observation is not finite.

Metadata written by ``policy-export`` (``model.metadata_props``, read with plain ONNX Runtime as
``InferenceSession(path).get_modelmeta().custom_metadata_map``): ``policy_spec`` (PolicySpec
JSON, with ``baked`` and ``parity`` filled), ``source_sha256``, ``tool_versions`` (JSON),
``parity`` (JSON), ``source_format``, ``exporter``. A foreign ONNX file without them is accepted
when ``spec`` is given: its single data input and its output are discovered from the graph.

Recurrent policies (LSTM ``h``, ``c``; GRU ``h``): every graph input ``<name>_in`` besides the
observation that has a graph output ``<name>_out`` is recurrent state, shaped ``[layers, batch,
hidden]`` float32 (torch's ``nn.LSTM`` / ``nn.GRU`` layout, batch on axis 1; ``layers`` and
``hidden`` fixed), with the output of the same shape. This is the layout ``policy-export`` writes
(``obs``, ``h_in``, ``c_in`` -> ``action``, ``h_out``, ``c_out``) and rsl_rl's own exporter
(``obs``, ``h_in``, ``c_in`` -> ``actions``, ``h_out``, ``c_out``). The policy keeps the state of
every env, feeds ``<name>_out`` back as ``<name>_in`` on the next call, and :meth:`OnnxPolicy.reset`
sets it to its initial value: zeros, or the file's declared initial state (an initializer of the
same name as the state input, ``[layers, 1 or batch, hidden]``). The observation input is the only
input when there is one, else the one named ``obs``. Isaac Lab's ``obs -> actions`` is a
feed-forward policy like ours.

Inference runs single-threaded (``intra_op_num_threads = inter_op_num_threads = 1``, sequential
execution: fastest for small MLPs at batch 1) through an IOBinding bound once to preallocated
numpy buffers; it is rebound only when the batch size changes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
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
        states: The recurrent states (:class:`StateTensor`; empty for a feed-forward policy).
        recurrent: Whether there are any. session: The ``onnxruntime.InferenceSession``.

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
        self.input_name, self.output_name, self._fixed_batch, self.states = self._check_graph(
            model, path
        )
        self.recurrent = bool(self.states)

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
        #: recurrent: (state input buffer, state output buffer) per state, (layers, batch, hidden)
        self._state_pairs: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
        probe_batch = self._fixed_batch or 1
        if self.recurrent:
            self._check_state_shapes(path, probe_batch)
        try:
            probe = self(np.zeros((probe_batch, self.obs_dim), np.float32))
        except Exception as exc:  # noqa: BLE001
            raise PolicyLoadError(
                f"{path}: running the model on a zero observation of shape "
                f"({probe_batch}, {self.obs_dim}) failed: {exc}"
            ) from None
        if not np.isfinite(probe).all():
            raise PolicyLoadError(f"{path}: the action for the zero observation is not finite")
        self.reset()  # the probe advanced the state

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

    def _check_graph(
        self, model: onnx.ModelProto, path: Path
    ) -> tuple[str, str, int, tuple[StateTensor, ...]]:
        graph = model.graph
        init = {t.name: t for t in graph.initializer}
        init_names = set(init) | {s.values.name for s in graph.sparse_initializer}
        inputs = [i for i in graph.input if i.name not in init_names]
        if not inputs:
            raise PolicyLoadError(f"{path}: the graph has no data input")
        names = [i.name for i in inputs]
        inp = inputs[0] if len(inputs) == 1 else inputs[names.index("obs") if "obs" in names else 0]
        outputs = {o.name: o for o in graph.output}
        pairs: list[tuple[onnx.ValueInfoProto, onnx.ValueInfoProto]] = []
        unknown = []
        for i in graph.input:
            if i.name == inp.name or (
                i.name in init_names and _state_output_name(i.name) not in outputs
            ):
                continue
            out_name = _state_output_name(i.name)
            if out_name in outputs:
                pairs.append((i, outputs[out_name]))
            else:
                unknown.append(i)
        if unknown:
            desc = ", ".join(f"'{i.name}' {_dims(i)}" for i in unknown)
            raise PolicyLoadError(
                f"{path}: the graph has extra input(s) {desc} besides the observation "
                f"'{inp.name}'; only recurrent state is accepted as a further input: rename a "
                "state input '<name>_in' and its output '<name>_out' (shape [layers, batch, "
                "hidden], batch on axis 1), or export the policy with policy-export, to load it"
            )
        state_outs = {o.name for _, o in pairs}
        actions = [o for o in graph.output if o.name not in state_outs]
        if len(actions) == 1:
            out = actions[0]
        else:
            named = [o for o in actions if o.name in ("action", "actions")]
            if len(named) != 1:
                raise PolicyLoadError(
                    f"{path}: the graph has outputs {[o.name for o in graph.output]}; expected one "
                    "action output (besides recurrent state outputs '<name>_out'), or one named "
                    "'action' or 'actions'"
                )
            out = named[0]
        for kind, vi, size, what in (
            ("input", inp, self.obs_dim, "observation"),
            ("output", out, self.act_dim, "action"),
        ):
            self._check_float32(path, kind, vi)
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
        states = tuple(self._check_state(path, i, o, fixed, init.get(i.name)) for i, o in pairs)
        return inp.name, out.name, fixed, states

    @staticmethod
    def _check_float32(path: Path, kind: str, vi: onnx.ValueInfoProto) -> None:
        if vi.type.tensor_type.elem_type != TensorProto.FLOAT:
            raise PolicyLoadError(
                f"{path}: graph {kind} '{vi.name}' is of type "
                f"{TensorProto.DataType.Name(vi.type.tensor_type.elem_type)}, expected float32"
            )

    def _check_state(
        self,
        path: Path,
        vi_in: onnx.ValueInfoProto,
        vi_out: onnx.ValueInfoProto,
        fixed_batch: int,
        initializer: TensorProto | None,
    ) -> StateTensor:
        """One recurrent state pair: float32, ``[layers, batch, hidden]``, same shape both ways."""
        self._check_float32(path, "input", vi_in)
        self._check_float32(path, "output", vi_out)
        din, dout = _dims(vi_in), _dims(vi_out)
        layout = (
            "a recurrent state is [layers, batch, hidden] (torch nn.LSTM/nn.GRU, batch on axis 1)"
        )
        if len(din) != 3:
            raise PolicyLoadError(
                f"{path}: recurrent state input '{vi_in.name}' has shape {din}: no batch axis; "
                f"{layout}"
            )
        batch = din[1]
        if isinstance(batch, int) and (fixed_batch == 0 or batch != fixed_batch):
            raise PolicyLoadError(
                f"{path}: recurrent state input '{vi_in.name}' has shape {din}: no batch axis "
                f"(axis 1 is fixed at {batch}, the observation's batch is "
                f"{fixed_batch or 'dynamic'}); {layout}"
            )
        if len(dout) != 3 or any(
            isinstance(a, int) and isinstance(b, int) and a != b
            for a, b in zip(din, dout, strict=True)
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

    def _check_state_shapes(self, path: Path, batch: int) -> None:
        """Run the graph once on zeros: every state output must have its input's shape."""
        feeds = {self.input_name: np.zeros((batch, self.obs_dim), np.float32)}
        for s in self.states:
            feeds[s.input] = np.zeros((s.layers, batch, s.hidden), np.float32)
        try:
            outs = self.session.run([s.output for s in self.states], feeds)
        except Exception as exc:  # noqa: BLE001
            raise PolicyLoadError(
                f"{path}: running the model on a zero observation and zero state failed: {exc}"
            ) from None
        for s, value in zip(self.states, outs, strict=True):
            if value.shape != feeds[s.input].shape:
                raise PolicyLoadError(
                    f"{path}: recurrent state output '{s.output}' has shape {list(value.shape)}, "
                    f"its input '{s.input}' {list(feeds[s.input].shape)}; they must be equal"
                )

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
        pairs, self._state_values = [], []
        for s in self.states:
            pair = (
                np.zeros((s.layers, batch, s.hidden), np.float32),
                np.zeros((s.layers, batch, s.hidden), np.float32),
            )
            values = [ort.OrtValue.ortvalue_from_numpy(a) for a in pair]
            self._binding.bind_ortvalue_input(s.input, values[0])
            self._binding.bind_ortvalue_output(s.output, values[1])
            pairs.append(pair)
            self._state_values.append(values)  # keep the OrtValues alive with the buffers
        self._state_pairs = tuple(pairs)
        self._batch = batch
        if self.states:
            self.reset()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """The actions for a batch of observations.

        Args:
            obs: float32 (envs, obs_dim), the spec's normalized observation (other float dtypes
                are converted).

        Returns:
            float32 (envs, act_dim). The array is a preallocated buffer, overwritten by the next
            call: copy what you keep.

        A recurrent policy reads each env's state and keeps the new one for the next call; a
        change of ``envs`` starts every env from its initial state.

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
        if self._state_pairs:
            for state_in, state_out in self._state_pairs:
                np.copyto(state_in, state_out)
        return self._action

    def reset(self, envs: np.ndarray | None = None) -> None:
        """Set the recurrent state of some envs to its initial value (zeros, or the file's
        declared initial state). No-op for a feed-forward policy.

        Args:
            envs: Boolean mask (envs,) of the envs to reset; default all. A mask of another
                length than the current batch sets the batch size to its length (every env then
                starts from its initial state).

        Raises:
            ValueError: the graph has a fixed batch size and the mask's length differs.
        """
        if not self.states:
            return
        if envs is not None:
            envs = np.asarray(envs, dtype=bool).reshape(-1)
            if envs.shape[0] != self._batch:
                self._bind(envs.shape[0])
                return
        index = slice(None) if envs is None else envs
        for s, (state_in, _) in zip(self.states, self._state_pairs, strict=True):
            state_in[:, index, :] = 0.0 if s.initial is None else s.initial

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The recurrent state (copies), keyed by state input name: ``(layers, hidden)`` float32
        for env ``env``, or ``(layers, envs, hidden)`` for all. Empty for a feed-forward policy."""
        index = slice(None) if env is None else env
        return {
            s.input: state_in[:, index, :].copy()
            for s, (state_in, _) in zip(self.states, self._state_pairs, strict=True)
        }

    def load_state_dict(self, state: Mapping[str, np.ndarray], env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (for the same ``env``, or all envs).

        Raises:
            ValueError: a missing or unexpected key, or a shape that does not fit (for all envs,
                the batch is set from the arrays' axis 1 first).
        """
        expected = {s.input for s in self.states}
        if set(state) != expected:
            raise ValueError(f"policy state: expected keys {sorted(expected)}, got {sorted(state)}")
        if not self.states:
            return
        if env is None:
            batch = np.shape(next(iter(state.values())))[1:2]
            if batch and batch[0] != self._batch:
                self._bind(batch[0])
        index = slice(None) if env is None else env
        for s, (state_in, _) in zip(self.states, self._state_pairs, strict=True):
            value = np.asarray(state[s.input], dtype=np.float32)
            if value.shape != state_in[:, index, :].shape:
                raise ValueError(
                    f"policy state '{s.input}': expected shape "
                    f"{state_in[:, index, :].shape}, got {value.shape}"
                )
            state_in[:, index, :] = value

    @property
    def parity(self) -> dict[str, Any]:
        """The export's parity figures (empty for a foreign model)."""
        return dict(self.spec.parity)

    def __repr__(self) -> str:
        kind = f", state={[s.input for s in self.states]}" if self.states else ""
        return (
            f"OnnxPolicy('{self.path}', robot='{self.spec.robot}', obs_dim={self.obs_dim}, "
            f"act_dim={self.act_dim}, mode='{self.spec.action.mode}'{kind})"
        )
