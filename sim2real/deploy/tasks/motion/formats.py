"""The clip formats ``deploy-run --motion`` and the soak's clip play: each format by its name, how a
file of it is recognised (its extension and the keys inside it) and its reader, registered by its
stack (the ``clips`` face of :mod:`sim2real.stacks`; :func:`clip_formats`).

- ``rl_sar_csv``, ``.csv``: the extension decides (rl_sar's and BeyondMimic's CSV: root xyz, root
  quaternion x y z w, joints; no header, no names: the contract's columns name them),
  :mod:`.csv_clip`;
- ``holosoma_npz``, ``.npz``: archive keys ``fps joint_pos joint_vel body_pos_w body_quat_w
  joint_names body_names`` (``convert_data_format_mj.py``), :mod:`.npz_holosoma`;
- ``beyondmimic_npz``, ``.npz``: archive keys ``fps joint_pos joint_vel body_pos_w body_quat_w``
  (``csv_to_npz.py``; no names: the policy's ``joint_names`` metadata, Isaac Lab's articulation
  order, names the columns, else a 29-column file on a robot with the G1's joints is
  :data:`~.npz_beyondmimic.BEYONDMIMIC_G1_JOINTS`), :mod:`.npz_beyondmimic`;
- ``holosoma_onnx``, ``.onnx``: graph outputs ``joint_pos joint_vel ref_pos_xyz ref_quat_xyzw``,
  :mod:`.onnx_holosoma`;
- ``beyondmimic_onnx``, ``.onnx``: graph outputs ``joint_pos joint_vel body_pos_w body_quat_w``,
  :mod:`.onnx_beyondmimic`.

A file is the format whose extension it has and whose keys it all holds, the one with the most
keys where two fit (holosoma's NPZ holds BeyondMimic's keys and its names); a file no format
recognises is refused in one line naming the file and the formats known. Every reader gives the
clip's joints by name; :func:`read_clip` maps them to the robot's joints (by name or a known alias)
and refuses a frame past a hard limit, whatever the format.
"""

from __future__ import annotations

import dataclasses
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim2real.deploy.spec.foreign.mapping import robot_joint_named
from sim2real.deploy.tasks.motion.clip import ClipError, MotionClip
from sim2real.deploy.tasks.motion.csv_clip import check_limits, parse_rate, read_csv_clip


@dataclass(frozen=True)
class ClipRequest:
    """What a reader may need besides the file.

    Attributes:
        path: The clip file.
        fps: Hz: ``--motion-fps`` or the contract's rate; None: neither gives one.
        fps_flag: Whether ``fps`` is the user's ``--motion-fps`` (a file that states its own rate
            is then refused, never silently overridden).
        columns: The contract's joint of each CSV column, by the robot's names; None: no contract
            names them.
        metadata_joints: The policy file's ``joint_names`` metadata (Isaac Lab's exports,
            comma-joined), split; None when it has none.
        robot_joints: The robot's joints (robot.toml order).
    """

    path: Path
    fps: float | None
    fps_flag: bool
    columns: tuple[str, ...] | None
    metadata_joints: tuple[str, ...] | None
    robot_joints: tuple[str, ...]


@dataclass(frozen=True)
class ClipFormat:
    """One clip format: ``name``, the file ``extension`` (lower case, with its dot), the ``keys``
    a file of it holds (NPZ archive keys, ONNX graph outputs; empty: the extension decides),
    ``stack`` (who writes it, for messages) and ``read`` (the :class:`ClipRequest` to a clip)."""

    name: str
    extension: str
    keys: tuple[str, ...]
    stack: str
    read: Callable[[ClipRequest], MotionClip]


def _given_rate(request: ClipRequest) -> float:
    if request.fps is None:
        raise ClipError(
            f"{request.path}: fps: the file and the contract state no rate: give --motion-fps HZ"
        )
    return parse_rate(request.fps, request.path)


