"""rl_sar's and BeyondMimic's CSV clip: one frame per row, no header.

Columns (fan-ziqi/rl_sar ``MotionLoader::LoadFromCSV``; BeyondMimic's ``csv_to_npz.py`` input):
root position x y z, m; root quaternion x y z w; then one joint angle per column, rad, in the
order the stack names (rl_sar: the SDK's motor order, its base.yaml ``joint_names``). The rate
is the stack's, not the file's (rl_sar plays its clip at the control rate ``1 / (dt x
decimation)``, whatever its name says). Joint velocities are rl_sar's ``ComputeVelocities``:
the forward difference ``(q[i+1] - q[i]) x fps``, the last frame repeating the one before.

Where rl_sar warns and reads 0 for a cell that is not a number, and skips a short row, this
reader refuses the file naming the row and column: a clip is never zeroed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim2real.deploy.tasks.motion.clip import ClipError, MotionClip

#: Columns before the joints: root position (3) and quaternion x y z w (4).
ROOT_COLUMNS = 7


def parse_rate(value, source) -> float:
    """``value`` as a positive finite rate, Hz.

    Raises:
        ClipError: ``"<source>: fps: expected a positive number of frames per second, got .."``.
    """
    try:
        fps = float(value)
    except (TypeError, ValueError):
        fps = float("nan")
    if isinstance(value, bool) or not np.isfinite(fps) or fps <= 0.0:
        raise ClipError(
            f"{source}: fps: expected a positive number of frames per second, got {value!r}"
        )
    return fps


def forward_difference(joint_pos: np.ndarray, fps: float) -> np.ndarray:
    """(T, J) rad/s: rl_sar's ``ComputeVelocities`` of ``joint_pos`` (T, J) rad at ``fps`` Hz:
    ``(q[i + 1] - q[i]) * fps`` for ``i < T - 1``, the last row the one before it."""
    vel = np.empty_like(joint_pos, dtype=float)
    vel[:-1] = (joint_pos[1:] - joint_pos[:-1]) * fps
    vel[-1] = vel[-2]
    return vel


def read_csv_clip(
    path: str | Path,
    columns: tuple[str, ...],
    fps,
    limits: dict[str, tuple[float, float]] | None = None,
) -> MotionClip:
    """The clip in the CSV ``path`` (module docstring).

    Args:
        path: The CSV file.
        columns: The joint of each joint column, by the robot's names (J,).
        fps: The rate its frames play at, Hz (the contract's).
        limits: Optional hard limits ``{joint: (lower, upper)}``, rad (robot.toml): a frame past
            one is refused.

    Returns:
        A :class:`~sim2real.deploy.tasks.motion.clip.MotionClip`: the joints in ``columns``'
        order, root quaternion reordered to ``w x y z``, velocities by forward difference.

    Raises:
        ClipError: one line naming the file and field: not readable, a cell not a number, a
            row whose joint count is not ``len(columns)``, a rate that is not a positive number,
            a frame past a joint's hard limit, fewer than 2 frames.
    """
    path = Path(path)
    fps = parse_rate(fps, path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ClipError(f"{path}: cannot read the clip: {exc}") from None
    width = ROOT_COLUMNS + len(columns)
    rows = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) != width:
            raise ClipError(
                f"{path}: row {i + 1}: expected {width} columns (root position 3, quaternion "
                f"x y z w 4, {len(columns)} joints), got {len(cells)} "
                f"({len(cells) - ROOT_COLUMNS} joints)"
            )
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            bad = next(j for j, c in enumerate(cells) if not _number(c))
            raise ClipError(
                f"{path}: row {i + 1} column {bad + 1}: expected a number, got {cells[bad]!r}"
            ) from None
    data = np.asarray(rows, dtype=float).reshape(-1, width)
    joint_pos = data[:, ROOT_COLUMNS:]
    if limits:
        check_limits(path, columns, joint_pos, limits)
    return MotionClip(
        source=path,
        fps=fps,
        joint_names=tuple(columns),
        joint_pos=joint_pos,
        joint_vel=forward_difference(joint_pos, fps) if len(joint_pos) > 1 else joint_pos,
        root_pos=data[:, :3],
        root_quat=data[:, [6, 3, 4, 5]],  # x y z w -> w x y z
    )


def _number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def check_limits(path, columns, joint_pos: np.ndarray, limits: dict) -> None:
    """Refuse the first frame of ``joint_pos`` (T, J) past a joint's ``limits`` (rad).

    Raises:
        ClipError: ``"<path>: frame F joint NAME: A rad is past its hard limit [lo, hi]"``.
    """
    for j, name in enumerate(columns):
        if name not in limits:
            continue
        lo, hi = limits[name]
        past = np.flatnonzero((joint_pos[:, j] < lo) | (joint_pos[:, j] > hi))
        if len(past):
            f = int(past[0])
            raise ClipError(
                f"{path}: frame {f} joint {name}: {joint_pos[f, j]:.4f} rad is past its hard "
                f"limit [{lo:.4f}, {hi:.4f}] (robot.toml)"
            )
