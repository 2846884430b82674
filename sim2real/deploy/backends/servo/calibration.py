"""Joint calibration of a serial-bus servo arm: servo IDs, zero tick, direction, range.

A servo's position register counts encoder ticks (``resolution`` per output turn). A joint's
calibration maps them to the robot description's joint angle::

    q [rad] = direction x (ticks - zero) x 2 pi / resolution
    ticks   = clip(round(zero + direction x q x resolution / (2 pi)), range_min, range_max)

Without a calibration file (:func:`default_calibration`): servo IDs 1..n in joint order,
``zero = resolution / 2`` (2048 of 4096 ticks is 0 rad), direction +1, the full tick range.
LeRobot's calibration JSON (:func:`load_lerobot_calibration`; what ``lerobot-calibrate`` writes for
an SO-100 / SO-101) has one entry per motor name, ``{"shoulder_pan": {"id": 1, "drive_mode": 0,
"homing_offset": -1207, "range_min": 760, "range_max": 3300}, ...}``, read as LeRobot's motor bus
applies it (huggingface/lerobot, ``src/lerobot/motors/motors_bus.py`` and
``src/lerobot/motors/feetech/feetech.py``):

- ``homing_offset`` lives in the servo's Homing_Offset register (sign-magnitude, sign bit 11 on
  the STS3215) and the servo applies it itself: Present_Position = actual position -
  Homing_Offset (Feetech; Dynamixel X adds it). The backend writes it at ``open()`` and then reads
  positions already offset.
- ``range_min`` / ``range_max`` are ticks in that offset frame (LeRobot writes them to the
  Min/Max_Position_Limit registers) and LeRobot maps the range's middle to 0 degrees: here ``zero
  = (range_min + range_max) / 2``. (LeRobot scales by 4095 ticks per turn; we use the encoder's
  4096, 0.02 % apart.)
- ``drive_mode`` 1 inverts the joint's direction: here ``direction = -1``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim2real.robots.errors import Sim2RealError

#: Keys of one motor's entry in LeRobot's calibration JSON (``MotorCalibration`` fields).
LEROBOT_KEYS = ("id", "drive_mode", "homing_offset", "range_min", "range_max")


class CalibrationError(Sim2RealError, ValueError):
    """A calibration file that does not fit the robot (missing joint, bad range, bad ID)."""


@dataclass(frozen=True)
class JointCalibration:
    """Calibration of one joint's servo.

    Attributes:
        servo_id: Bus ID of the servo (1..252).
        direction: +1, or -1 when the servo turns against the joint's positive direction.
        zero: Position-register value (ticks, after the servo's homing offset) at 0 rad.
        range_min, range_max: Allowed position-register values (ticks); goals are clipped to them
            and they are written to the servo's Min/Max_Position_Limit registers when
            ``homing_offset`` is given.
        homing_offset: Value for the servo's Homing_Offset register (ticks), written at
            ``open()``; None leaves the register as it is.
        resolution: Encoder ticks per output turn.
    """

    servo_id: int
    direction: int
    zero: float
    range_min: int
    range_max: int
    homing_offset: int | None
    resolution: int

    def to_rad(self, ticks: float) -> float:
        """Position register (ticks) -> joint angle, rad."""
        return self.direction * (ticks - self.zero) * 2.0 * math.pi / self.resolution

    def to_ticks(self, angle: float) -> int:
        """Joint angle (rad) -> position register (ticks, nearest, clipped to the range)."""
        ticks = round(self.zero + self.direction * angle * self.resolution / (2.0 * math.pi))
        return int(min(max(ticks, self.range_min), self.range_max))


def default_calibration(resolutions: Sequence[int]) -> list[JointCalibration]:
    """IDs 1..n in joint order, ``resolution / 2`` ticks at 0 rad, direction +1, full range.

    Args:
        resolutions: Encoder ticks per turn of each joint's servo (n,).
    """
    return [JointCalibration(j + 1, 1, r / 2, 0, r - 1, None, r) for j, r in enumerate(resolutions)]


def load_lerobot_calibration(
    path: str | Path, joint_names: Sequence[str], resolutions: Sequence[int]
) -> list[JointCalibration]:
    """Read LeRobot's calibration JSON (module docstring) for the joints ``joint_names``.

    Args:
        path: The JSON file (a dict keyed by motor name, LeRobot's ``MotorCalibration`` fields).
        joint_names: The robot's joint names in order; each must be a key of the file (LeRobot's
            SO-101 motor names are the joint names of ``sim2real/robots/so101``).
        resolutions: Encoder ticks per turn of each joint's servo.

    Returns:
        One :class:`JointCalibration` per joint, in joint order.

    Raises:
        CalibrationError: unreadable JSON, a joint missing, a key missing or not an integer, a
            range outside ``[0, resolution)`` or empty, a duplicate ID.
        OSError: the file cannot be read.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"calibration {path}: not JSON ({exc})") from None
    if not isinstance(data, dict):
        raise CalibrationError(f"calibration {path}: expected an object keyed by motor name")
    missing = [name for name in joint_names if name not in data]
    if missing:
        raise CalibrationError(
            f"calibration {path}: no entry for joints {missing} (has {sorted(data)})"
        )
    out = []
    for name, resolution in zip(joint_names, resolutions, strict=True):
        entry = data[name]
        bad = [k for k in LEROBOT_KEYS if not isinstance(entry.get(k), int)]
        if bad:
            raise CalibrationError(
                f"calibration {path}: '{name}' needs integer {', '.join(LEROBOT_KEYS)}; "
                f"missing or not an integer: {bad}"
            )
        lo, hi = entry["range_min"], entry["range_max"]
        if not 0 <= lo < hi < resolution:
            raise CalibrationError(
                f"calibration {path}: '{name}' range [{lo}, {hi}] is not an increasing range "
                f"within [0, {resolution - 1}] ticks"
            )
        if not 1 <= entry["id"] <= 252:
            raise CalibrationError(f"calibration {path}: '{name}' id {entry['id']} not in 1..252")
        direction = -1 if entry["drive_mode"] else 1
        out.append(
            JointCalibration(
                entry["id"], direction, (lo + hi) / 2, lo, hi, entry["homing_offset"], resolution
            )
        )
    ids = [c.servo_id for c in out]
    if len(set(ids)) != len(ids):
        raise CalibrationError(f"calibration {path}: duplicate servo IDs {ids}")
    return out


def calibration_arrays(calibration: Sequence[JointCalibration]) -> dict[str, np.ndarray]:
    """The calibration as (n,) float arrays for vectorized conversion: ``direction``, ``zero``
    (ticks), ``rad_per_tick`` (2 pi / resolution), ``range_min``, ``range_max`` (ticks)."""
    return {
        "direction": np.array([c.direction for c in calibration], dtype=np.float64),
        "zero": np.array([c.zero for c in calibration], dtype=np.float64),
        "rad_per_tick": np.array([2.0 * math.pi / c.resolution for c in calibration]),
        "range_min": np.array([c.range_min for c in calibration], dtype=np.float64),
        "range_max": np.array([c.range_max for c in calibration], dtype=np.float64),
    }
