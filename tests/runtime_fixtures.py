"""Small ONNX policies for the runtime tests, and the shipped policies exported."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from sim2real.deploy.policy.adversarial import adversarial_model
from sim2real.deploy.spec.policy_spec import PolicySpec

REPO = Path(__file__).resolve().parent.parent


#: The shipped policies this process exported, by name (:func:`shipped_onnx`).
_EXPORTED: dict[str, bytes] = {}


def shipped_onnx(name: str, folder: Path) -> Path:
    """The shipped policy ``sim2real/policies/<name>.pt`` exported (parity gate included) to
    ``folder/<name>.onnx``; returns that path. Imports torch (the export) only when called.

    Exported once per process: a later call writes the first export's bytes (the same
    checkpoint, the same file) to its own ``folder``, so a test may edit its copy. The export
    runs on one torch thread: two spin-wait in OpenMP on a loaded 2-core machine
    (PITFALLS.md), and the wall-clock tests export beside the suite (Makefile): go2's export took
    35 CPU-s on two threads beside a load, 1.7 on one."""
    out = folder / f"{name}.onnx"
    if name in _EXPORTED:
        if not folder.is_dir():  # as export_policy refuses a missing output folder
            raise FileNotFoundError(f"{out}: the output folder {folder} does not exist")
        out.write_bytes(_EXPORTED[name])
        return out
    import torch

    from sim2real.deploy.export import export_policy

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        src = REPO / "sim2real" / "policies" / f"{name}.pt"
        path = export_policy(src, out=out)
    finally:
        torch.set_num_threads(threads)
    _EXPORTED[name] = Path(path).read_bytes()
    return path


def adversarial_onnx(tmp_path, robot, mode, nan_probability=0.0, name="adv.onnx"):
    spec = PolicySpec.for_robot(robot, mode=mode, position_range="hard")  # past the soft limits
    path = tmp_path / f"{robot.name}_{mode}_{name}"
    onnx.save(adversarial_model(spec, nan_probability), path)
    return path


def feedback_mlp_onnx(path: Path, spec: PolicySpec, name: str = "tiny") -> Path:
    """A deterministic MLP (seeded, 16 tanh units) plus a stabilizing joint-position and
    velocity feedback, for ``spec`` (whose first blocks are joint_position, joint_velocity),
    written to ``path`` with the spec in its metadata."""
    d, n, h = spec.obs_dim, spec.act_dim, 16
    rng = np.random.default_rng(0)
    w1 = rng.normal(0, 0.5, (d, h)).astype(np.float32)
    w2 = rng.normal(0, 0.3, (h, n)).astype(np.float32)
    feedback = np.zeros((d, n), np.float32)
    feedback[:n, :n] = -1.5 * np.eye(n)  # joint_position block comes first
    feedback[n : 2 * n, :n] = -0.3 * np.eye(n)  # then joint_velocity
    nodes = [
        helper.make_node("MatMul", ["obs", "w1"], ["a"]),
        helper.make_node("Tanh", ["a"], ["b"]),
        helper.make_node("MatMul", ["b", "w2"], ["c"]),
        helper.make_node("MatMul", ["obs", "feedback"], ["f"]),
        helper.make_node("Add", ["c", "f"], ["g"]),
        helper.make_node("Tanh", ["g"], ["action"]),
    ]
    graph = helper.make_graph(
        nodes,
        name,
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", d])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", n])],
        initializer=[
            numpy_helper.from_array(w1, "w1"),
            numpy_helper.from_array(w2, "w2"),
            numpy_helper.from_array(feedback, "feedback"),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    helper.set_model_props(model, {"policy_spec": spec.to_json()})
    onnx.save(model, path)
    return path


def linear_onnx(spec, path: Path, nodes, weights: dict, name: str = "linear") -> Path:
    """An ONNX policy of ``spec`` at ``path``: ``nodes`` from input ``obs`` (batch, obs_dim) to
    output ``action`` (batch, act_dim) with the initializers ``weights`` (name -> float32 array),
    the spec in its metadata; returns ``path``."""
    d, n = spec.obs_dim, spec.act_dim
    graph = helper.make_graph(
        nodes,
        name,
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", d])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", n])],
        initializer=[numpy_helper.from_array(v, k) for k, v in weights.items()],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    helper.set_model_props(model, {"policy_spec": spec.to_json()})
    onnx.save(model, path)
    return path


def zero_action_onnx(robot, path: Path) -> Path:
    """An ONNX policy of ``robot``'s default spec whose action is 0 (the home pose in position
    mode), whatever it observes, at ``path``; returns ``path``."""
    spec = PolicySpec.for_robot(robot)
    nodes = [helper.make_node("MatMul", ["obs", "w"], ["action"])]
    weights = {"w": np.zeros((spec.obs_dim, spec.act_dim), np.float32)}
    return linear_onnx(spec, path, nodes, weights, name=path.stem)


def assert_same_arrays(a: dict, b: dict) -> None:
    """Assert two dicts of results hold the same keys and, per key, arrays of the same dtype
    and bits (NaN equal to NaN in float arrays: no yaw or command seen yet)."""
    assert a.keys() == b.keys()
    for key in a:
        x, y = np.asarray(a[key]), np.asarray(b[key])
        nan = x.dtype.kind == "f"
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=nan), key
