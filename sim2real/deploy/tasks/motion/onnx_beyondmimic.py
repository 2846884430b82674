"""The motion BeyondMimic bakes into its exported ONNX, read into a :class:`MotionClip`.

BeyondMimic's exporter (``whole_body_tracking/utils/exporter.py``, ``_OnnxMotionPolicyExporter``)
stores the training clip in the graph: inputs ``obs``, ``time_step``; outputs ``actions`` then
``joint_pos``, ``joint_vel`` (1, J), ``body_pos_w`` (1, B, 3), ``body_quat_w`` (1, B, 4, ``w x y
z``), ``body_lin_vel_w``, ``body_ang_vel_w``, each a ``Gather`` of a constant (T, ...) table at
``time_step`` clamped to T - 1. Its metadata names them (``attach_onnx_metadata``: lists
comma-joined): ``joint_names`` (the articulation's order, the tables' columns), ``body_names``
(the tracked bodies, the tables' second axis), ``anchor_body_name``. The clip's rate is the
policy's (one frame per policy step); the file does not state it, so the caller gives it.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper

from sim2real.deploy.tasks.motion.clip import ClipError, MotionClip
from sim2real.deploy.tasks.motion.npz_fields import by_robot_order, unit_quaternions

#: The motion outputs of the exporter, in its order.
OUTPUTS = ("joint_pos", "joint_vel", "body_pos_w", "body_quat_w")


def constant_table(
    path: Path, graph: onnx.GraphProto, output: str, stack: str = "BeyondMimic's"
) -> np.ndarray:
    """The constant (T, ...) table the graph gathers ``output`` from (an initializer or a
    ``Constant`` node behind a ``Gather``).

    Raises:
        ClipError: ``output`` is no output of the graph, not a ``Gather`` or not of a constant.
    """
    producers = {o: n for n in graph.node for o in n.output}
    node = producers.get(output)
    if node is None or node.op_type != "Gather":
        raise ClipError(
            f"{path}: {output}: expected {stack} motion output (a Gather of the clip "
            f"at time_step), got {'no such output' if node is None else node.op_type}"
        )
    source = node.input[0]
    for init in graph.initializer:
        if init.name == source:
            return numpy_helper.to_array(init)
    constant = producers.get(source)
    if constant is not None and constant.op_type == "Constant":
        for attr in constant.attribute:
            if attr.name == "value":
                return numpy_helper.to_array(attr.t)
    raise ClipError(f"{path}: {output}: expected a constant clip table, got {source!r}")


def _names(path: Path, metadata: dict[str, str], key: str) -> tuple[str, ...]:
    if key not in metadata:
        raise ClipError(f"{path}: {key}: expected BeyondMimic's metadata entry; missing")
    return tuple(n.strip() for n in metadata[key].split(","))


def read_beyondmimic_onnx_motion(
    path, fps: float, robot_joints: Sequence[str] | None = None, root_body: str = "pelvis"
) -> MotionClip:
    """The clip baked into BeyondMimic's exported ONNX at ``path``.

    Args:
        path: the exported ``policy.onnx``.
        fps: the policy's rate, Hz (BeyondMimic: sim dt 0.005 x decimation 4 = 50 Hz).
        robot_joints: the robot's joints in the order the clip should carry them; None keeps
            the metadata's ``joint_names`` order.
        root_body: the tracked body that is the robot's floating base.

    Returns:
        A :class:`MotionClip`: joints (T, J) rad, rad/s; the tracked bodies (T, B) with
        ``w x y z`` quaternions; the root the ``root_body``'s pose.

    Raises:
        ClipError: one line naming the file and field: a file ONNX cannot read, a missing motion
            output or metadata entry, tables whose widths disagree with ``joint_names`` or
            ``body_names``, ``root_body`` not tracked, quaternions that are not unit.
    """
    path = Path(path)
    try:
        model = onnx.load(str(path))
    except Exception as exc:  # onnx raises DecodeError, OSError, ...: all mean "not a model"
        raise ClipError(f"{path}: file: expected an ONNX model ({exc})") from None
    metadata = {p.key: p.value for p in model.metadata_props}
    tables = {name: np.asarray(constant_table(path, model.graph, name), float) for name in OUTPUTS}
    joints = _names(path, metadata, "joint_names")
    bodies = _names(path, metadata, "body_names")
    frames = tables["joint_pos"].shape[0]
    shapes = {
        "joint_pos": (frames, len(joints)),
        "joint_vel": (frames, len(joints)),
        "body_pos_w": (frames, len(bodies), 3),
        "body_quat_w": (frames, len(bodies), 4),
    }
    for name, shape in shapes.items():
        if tables[name].shape != shape:
            raise ClipError(
                f"{path}: {name}: expected a clip table {shape} (frames, joint_names / "
                f"body_names), got {tables[name].shape}"
            )
    if root_body not in bodies:
        raise ClipError(
            f"{path}: body_names: expected the root body {root_body!r} among the tracked "
            f"bodies, got {', '.join(bodies)}"
        )
    unit_quaternions(path, "body_quat_w", tables["body_quat_w"])
    order = by_robot_order(path, "joint_names", joints, robot_joints)
    root = bodies.index(root_body)
    return MotionClip(
        source=path,
        fps=fps,
        joint_names=tuple(joints[i] for i in order),
        joint_pos=tables["joint_pos"][:, order],
        joint_vel=tables["joint_vel"][:, order],
        root_pos=tables["body_pos_w"][:, root],
        root_quat=tables["body_quat_w"][:, root],
        body_names=bodies,
        body_pos_w=tables["body_pos_w"],
        body_quat_w=tables["body_quat_w"],
    )
