"""The clip a motion-tracking policy plays in a run: the one its contract names beside it
(rl_sar's ``motion_file``) or in its graph (holosoma's WBT export), or ``deploy-run --motion
CLIP``.

:func:`motion_for` reads it for the robot (its columns named as the contract names them, each
matched to a robot joint by name or a known alias; every frame within the robot's hard limits)
and builds the :class:`~sim2real.deploy.tasks.motion.clock.MotionClock` and the waist joints the
``tracking`` task needs (:mod:`sim2real.deploy.tasks.motion.tracking`). A policy whose spec reads
no clip plays none; one that does and has no clip is refused, never fed zeros.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from sim2real.deploy.spec.foreign.contract import MotionSource
from sim2real.deploy.spec.foreign.mapping import robot_joint_named
from sim2real.deploy.tasks.motion.clip import ClipError
from sim2real.deploy.tasks.motion.clock import STAND_S, MotionClock
from sim2real.deploy.tasks.motion.formats import ClipRequest, read_clip
from sim2real.robots.files import sha256_file

#: The blocks that read a clip (:mod:`sim2real.deploy.spec.motion_blocks`).
MOTION_BLOCKS = ("motion_command", "motion_anchor_ori_b")
#: The waist joints (yaw, roll, pitch) of a spec without an anchor block: unitree's G1 names.
WAIST_NAMES = ("waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint")


def reads_motion(spec) -> bool:
    """Whether ``spec``'s observation reads a clip."""
    return any(b.name in MOTION_BLOCKS for b in spec.observation_blocks)


def motion_for(
    policy, robot, envs: int, path=None, playback: str = "stand", fps=None, stand_s=STAND_S,
    rest_s: float = 10.0,
):  # fmt: skip
    """``(MotionClock, waist joint indices)`` of ``policy`` on ``robot``, or None when its spec
    reads no clip and none is given.

    Args:
        policy: The loaded policy (``spec``; ``foreign``: its stack's contract, whose
            ``motion`` names the clip and its rate; ``metadata``: the export's ``motion`` entry,
            whose sha256 the clip is checked against).
        robot: The robot. envs: Batch size.
        path: The clip in place of the contract's, any format of
            :func:`~sim2real.deploy.tasks.motion.formats.clip_formats` (rl_sar CSV, BeyondMimic
            or holosoma NPZ, a motion inside a holosoma or BeyondMimic ONNX).
        playback: ``stand`` (to the robot's home pose over ``stand_s`` s after the clip),
            ``once``, ``loop``, ``hold``.
        fps: Hz, in place of the contract's rate (for a file that states none).
        rest_s: s at home between an ``exhibition``'s plays.

    Raises:
        ClipError: one line naming the file and field: no clip for a spec that reads one, a clip
            for a spec that reads none, a column no joint of the robot, a rate not a positive
            number, a frame past a hard limit, a file no clip format recognises (naming the
            formats known).
    """
    foreign = getattr(policy, "foreign", None)
    source = getattr(foreign, "motion", None) or _exported_motion(policy)
    if not reads_motion(policy.spec):
        if path is not None:
            raise ClipError(f"{path}: --motion: the policy's observation reads no clip")
        return None
    where = getattr(foreign, "source", None) or "the policy's spec"
    if path is None and source is None:
        raise ClipError(
            f"{where}: motion_file: the policy's observation reads a reference motion and its "
            "contract names none: give deploy-run --motion CLIP"
        )
    path = Path(path if path is not None else source.file)
    columns = None
    if source is not None:
        columns = tuple(robot_joint_named(n, robot.joint_names) for n in source.columns)
        unknown = [n for n, r in zip(source.columns, columns, strict=True) if r is None]
        if unknown:
            raise ClipError(f"{path}: columns: joints {unknown} are no joints of '{robot.name}'")
    limits = {
        n: (float(robot.position_lower[i]), float(robot.position_upper[i]))
        for i, n in enumerate(robot.joint_names)
    }
    request = ClipRequest(
        path=path,
        fps=fps if fps is not None else getattr(source, "fps", None),
        fps_flag=fps is not None,
        columns=columns,
        metadata_joints=_metadata_joints(policy),
        robot_joints=tuple(robot.joint_names),
    )
    _, clip = read_clip(request, robot.name, limits)
    _check_hash(policy, path)
    anchor = next((b for b in policy.spec.observation_blocks if b.name == MOTION_BLOCKS[1]), None)
    if anchor is not None:
        waist = tuple(anchor.joints)
    else:
        missing = [n for n in WAIST_NAMES if n not in robot.joint_names]
        if missing:
            raise ClipError(f"{path}: waist: the robot has no joints {missing}")
        waist = tuple(robot.joint_names.index(n) for n in WAIST_NAMES)
    names = tuple(robot.joint_names[i] for i in waist)
    clock = MotionClock(clip, robot.joint_names, names, envs, playback, robot.home, stand_s, rest_s)
    return clock, waist


def _exported_motion(policy) -> MotionSource | None:
    """The clip an export whose spec is stored names in its ``motion`` metadata (``policy-export``
    of a tracking ONNX: :func:`sim2real.deploy.export.folder_torchscript.motion_metadata`), the
    file beside the policy; None: no such entry.

    Raises:
        ClipError: an entry that is not JSON or lacks ``file``, ``fps`` or ``columns``.
    """
    entry = getattr(policy, "metadata", {}).get("motion")
    path = getattr(policy, "path", None)
    if not entry or path is None:
        return None
    try:
        recorded = json.loads(entry)
        return MotionSource(
            str(Path(path).parent / recorded["file"]),
            recorded["fps"],
            tuple(recorded["columns"]),
            recorded.get("timing", "rl_sar"),
            f"the export's motion metadata ({recorded['file']} beside {Path(path).name})",
        )
    except (ValueError, KeyError, TypeError) as exc:
        raise ClipError(
            f"{path}: metadata 'motion': expected JSON with file, fps and columns (policy-export "
            f"writes them), got {exc!r}"
        ) from None


def _metadata_joints(policy) -> tuple[str, ...] | None:
    """The policy file's ``joint_names`` metadata (Isaac Lab's exports: comma-joined), or None."""
    value = getattr(policy, "metadata", {}).get("joint_names")
    if not value or not isinstance(value, str) or value.lstrip().startswith("["):
        return None
    return tuple(n.strip() for n in value.split(","))


def _check_hash(policy, path: Path) -> None:
    """Warn (stderr) when the clip is not the one the export hashed (its ``motion`` metadata)."""
    entry = getattr(policy, "metadata", {}).get("motion")
    if not entry:
        return
    recorded = json.loads(entry)
    if recorded.get("file") == path.name and recorded.get("sha256") != sha256_file(path):
        print(
            f"deploy-run: warning: {path}: not the clip policy-export hashed "
            f"(sha256 {recorded.get('sha256', '')[:12]}...): it changed since",
            file=sys.stderr,
        )
