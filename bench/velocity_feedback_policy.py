"""A policy that observes the base's linear velocity, built from one that does not: the push
benchmark's estimate-fed rows (``python -m bench.push_reference``, docs/soak.md) need one, and no
published policy on this machine observes it.

``python -m bench.velocity_feedback_policy POLICY.onnx OUT.onnx [--gain K]``

The exported ONNX policy (its spec in the metadata, a ``velocity_command`` block) gets a
``base_linear_velocity`` block in front of its observation, scaled as its command's planar
entries, and one MatMul before its network that feeds the planar velocity error back into the
command it sees: ``cmd' = cmd + K (cmd - v)`` in x and y (K: ``--gain``, default 0.5). The rest of
the graph, the spec's other blocks and its metadata are the file's. Exit codes: 0 written, 2 bad
input (one line).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import onnx
from onnx import helper, numpy_helper

PROG = "python -m bench.velocity_feedback_policy"


def feedback_policy(source: Path, out: Path, gain: float = 0.5) -> int:
    """Write ``source`` with the velocity feedback (module docstring) to ``out``; returns the
    new observation size.

    Raises:
        ValueError: no spec in the metadata, no planar ``velocity_command`` block, or one input.
    """
    model = onnx.load(source)
    props = {p.key: p.value for p in model.metadata_props}
    if "policy_spec" not in props:
        raise ValueError(f"{source}: no policy_spec in its metadata (an exported ONNX file)")
    spec = json.loads(props["policy_spec"])
    blocks = spec["observation"]
    starts = np.cumsum([0] + [b["size"] for b in blocks])
    named = [i for i, b in enumerate(blocks) if b["name"] == "velocity_command"]
    if not named or blocks[named[0]]["size"] != 3 or len(model.graph.input) != 1:
        raise ValueError(f"{source}: expected one input and a 3-entry velocity_command block")
    command, n = int(starts[named[0]]), int(starts[-1])
    scale = blocks[named[0]]["scale"]
    blocks.insert(
        0,
        {"clip": blocks[named[0]]["clip"], "joints": [], "name": "base_linear_velocity",
         "offset": [0.0, 0.0, 0.0], "scale": [scale[0], scale[1], scale[0]], "size": 3},
    )  # fmt: skip
    matrix = np.zeros((n + 3, n), np.float32)
    matrix[3:] = np.eye(n, dtype=np.float32)
    for axis in (0, 1):  # the same scale: the scaled entries subtract as the velocities do
        matrix[3 + command + axis, command + axis] = 1.0 + gain
        matrix[axis, command + axis] = -gain
    graph, name = model.graph, model.graph.input[0].name
    for node in graph.node:
        node.input[:] = [f"{name}_inner" if x == name else x for x in node.input]
    graph.node.insert(0, helper.make_node("MatMul", [name, "feedback"], [f"{name}_inner"]))
    graph.initializer.append(numpy_helper.from_array(matrix, "feedback"))
    graph.input[0].type.tensor_type.shape.dim[1].dim_value = n + 3
    del model.metadata_props[:]
    helper.set_model_props(model, {**props, "policy_spec": json.dumps(spec)})
    onnx.checker.check_model(model)
    onnx.save(model, out)
    return n + 3


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__)
    p.add_argument("policy", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--gain", type=float, default=0.5, help="K of cmd' = cmd + K (cmd - v)")
    a = p.parse_args(argv)
    try:
        size = feedback_policy(a.policy, a.out, a.gain)
    except (ValueError, OSError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {a.out} (observation {size})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
