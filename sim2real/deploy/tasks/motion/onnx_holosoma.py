"""The clip holosoma bakes into its whole-body tracking ONNX, read as holosoma_inference plays it.

holosoma's WBT export (``models/wbt/*.onnx``; amazon-far/holosoma fc600e7) gathers the training
clip at input ``time_step`` (cast, clamped to T - 1): outputs ``joint_pos``, ``joint_vel`` (1, J)
in the metadata's ``dof_names`` order, ``ref_pos_xyz`` (1, 3) and ``ref_quat_xyzw`` (1, 4, **x y z
w**) of the reference body (``torso_link`` for the G1). The actions read ``obs`` alone (checked:
a graph whose ``actions`` depend on ``time_step`` is refused, since the runtime feeds it 0).

holosoma_inference (``policies/wbt.py``, ``WholeBodyTrackingPolicy.rl_inference``) advances the
step by one each policy tick from the clip's start and builds each tick's observation from the
outputs of the tick before (the first tick reads step 0). Read here so that the motion clock's
frame at tick k is exactly that: the first frame twice, then one frame a tick (the clock's
``f = t / (T / fps) x (T - 1)``, see :mod:`.clock`, is ``t x rate`` with ``fps = rate x T / (T -
1)``); the last frame holds after the end as the graph's clamp holds it.

The clip's root (pelvis) orientation is the torso's with the waist's rotation removed
(``torso = root * Rz(yaw) Rx(roll) Ry(pitch)``, the G1's waist, as
:func:`~sim2real.deploy.spec.motion_blocks.torso_quat`), so the clock's anchor is the graph's
torso exactly; ``root_pos`` is the torso's position (the graph carries no pelvis position; no
tracking term reads it).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnx

from sim2real.deploy.spec.motion_blocks import quat_conj, quat_mul, torso_quat
from sim2real.deploy.tasks.motion.clip import ClipError, MotionClip
from sim2real.deploy.tasks.motion.csv_clip import check_limits
from sim2real.deploy.tasks.motion.npz_fields import unit_quaternions
from sim2real.deploy.tasks.motion.onnx_beyondmimic import constant_table

STACK = "holosoma's WBT"
#: The waist joints the reference body (``torso_link``) rides: yaw, roll, pitch.
WAIST = ("waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint")


def _ancestors(graph: onnx.GraphProto, output: str) -> set[str]:
    producers = {o: n for n in graph.node for o in n.output}
    seen: set[str] = set()
    todo = [output]
    while todo:
        node = producers.get(todo.pop())
        for name in node.input if node is not None else ():
            if name and name not in seen:
                seen.add(name)
                todo.append(name)
    return seen


def read_holosoma_onnx_motion(
    path, rate: float, columns: Sequence[str], limits: dict | None = None
) -> MotionClip:
    """The clip of holosoma's WBT export at ``path`` (module docstring).

    Args:
        path: The ``.onnx`` file. rate: The policy's rate, Hz (holosoma_inference ``rl_rate``).
        columns: The robot joint of each table column (the metadata's ``dof_names`` mapped to
            the robot's names). limits: ``{joint: (low, high)}`` rad, the robot's hard limits.

    Returns:
        A :class:`MotionClip` of T + 1 frames at ``rate x (T + 1) / T`` Hz (module docstring),
        ``stated`` as holosoma_inference plays it: T frames at ``rate`` Hz.

    Raises:
        ClipError: one line naming the file and field: not an ONNX model, a table missing or
            not a constant, tables whose widths are not ``len(columns)``, actions that read
            ``time_step``, non-unit quaternions, no waist joints, a frame past a hard limit, a
            rate that is not a positive number.
    """
    path = Path(path)
    if not (isinstance(rate, int | float) and np.isfinite(rate) and rate > 0):
        raise ClipError(
            f"{path}: fps: expected a positive number of frames per second, got {rate!r}"
        )
    try:
        model = onnx.load(str(path))
    except Exception as exc:  # noqa: BLE001 - onnx raises DecodeError, OSError, ...
        raise ClipError(f"{path}: file: expected an ONNX model ({exc})") from None
    graph = model.graph
    if "time_step" in _ancestors(graph, "actions"):
        raise ClipError(
            f"{path}: actions: expected holosoma's WBT graph, whose actions read obs alone; "
            "these read time_step"
        )
    t = {
        name: np.asarray(constant_table(path, graph, name, STACK), float)
        for name in ("joint_pos", "joint_vel", "ref_pos_xyz", "ref_quat_xyzw")
    }
    frames, n = t["joint_pos"].shape[0], len(columns)
    shapes = {"joint_pos": (frames, n), "joint_vel": (frames, n), "ref_pos_xyz": (frames, 3)}
    shapes["ref_quat_xyzw"] = (frames, 4)
    for name, shape in shapes.items():
        if t[name].shape != shape:
            raise ClipError(
                f"{path}: {name}: expected a clip table {shape} (frames, dof_names), "
                f"got {t[name].shape}"
            )
    torso = t["ref_quat_xyzw"][:, [3, 0, 1, 2]]  # x y z w -> w x y z
    unit_quaternions(path, "ref_quat_xyzw", torso)
    missing = [j for j in WAIST if j not in columns]
    if missing:
        raise ClipError(f"{path}: dof_names: expected the waist joints, none for {missing}")
    waist = t["joint_pos"][:, [list(columns).index(j) for j in WAIST]]
    root = quat_mul(torso, quat_conj(torso_quat(np.tile([1.0, 0, 0, 0], (frames, 1)), waist)))
    check_limits(path, columns, t["joint_pos"], limits or {})

    def lagged(a: np.ndarray) -> np.ndarray:  # the first frame twice (module docstring)
        return np.concatenate([a[:1], a], axis=0)

    return MotionClip(
        source=path,
        fps=float(rate) * (frames + 1) / frames,
        joint_names=tuple(columns),
        joint_pos=lagged(t["joint_pos"]),
        joint_vel=lagged(t["joint_vel"]),
        root_pos=lagged(t["ref_pos_xyz"]),
        root_quat=lagged(root / np.linalg.norm(root, axis=-1, keepdims=True)),
        stated=(frames, float(rate)),  # holosoma_inference's: T frames, one a tick at rl_rate
    )
