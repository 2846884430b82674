"""OnnxPolicy: load an exported policy, verify it against the robot, run it batch-first.

The runtime's only view of a policy. It needs neither torch nor the training code: an ONNX file
and the robot description are enough.

Loading refuses (with :class:`PolicyLoadError`, naming the file and the problem):
    - a missing, empty, truncated or corrupt ONNX file, or one the ONNX checker rejects;
    - external-data tensors whose ``location`` is absolute or resolves outside the model's folder
      (symbolic links included), or whose file is missing; checked before anything is read;
    - weights holding NaN or inf: initializers and constants that feed a MatMul, Gemm, Conv or
      recurrent cell (:data:`WEIGHT_OPS`); other non-finite constants (attention masks, ``Where``
      fills) are by design, and the model is judged by its answers instead;
    - a policy whose action for the zero observation is not finite, or, for a foreign file (no
      ``policy_spec`` metadata; an export's parity gate already ran ours across the spec's
      ranges), for an observation of the spec's range (every entry at -1, at +1, and 29
      uniform draws in [-1, 1]);
    - a graph input other than the observation and recurrent state inputs (the message names the
      input and its shape, and what would make it load), several action outputs none of which is
      named ``action`` or ``actions``, non-float32 input or output, or an input/output size that
      differs from the spec;
    - a recurrent state input without a batch axis (not ``[layers, batch, hidden]``), or whose
      state output has another shape than the input (declared, or when run);
    - a spec that does not match the robot (``PolicySpec.check_robot``: robot name, joint names and
      order, control rate, description hash) or a model without our metadata when no spec is given
      and no training stack's own contract is found;
    - a spec passed in that contradicts the one stored in the file;

Metadata written by ``policy-export`` (``model.metadata_props``, read with plain ONNX Runtime as
``InferenceSession(path).get_modelmeta().custom_metadata_map``): ``policy_spec`` (PolicySpec
JSON, with ``baked`` and ``parity`` filled), ``source_sha256``, ``tool_versions`` (JSON),
``parity`` (JSON), ``source_format``, ``exporter``. A foreign ONNX file without them is accepted
when ``spec`` is given: its single data input and its output are discovered from the graph.
Without ``spec``, a file that carries its training stack's own contract (mjlab's or holosoma's
metadata, an Isaac Lab run folder: :mod:`deploy.spec.foreign`) gets the spec built from it
(``foreign`` holds that contract); an unmappable contract is refused naming the term or joint.
A spec whose ``action.joints`` orders the graph's outputs otherwise than ``joint_names`` has the
output reordered into ``joint_names`` order (one ``np.take`` a call).

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

Constant inputs: Godot RL Agents' export (``obs``, ``state_ins`` -> ``output``, ``state_outs``,
opset 17; ``state_ins`` ``[batch]`` is a dummy the exporter passes through to ``state_outs``, and
``output`` is the unclipped PPO action mean) is recognised by those four names: ``state_ins`` is
fed zeros every tick, as Godot's own ONNX inference does, and ``output`` is the action, clipped by
the spec's ``action.clip``. Any other extra input loads only when the spec's ``constant_inputs``
names it (``{"name": value}``: fed that constant, shaped as declared with a symbolic axis 0 as the
batch).

Inference runs single-threaded (``intra_op_num_threads = inter_op_num_threads = 1``, sequential
execution: fastest for small MLPs at batch 1) through an IOBinding bound once to preallocated
numpy buffers; it is rebound only when the batch size changes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

from deploy.policy.onnx_checks import (  # noqa: F401 - PolicyLoadError and WEIGHT_OPS re-exported
    WEIGHT_OPS,
    PolicyLoadError,
    check_external_data,
    check_finite_weights,
)
from deploy.spec.policy_spec import PolicySpec, SpecError
from robots import Robot

#: Metadata keys written by the exporter.
METADATA_SPEC = "policy_spec"
#: Godot RL Agents' dummy state: input and output names (fed zeros; the output is ignored).
GODOT_STATE = ("state_ins", "state_outs")


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
        foreign: The :class:`~deploy.spec.foreign.ForeignContract` the spec was built from, or
            None (our metadata or a given spec).
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
        #: The training stack's own contract the spec was built from (None: ours or --spec).
        self.foreign = None
        self.spec = self._resolve_spec(path, spec, model, robot)
        try:
            self.spec.check_robot(robot, check_hash=check_hash)
        except SpecError as exc:  # name the spec file the user gave, else the ONNX file
            where = spec if isinstance(spec, str | os.PathLike) else path
            raise PolicyLoadError(f"{where}: {exc}") from None
        self.obs_dim, self.act_dim = self.spec.obs_dim, self.spec.act_dim
        self.input_name, self.output_name, self._fixed_batch, self.states = self._check_graph(
            model, path
        )
        self.recurrent = bool(self.states)
        joints = self.spec.action.joints
        #: spec-order action entry i is graph output _to_spec_order[i] (None: the same order)
        self._to_spec_order = None if not joints else np.argsort(np.asarray(joints))

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
        if self.recurrent:  # batch 2 too: a state output may ignore the batch axis
            for batch in (probe_batch,) if self._fixed_batch else (1, 2):
                self._check_state_shapes(path, batch)
        try:
            probe = self(np.zeros((probe_batch, self.obs_dim), np.float32))
        except Exception as exc:  # noqa: BLE001
            raise PolicyLoadError(
                f"{path}: running the model on a zero observation of shape "
                f"({probe_batch}, {self.obs_dim}) failed: {exc}"
            ) from None
        if not np.isfinite(probe).all():
            raise PolicyLoadError(f"{path}: the action for the zero observation is not finite")
        if METADATA_SPEC not in self.metadata:  # an export's parity gate probed it already
            self._probe_range(path, probe_batch)
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

    def _resolve_spec(
        self,
        path: Path,
        spec: PolicySpec | str | os.PathLike | None,
        model: onnx.ModelProto,
        robot: Robot,
    ) -> PolicySpec:
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
            from deploy.spec import foreign

            try:
                self.foreign = foreign.read_contract(foreign.OnnxFacts.of(path, model))
                if self.foreign is not None:
                    return foreign.to_spec(self.foreign, robot)
            except SpecError as exc:
                raise PolicyLoadError(str(exc)) from None
            raise PolicyLoadError(
                f"{path}: no '{METADATA_SPEC}' metadata (not written by policy-export) and no "
                f"training stack's own contract ({foreign.known_formats()}); pass the "
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
        constants: dict[str, onnx.ValueInfoProto] = {}
        godot = inp.name == "obs" and GODOT_STATE[0] in names and GODOT_STATE[1] in outputs
        for i in graph.input:
            if i.name == inp.name or (
                i.name in init_names and _state_output_name(i.name) not in outputs
            ):
                continue
            out_name = _state_output_name(i.name)
            if i.name in self.spec.constant_inputs or (godot and i.name == GODOT_STATE[0]):
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
                '"constant_inputs": {"' + unknown[0].name + '": VALUE} to the --spec file; '
                "or export the policy with policy-export"
            )
        self._constant_specs = {
            name: self._constant_shape(path, vi, self.spec.constant_inputs.get(name, 0.0))
            for name, vi in constants.items()
        }
        missing = sorted(set(self.spec.constant_inputs) - set(constants))
        if missing:
            raise PolicyLoadError(
                f"{path}: the spec's constant_inputs name {missing}, which the graph does not have "
                f"as inputs (its inputs: {names})"
            )
        state_outs = {o.name for _, o in pairs} | ({GODOT_STATE[1]} if godot else set())
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
                parts = (
                    " + ".join(f"{b.name} {b.size}" for b in self.spec.observation_blocks)
                    if kind == "input"
                    else f"{self.spec.action.mode} x {self.spec.action.size} joints"
                )
                raise PolicyLoadError(
                    f"{path}: graph {kind} '{vi.name}' has size {dims[-1]}, the spec's {what} "
                    f"has {size} ({parts}; shape {dims}): the spec must describe the model's "
                    f"{what} entry for entry"
                )
        in_dims = _dims(inp)
        fixed = in_dims[0] if in_dims and isinstance(in_dims[0], int) and in_dims[0] > 0 else 0
        states = tuple(self._check_state(path, i, o, fixed, init.get(i.name)) for i, o in pairs)
        return inp.name, out.name, fixed, states

    @staticmethod
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

    def _probe_range(self, path: Path, batch: int) -> None:
        """Judge the model by its answers: the action must be finite for every entry at -1 and at
        +1 and for 29 uniform draws in [-1, 1] (seed 0): the range the spec's normalized
        observations live in. Each probe starts from the initial recurrent state."""
        rows = np.random.default_rng(0).uniform(-1.0, 1.0, (31, self.obs_dim)).astype(np.float32)
        rows[0], rows[1] = 1.0, -1.0
        for k, row in enumerate(rows):
            self.reset()
            action = self(np.broadcast_to(row, (batch, self.obs_dim)))
            if not np.isfinite(action).all():
                what = (
                    ("every entry at +1", "every entry at -1")[k]
                    if k < 2
                    else (f"uniform draw {k - 1} of 29 in [-1, 1] (seed 0)")
                )
                raise PolicyLoadError(
                    f"{path}: the action for the observation with {what} is not finite "
                    f"({action[0].tolist()}); refusing the model"
                )

    def _check_state_shapes(self, path: Path, batch: int) -> None:
        """Run the graph once on zeros: every state output must have its input's shape."""
        feeds = {self.input_name: np.zeros((batch, self.obs_dim), np.float32)}
        for name, (shape, dtype, value) in self._constant_specs.items():
            feeds[name] = np.full([batch if d is None else d for d in shape], value, dtype)
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
        # the graph's outputs in its own joint order when it differs (spec action.joints)
        self._graph_action = self._action if self._to_spec_order is None else self._action.copy()
        self._obs_value = ort.OrtValue.ortvalue_from_numpy(self._obs)
        self._action_value = ort.OrtValue.ortvalue_from_numpy(self._graph_action)
        self._binding.clear_binding_inputs()
        self._binding.clear_binding_outputs()
        self._binding.bind_ortvalue_input(self.input_name, self._obs_value)
        self._binding.bind_ortvalue_output(self.output_name, self._action_value)
        self._constant_values = []  # keep the OrtValues alive with the binding
        for name, (shape, dtype, value) in self._constant_specs.items():
            array = np.full([batch if d is None else d for d in shape], value, dtype)
            self._constant_values.append(ort.OrtValue.ortvalue_from_numpy(array))
            self._binding.bind_ortvalue_input(name, self._constant_values[-1])
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
        if self._to_spec_order is not None:
            np.take(self._graph_action, self._to_spec_order, axis=1, out=self._action)
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
