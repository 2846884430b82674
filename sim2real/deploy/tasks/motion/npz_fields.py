"""The fields of a motion NPZ archive, read and checked for the clip readers.

BeyondMimic's and holosoma's motion files are ``numpy.savez`` archives of arrays (no pickled
objects: read with ``allow_pickle=False``). Every refusal is a :class:`ClipError` whose one line
names the file, the field and the value expected.
"""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sim2real.deploy.tasks.motion.clip import ClipError

#: How far from 1 a stored quaternion's norm may be (float32 files, slerped frames).
UNIT_TOLERANCE = 1e-3


def load_npz(path: Path, keys: Sequence[str], stack: str) -> dict[str, np.ndarray]:
    """The arrays ``keys`` of the archive at ``path``, as a dict (extra keys are ignored).

    Raises:
        ClipError: the file is absent or not an NPZ archive, holds pickled objects, or lacks a
            key (named, with ``stack``'s keys listed).
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            present = list(data.files)
            arrays = {k: data[k] for k in keys if k in present}
    except (OSError, zipfile.BadZipFile, EOFError) as exc:
        raise ClipError(f"{path}: file: expected a NumPy .npz archive ({exc})") from None
    except ValueError as exc:  # an object array: np.load refuses to unpickle
        raise ClipError(f"{path}: file: expected arrays without pickled objects ({exc})") from None
    missing = [k for k in keys if k not in present]
    if missing:
        raise ClipError(
            f"{path}: {missing[0]}: expected {stack}'s motion keys {', '.join(keys)}; missing"
        )
    return arrays


def read_fps(path: Path, value: np.ndarray) -> float:
    """The archive's ``fps`` (stored as ``[fps]`` by both stacks' converters), Hz.

    Raises:
        ClipError: not a single finite positive number.
    """
    array = np.asarray(value)
    if array.size != 1 or array.dtype.kind not in "iuf":
        raise ClipError(
            f"{path}: fps: expected one positive number of frames per second, got "
            f"{array.tolist()!r}"
        )
    fps = float(array.reshape(()))
    if not np.isfinite(fps) or fps <= 0.0:
        raise ClipError(f"{path}: fps: expected a positive finite number, got {fps!r}")
    return fps


def read_names(path: Path, field: str, value) -> tuple[str, ...]:
    """A list of names (``joint_names``, ``body_names``): strings, none repeated."""
    array = np.asarray(value)
    if array.ndim != 1 or array.dtype.kind not in "US":
        raise ClipError(
            f"{path}: {field}: expected a list of names, got {array.dtype} {array.shape}"
        )
    names = tuple(str(n) for n in array.tolist())
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ClipError(f"{path}: {field}: expected each name once, {repeated[0]!r} repeats")
    return names


def columns(path: Path, field: str, value, width: int, what: str) -> np.ndarray:
    """``value`` as a (frames, width) float array; ``what`` says what the columns are."""
    array = np.asarray(value)
    if array.ndim != 2 or array.shape[1] != width or array.dtype.kind not in "iuf":
        raise ClipError(
            f"{path}: {field}: expected (frames, {width}) numbers ({what}), got "
            f"{array.dtype} {array.shape}"
        )
    return array.astype(float)


def unit_quaternions(path: Path, field: str, quat: np.ndarray) -> None:
    """Refuse quaternions (..., 4) whose norm is not 1 (a zero row, a scaled one)."""
    norm = np.linalg.norm(quat, axis=-1)
    bad = np.argwhere(~(np.abs(norm - 1.0) <= UNIT_TOLERANCE))
    if len(bad):
        raise ClipError(
            f"{path}: {field}: expected unit quaternions w x y z, got norm "
            f"{norm[tuple(bad[0])]:.4g} at frame {bad[0][0]}"
        )


def by_robot_order(
    path: Path, field: str, names: tuple[str, ...], robot_joints: Sequence[str] | None
) -> list[int]:
    """Column of each robot joint (``robot_joints`` order) in the file's ``names``; the file's
    own order when ``robot_joints`` is None.

    Raises:
        ClipError: a robot joint without a column, or a column for a joint the robot lacks.
    """
    if robot_joints is None:
        return list(range(len(names)))
    missing = [j for j in robot_joints if j not in names]
    if missing:
        raise ClipError(
            f"{path}: {field}: expected a column for every robot joint, none for {missing[0]!r} "
            f"({len(names)} columns for {len(robot_joints)} robot joints)"
        )
    extra = [n for n in names if n not in robot_joints]
    if extra:
        raise ClipError(
            f"{path}: {field}: expected the robot's joints only, {extra[0]!r} is not one "
            f"({len(names)} columns for {len(robot_joints)} robot joints)"
        )
    return [names.index(j) for j in robot_joints]