def _own_rate(request: ClipRequest, clip: MotionClip) -> MotionClip:
    """A clip whose file states its rate: ``--motion-fps`` is refused, not applied silently."""
    if request.fps_flag:
        raise ClipError(
            f"{request.path}: fps: the file states its rate ({clip.fps:g} Hz): --motion-fps is for "
            "clips that state none"
        )
    return clip


def _read_csv(request: ClipRequest) -> MotionClip:
    if request.columns is None:
        raise ClipError(
            f"{request.path}: columns: a CSV names no joints and no contract names the clip's "
            "joint columns"
        )
    return read_csv_clip(request.path, request.columns, _given_rate(request))


def _read_holosoma_npz(request: ClipRequest) -> MotionClip:
    from sim2real.deploy.tasks.motion.npz_holosoma import read_holosoma_npz

    return _own_rate(request, read_holosoma_npz(request.path))


def _read_beyondmimic_npz(request: ClipRequest) -> MotionClip:
    from sim2real.deploy.tasks.motion.npz_beyondmimic import (
        BEYONDMIMIC_G1_JOINTS,
        read_beyondmimic_npz,
    )

    names = request.metadata_joints
    if names is None:
        try:
            with np.load(request.path, allow_pickle=False) as data:
                width = data["joint_pos"].shape[-1]
        except (OSError, ValueError, IndexError):  # the reader names what is wrong
            width = len(BEYONDMIMIC_G1_JOINTS)
        g1 = [robot_joint_named(n, request.robot_joints) for n in BEYONDMIMIC_G1_JOINTS]
        if width != len(BEYONDMIMIC_G1_JOINTS) or None in g1:
            raise ClipError(
                f"{request.path}: joint_names: BeyondMimic's NPZ names no joints and the policy "
                "has no joint_names metadata (Isaac Lab's articulation order) to name its "
                f"{width} columns; known without it: the G1 29-dof's"
            )
        names = BEYONDMIMIC_G1_JOINTS
    return _own_rate(request, read_beyondmimic_npz(request.path, names))


def _read_holosoma_onnx(request: ClipRequest) -> MotionClip:
    from sim2real.deploy.tasks.motion.onnx_holosoma import read_holosoma_onnx_motion

    if request.columns is None:
        raise ClipError(
            f"{request.path}: dof_names: no holosoma WBT contract names the clip's joints "
            "(give the policy this ONNX itself)"
        )
    return read_holosoma_onnx_motion(request.path, _given_rate(request), request.columns)


def _read_beyondmimic_onnx(request: ClipRequest) -> MotionClip:
    from sim2real.deploy.tasks.motion.onnx_beyondmimic import read_beyondmimic_onnx_motion

    return read_beyondmimic_onnx_motion(request.path, _given_rate(request))


#: The stacks' clip formats (their ``clips`` face, :mod:`sim2real.stacks`): rl_sar's CSV (which
#: BeyondMimic's CSV also is), holosoma's NPZ and WBT export, BeyondMimic's NPZ and ONNX export.
RL_SAR_CLIPS = (ClipFormat("rl_sar_csv", ".csv", (), "rl_sar, BeyondMimic", _read_csv),)
HOLOSOMA_CLIPS = (
    ClipFormat(
        "holosoma_npz", ".npz",
        ("fps", "joint_pos", "joint_vel", "body_pos_w", "body_quat_w", "joint_names", "body_names"),
        "holosoma convert_data_format_mj.py", _read_holosoma_npz,
    ),
    ClipFormat(
        "holosoma_onnx", ".onnx", ("joint_pos", "joint_vel", "ref_pos_xyz", "ref_quat_xyzw"),
        "holosoma WBT export", _read_holosoma_onnx,
    ),
)  # fmt: skip
BEYONDMIMIC_CLIPS = (
    ClipFormat(
        "beyondmimic_npz", ".npz", ("fps", "joint_pos", "joint_vel", "body_pos_w", "body_quat_w"),
        "whole_body_tracking csv_to_npz.py", _read_beyondmimic_npz,
    ),
    ClipFormat(
        "beyondmimic_onnx", ".onnx", ("joint_pos", "joint_vel", "body_pos_w", "body_quat_w"),
        "whole_body_tracking exporter", _read_beyondmimic_onnx,
    ),
)  # fmt: skip


