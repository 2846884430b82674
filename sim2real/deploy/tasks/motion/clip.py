"""A reference motion (a clip: a dance, a kick), as every clip reader returns it.

A whole-body motion-tracking policy (BeyondMimic's ``whole_body_tracking``, rl_sar's
``whole_body_tracking`` folders, unitree_rl_lab's Mimic, holosoma's WBT) is commanded by a clip
rather than a velocity. Each stack ships its clips in its own format (rl_sar's and BeyondMimic's
CSV: root position, root quaternion x y z w, joint angles per frame at a stated rate;
BeyondMimic's NPZ: ``joint_pos``, ``joint_vel``, ``body_pos_w``, ``body_quat_w``, ``fps``);
each reader turns its format into one :class:`MotionClip`, the robot's joints named, and the
motion command source plays it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim2real.robots.errors import Sim2RealError


class ClipError(Sim2RealError, ValueError):
    """A clip file that does not fit the robot or is not a clip: the message is one line that
    names the file, the field and the value expected."""


@dataclass(frozen=True)
class MotionClip:
    """One reference motion, frames at a constant rate, in the world frame of the recording.

    Attributes:
        source: The file it was read from (named by every error about it).
        fps: Frames per second, Hz (finite, > 0).
        joint_names: (J,) the robot joint of each column of ``joint_pos`` / ``joint_vel``, by the
            names of the robot's description (a reader maps a stack's motor order to names).
        joint_pos: (T, J) joint angles, rad.
        joint_vel: (T, J) joint velocities, rad/s, as the source stack computes them (its file's
            own column, or its finite difference of ``joint_pos``).
        root_pos: (T, 3) the floating base's (pelvis') position, m, world frame.
        root_quat: (T, 4) the floating base's orientation, unit quaternion ``w x y z``, world
            frame (a reader converts from ``x y z w`` where its format stores that order).
        body_names: (B,) bodies whose world poses the file carries too (BeyondMimic's NPZ); empty
            for a CSV clip.
        body_pos_w: (T, B, 3) their positions, m, world frame.
        body_quat_w: (T, B, 4) their orientations, ``w x y z``, world frame.
        stated: ``(frames, Hz)`` as the source stack states and plays the clip, where the frames
            here are not its own (holosoma's WBT ONNX: the graph's T frames, one a tick at its
            ``rl_rate``, carried here as T + 1 frames at ``rl_rate x (T + 1) / T`` Hz,
            :mod:`sim2real.deploy.tasks.motion.onnx_holosoma`); None: ``frames`` and ``fps``.
            What a report names the clip by (:attr:`shown`).

    Raises:
        ClipError: from the constructor: a field whose shape disagrees with the others, a
            non-finite value, an ``fps`` that is not a positive finite number, fewer than 2 frames.
    """

    source: Path
    fps: float
    joint_names: tuple[str, ...]
    joint_pos: np.ndarray
    joint_vel: np.ndarray
    root_pos: np.ndarray
    root_quat: np.ndarray
    body_names: tuple[str, ...] = ()
    body_pos_w: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    body_quat_w: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 4)))
    stated: tuple[int, float] | None = None

    def __post_init__(self) -> None:
        def refuse(name: str, expected: str) -> ClipError:
            return ClipError(f"{self.source}: {name}: expected {expected}")

        try:
            fps = float(self.fps)
        except (TypeError, ValueError):
            raise refuse(
                "fps", f"a positive number of frames per second, got {self.fps!r}"
            ) from None
        if not np.isfinite(fps) or fps <= 0.0:
            raise refuse("fps", f"a positive finite number of frames per second, got {self.fps!r}")
        object.__setattr__(self, "fps", fps)
        frames = np.shape(self.joint_pos)[0] if np.ndim(self.joint_pos) == 2 else -1
        joints = len(self.joint_names)
        bodies = len(self.body_names)
        shapes = {
            "joint_pos": (frames, joints),
            "joint_vel": (frames, joints),
            "root_pos": (frames, 3),
            "root_quat": (frames, 4),
        }
        if bodies:
            shapes.update(body_pos_w=(frames, bodies, 3), body_quat_w=(frames, bodies, 4))
        for name, shape in shapes.items():
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != shape:
                raise refuse(name, f"shape {shape} (frames, ...), got {value.shape}")
            bad = np.argwhere(~np.isfinite(value))
            if len(bad):
                raise refuse(
                    name, f"finite numbers, got {value[tuple(bad[0])]} at frame {bad[0][0]}"
                )
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if frames < 2:
            raise refuse("frames", f"at least 2 frames, got {max(frames, 0)}")

    @property
    def frames(self) -> int:
        """T, the number of frames."""
        return self.joint_pos.shape[0]

    @property
    def shown(self) -> tuple[int, float]:
        """``(frames, Hz)`` as its stack states them (``stated``), else ``(frames, fps)``."""
        return self.stated if self.stated is not None else (self.frames, self.fps)

    @property
    def duration(self) -> float:
        """The clip's length, s: ``(T - 1) / fps`` (its last frame's time)."""
        return (self.frames - 1) / self.fps
