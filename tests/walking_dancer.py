"""A made-up motion-tracking policy that walks: the shipped go2 walker behind a graph that reads
a clip (``motion_command`` and ``motion_anchor_ori_b`` blocks, which it ignores) and always
feeds the walker a forward command; and a holosoma-format clip of the go2's joints whose root
walks forward or stands. What a dance that leaves its spot after its clip looks like, on CI's
shipped robot, no stack needed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper

#: The go2's joints standing in for a humanoid's waist (yaw, roll, pitch) of the anchor block.
WAIST = (0, 1, 2)


def walking_dancer_onnx(walker: Path, out: Path, forward_m_s: float) -> Path:
    """``walker`` (an exported go2 ONNX with its spec) behind a graph whose observation adds a
    clip's blocks (ignored) and whose walker always sees ``forward_m_s`` m/s more forward
    command; written to ``out`` with its spec."""
    model = onnx.load(str(walker))
    meta = {p.key: p.value for p in model.metadata_props}
    spec = json.loads(meta["policy_spec"])
    inner = sum(b["size"] for b in spec["observation"])
    n = len(spec["joint_names"])
    offset = np.zeros((1, inner), np.float32)
    at = 0
    for b in spec["observation"]:
        if b["name"] == "velocity_command":
            offset[0, at] = forward_m_s / b["scale"][0]  # the spec's scale divides
        at += b["size"]
    spec["observation"] += [
        {"name": "motion_command", "size": 2 * n, "joints": list(range(n)), "clip": 100.0,
         "scale": [1.0] * 2 * n, "offset": [0.0] * 2 * n},
        {"name": "motion_anchor_ori_b", "size": 6, "joints": list(WAIST), "clip": 100.0,
         "scale": [1.0] * 6, "offset": [0.0] * 6},
    ]  # fmt: skip
    g = model.graph
    (obs,) = [i for i in g.input if i.name == "obs"]
    for node in g.node:
        node.input[:] = ["walker_obs" if x == "obs" else x for x in node.input]
    total = inner + 2 * n + 6
    g.initializer.extend([
        helper.make_tensor("dancer_starts", TensorProto.INT64, [1], [0]),
        helper.make_tensor("dancer_ends", TensorProto.INT64, [1], [inner]),
        helper.make_tensor("dancer_axes", TensorProto.INT64, [1], [1]),
        helper.make_tensor("dancer_offset", TensorProto.FLOAT, [1, inner], offset.ravel()),
    ])  # fmt: skip
    head = [
        helper.make_node("Slice", ["obs", "dancer_starts", "dancer_ends", "dancer_axes"], ["s"]),
        helper.make_node("Add", ["s", "dancer_offset"], ["walker_obs"]),
    ]
    nodes = head + list(g.node)
    del g.node[:]
    g.node.extend(nodes)
    dims = obs.type.tensor_type.shape.dim
    dims[1].dim_value = total
    del model.metadata_props[:]
    model.metadata_props.add(key="policy_spec", value=json.dumps(spec))
    onnx.checker.check_model(model)
    onnx.save(model, str(out))
    return out


def clip_npz(path: Path, robot, seconds: float, speed_m_s: float, fps: float = 50.0) -> Path:
    """A holosoma-format clip (``convert_data_format_mj.py``'s keys) of ``robot``'s joints
    swaying about its home pose for ``seconds`` s, its root walking ``speed_m_s`` m/s along x
    at 0.3 m, upright, heading 0."""
    frames = int(round(seconds * fps)) + 1
    t = np.arange(frames)[:, None] / fps
    n = robot.n_joints
    joints = np.asarray(robot.home) + 0.03 * np.sin(3.0 * t + np.linspace(0.0, 2.0, n))
    root = np.hstack([speed_m_s * t, 0.0 * t, 0.3 + 0.0 * t])
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1))
    qvel = np.hstack([np.gradient(root, axis=0) * fps, np.zeros((frames, 3)),
                      np.gradient(joints, axis=0) * fps])  # fmt: skip
    np.savez(
        path,
        fps=np.array([fps]),
        joint_pos=np.hstack([root, quat, joints]),
        joint_vel=qvel,
        body_pos_w=root[:, None, :],
        body_quat_w=quat[:, None, :],
        joint_names=np.array(robot.joint_names),
        body_names=np.array(["base"]),
    )
    return path