def clip_formats() -> dict[str, ClipFormat]:
    """The clip formats by name: every registered stack's ``clips`` face
    (:func:`sim2real.deploy.core.stacks.with_face`), the stacks by rank.

    Raises:
        ValueError: two stacks register a format of one name (naming both).
    """
    from sim2real.deploy.core.stacks import with_face

    out: dict[str, ClipFormat] = {}
    owner: dict[str, str] = {}
    for stack, formats in with_face("clips"):
        for fmt in formats:
            if fmt.name in out:
                raise ValueError(
                    f"clip format '{fmt.name}': registered by stacks '{owner[fmt.name]}' and "
                    f"'{stack.name}'"
                )
            out[fmt.name], owner[fmt.name] = fmt, stack.name
    return out


def known_formats() -> str:
    """``"rl_sar_csv (.csv), holosoma_npz (.npz), ..."``: the registry, for messages."""
    return ", ".join(f"{f.name} ({f.extension})" for f in clip_formats().values())


def _keys(path: Path, extension: str) -> set[str] | None:
    """The keys inside ``path`` (NPZ archive names, ONNX graph outputs); None: unreadable."""
    try:
        if extension == ".npz":
            with zipfile.ZipFile(path) as archive:
                return {n.removesuffix(".npy") for n in archive.namelist()}
        if extension == ".onnx":
            import onnx

            model = onnx.load(str(path), load_external_data=False)
            return {o.name for o in model.graph.output}
    except Exception:  # zipfile, protobuf and OS errors all mean "not a file of this format"
        return None
    return set()


def recognise(path) -> ClipFormat:
    """The format of the clip file ``path``: its extension, then the keys it holds.

    Raises:
        ClipError: ``"<path>: format: no clip format recognises it (...); known: ..."``.
    """
    path = Path(path)
    if not path.is_file():
        raise ClipError(f"{path}: file: expected a clip file, got none there")
    extension = path.suffix.lower()
    candidates = [f for f in clip_formats().values() if f.extension == extension]
    keys = _keys(path, extension) if candidates else None
    fitting = [f for f in candidates if keys is not None and set(f.keys) <= keys]
    if not fitting:
        held = "" if keys is None else f", keys {sorted(keys)}"
        raise ClipError(
            f"{path}: format: no clip format recognises it (extension {extension!r}{held}); "
            f"known: {known_formats()}"
        )
    return max(fitting, key=lambda f: len(f.keys))


def read_clip(request: ClipRequest, robot_name: str, limits: dict) -> tuple[ClipFormat, MotionClip]:
    """The clip of ``request.path`` through its format's reader, its joints named as the robot's.

    Args:
        request: The file and what the readers may need. robot_name: For messages.
        limits: ``{joint: (lower, upper)}`` rad, the robot's hard limits.

    Returns:
        ``(format, clip)``: the clip's ``joint_names`` the robot's (a known alias mapped).

    Raises:
        ClipError: one line naming the file and field: no format recognises it, its reader
            refuses it, a joint of the clip no joint of the robot, a frame past a hard limit.
    """
    fmt = recognise(request.path)
    clip = fmt.read(request)
    named = tuple(robot_joint_named(n, request.robot_joints) for n in clip.joint_names)
    unknown = [n for n, r in zip(clip.joint_names, named, strict=True) if r is None]
    if unknown:
        raise ClipError(
            f"{request.path}: joint_names: joints {unknown} are no joints of '{robot_name}'"
        )
    if named != clip.joint_names:
        clip = dataclasses.replace(clip, joint_names=named)
    check_limits(request.path, named, np.asarray(clip.joint_pos), limits)
    return fmt, clip
