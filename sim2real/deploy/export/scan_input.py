"""A policy graph given a ``height_scan`` input it does not use (:func:`add_unused_scan`): the
plumbing check of a perceptive policy's runtime path, not a perceptive policy.

The graph's observation input grows by the block's entries (appended after the spec's blocks, as
an Isaac Lab policy group lists ``height_scan`` last), and a ``Gather`` over the input's columns
feeds the original graph its own entries: the scan's weights are zero, so the policy acts as
before while the runtime fills, judges and logs the scan every tick. A spec with a frame history
is refused (its frames would interleave the scan). :func:`with_height_scan` is the spec's part
alone: a spec given the block (the perceptive recipe's, ``train_legged --height-scan``).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from sim2real.deploy.spec.height_scan import CLIP, OFFSET, SCALE, HeightScanPattern
from sim2real.deploy.spec.policy_spec import ObservationBlock, PolicySpec


def with_height_scan(spec: PolicySpec, pattern: HeightScanPattern | None = None) -> PolicySpec:
    """``spec`` with a legged_gym ``height_scan`` block (offset 0.5, scale 0.2, clip 5:
    :mod:`sim2real.deploy.spec.height_scan`) of ``pattern`` (default legged_gym's 17 x 11)
    appended after its blocks; the others keep their columns.

    Raises:
        ValueError: a spec with a frame history, or one that has a height_scan block already.
    """
    if spec.history is not None:
        raise ValueError(
            "with_height_scan: a spec with a frame history: the scan would interleave it"
        )
    if any(b.name == "height_scan" for b in spec.observation_blocks):
        raise ValueError("with_height_scan: the spec has a height_scan block already")
    p = pattern or HeightScanPattern()
    block = ObservationBlock(
        "height_scan", p.count, (SCALE,) * p.count, (OFFSET,) * p.count, CLIP, scan=p
    )
    spec = replace(spec, observation_blocks=(*spec.observation_blocks, block))
    spec.validate()
    return spec


def add_unused_scan(
    source: Path, out: Path, pattern: HeightScanPattern | None = None
) -> tuple[Path, PolicySpec]:
    """Write ``source`` (an ONNX policy with its spec in the metadata, one observation input
    first) with a legged_gym ``height_scan`` block (offset 0.5, scale 0.2, clip 5) of
    ``pattern`` (default legged_gym's 17 x 11) appended to ``out``; returns it and its spec.

    Raises:
        ValueError: a source without a spec in its metadata, or with a frame history.
    """
    model = onnx.load(str(source))
    meta = {p.key: p.value for p in model.metadata_props}
    if "policy_spec" not in meta:
        raise ValueError(f"{source}: no policy_spec in the ONNX metadata")
    spec = PolicySpec.from_json(meta["policy_spec"])
    if spec.history is not None:
        raise ValueError(f"{source}: a spec with a frame history: the scan would interleave it")
    spec = with_height_scan(spec, pattern)
    p = spec.observation_blocks[-1].scan
    graph = model.graph
    obs = graph.input[0]
    inner = f"{obs.name}_without_scan"
    for node in graph.node:  # the original graph reads the gathered columns
        node.input[:] = [inner if name == obs.name else name for name in node.input]
    columns = numpy_helper.from_array(
        np.arange(spec.obs_dim - p.count, dtype=np.int64), "scan_free"
    )
    graph.initializer.append(columns)
    graph.node.insert(0, helper.make_node("Gather", [obs.name, "scan_free"], [inner], axis=1))
    dims = obs.type.tensor_type.shape.dim
    batch = dims[0].dim_param or dims[0].dim_value
    graph.input.remove(obs)
    graph.input.insert(
        0, helper.make_tensor_value_info(obs.name, TensorProto.FLOAT, [batch, spec.obs_dim])
    )
    for prop in model.metadata_props:
        if prop.key == "policy_spec":
            prop.value = spec.to_json()
    onnx.checker.check_model(model)
    onnx.save(model, str(out))
    json.loads(spec.to_json())  # the metadata is the spec's JSON
    return out, spec
