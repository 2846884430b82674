"""The float32 noise floor of an ONNX graph whose source cannot run in float64:
:class:`GraphTwin`.

A TorchScript module whose code fixes float32 (rl_sar's RoboMimic ``DanceWrapper``:
``torch.zeros(..., dtype=6)``) has no float64 copy (:func:`~sim2real.deploy.export.noise_floor.
float64_twin`), so the parity gate cannot measure its noise floor from the source. The graph
exported from it can: :func:`float64_graph` rewrites every float32 tensor of the graph (its
input, output, initializers, constants, ``Cast`` targets) to float64, and ONNX's reference
evaluator (``onnx.reference.ReferenceEvaluator``: numpy, each operator in its inputs' dtype) runs
it. The largest ``|graph float32 (ONNX Runtime) - graph float64|`` over the parity observations
is the graph's own float32 rounding, the quantity the float64 copy of the source measures for
every other source.

Why this is sound: the rounding error of a float32 dot product is bounded by
``gamma_n |w|.|x|`` and depends on the order of its sums (Higham, *Accuracy and Stability of
Numerical Algorithms*, 2nd ed., SIAM 2002, section 3.1, eq. 3.5), so two float32 evaluations of
one network (torch's kernels, ONNX Runtime's) may differ by up to the sum of their rounding
errors, which grows with ``|w|.|x|``: an absolute tolerance is wrong for large activations.
Measuring the floor on the graph itself (its float32 answer against its own float64 answer) keeps
it independent of the torch side: a graph that computes another function (a wrong weight, swapped
outputs) rounds like the right one, so its floor stays at the rounding's size while its error
against the source is the size of the mistake. Perturbing the inputs by one float32 ulp measures
the network's sensitivity to its inputs' rounding, not the rounding of its sums, so it is no
bound (on rl_sar's charleston it gives 1.7e-3 where the graph's own rounding is 3.8e-3).
"""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
from onnx import AttributeProto, TensorProto, numpy_helper
from onnx.reference import ReferenceEvaluator

from sim2real.deploy.export.errors import _first_line

_F32, _F64 = TensorProto.FLOAT, TensorProto.DOUBLE


def _double(t: TensorProto) -> TensorProto:
    return numpy_helper.from_array(numpy_helper.to_array(t).astype(np.float64), t.name)


def float64_graph(model: onnx.ModelProto) -> onnx.ModelProto:
    """A copy of ``model`` computing in float64: every float32 initializer, constant tensor
    attribute (``Constant``, ``ConstantOfShape``), ``Cast`` target and value type made float64
    (tensors of other types are kept). ``model`` is not changed."""
    m = onnx.ModelProto.FromString(model.SerializeToString())
    g = m.graph
    for i, t in enumerate(g.initializer):
        if t.data_type == _F32:
            g.initializer[i].CopyFrom(_double(t))
    for v in [*g.input, *g.output, *g.value_info]:
        if v.type.tensor_type.elem_type == _F32:
            v.type.tensor_type.elem_type = _F64
    for node in g.node:
        if any(a.type == AttributeProto.GRAPH for a in node.attribute):
            raise ValueError(f"node {node.name or node.op_type} holds a subgraph")
        for a in node.attribute:
            if a.type == AttributeProto.TENSOR and a.t.data_type == _F32:
                a.t.CopyFrom(_double(a.t))
            elif node.op_type == "Cast" and a.name == "to" and a.i == _F32:
                a.i = _F64
    return m


class GraphTwin:
    """An ONNX graph run in float32 (ONNX Runtime, CPU, one thread: as the gate runs it) and in
    float64 (:func:`float64_graph` in ONNX's reference evaluator) on the same observations.

    Args:
        model: The exported graph; one float32 input and one float32 output.

    Raises:
        ValueError: the graph cannot be rewritten or run in float64 (one line, the reason).
    """

    def __init__(self, model: onnx.ModelProto):
        options = ort.SessionOptions()
        options.intra_op_num_threads = 1
        try:
            self.f32 = ort.InferenceSession(
                model.SerializeToString(), options, providers=["CPUExecutionProvider"]
            )
            self.f64 = ReferenceEvaluator(float64_graph(model))
            self.input = model.graph.input[0].name
            self.output = model.graph.output[0].name
            probe = np.zeros((1, _input_size(model)), np.float64)
            out = self.f64.run([self.output], {self.input: probe})[0]
        except Exception as exc:  # noqa: BLE001 - any failure: the graph has no float64 twin
            raise ValueError(
                f"its ONNX graph does not run in float64 ({_first_line(exc)})"
            ) from None
        if out.dtype != np.float64:
            raise ValueError("its ONNX graph does not run in float64 (its output stays float32)")

    def __call__(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(float32 answer, float64 answer)`` of the graph to ``obs`` (float32
        (batch, obs_dim); the batch the graph takes)."""
        out32 = self.f32.run([self.output], {self.input: obs})[0]
        with np.errstate(
            all="ignore"
        ):  # the reference ELU takes expm1 of every entry, kept where x <= 0
            out64 = self.f64.run([self.output], {self.input: obs.astype(np.float64)})[0]
        return out32, out64


def _input_size(model: onnx.ModelProto) -> int:
    dims = model.graph.input[0].type.tensor_type.shape.dim
    return int(dims[-1].dim_value)
