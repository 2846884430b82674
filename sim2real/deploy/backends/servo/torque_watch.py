"""When a servo-bus backend reads Torque_Enable back, and what a servo found off means.

A servo switches its own torque off on a fault (``ServoModel.torque_off_on``) and says so in its
status error byte (Feetech) or Hardware_Error_Status (Dynamixel). A Feetech servo clears its
overheat bit once the winding has cooled below its limit, which with the torque off takes moments:
a host that read no status in that window never sees the bit, and a runtime ending its safe stop
would drive the arm with that joint limp. So while the host has the torque on, the backend reads
Torque_Enable of every servo (one SYNC READ of one byte):

- every ``TORQUE_CHECK_PERIOD`` s, at the first read after it that was not slow (a read that
  took over half its timeout: the bus or the host is late this tick, and the check would push
  the tick past its period), and
- at the first read at which every temperature reading is below its motor's derating start
  after one was not: the condition on which the runtime ends a thermal safe stop (it takes the
  readings as its winding temperatures), so the check comes in that tick, before the runtime
  can resume. A reply lost in that check is found at the next periodic one.

A servo found off that reports no hardware error is a drive error of its own, ``TORQUE_OFF``
(a bit above the vendors' 8-bit error bytes): the runtime makes a safe stop of it (``servo_error``)
and does not resume.
"""

from __future__ import annotations

import numpy as np

from sim2real.robots import Robot

#: Drive error bit of a servo found with its torque off while the host had it on (not a vendor
#: bit: both vendors' error bytes are 8 bits wide).
TORQUE_OFF = 1 << 8
#: s between two reads of Torque_Enable (our choice: a fraction of the seconds a winding takes to
#: cool from the servo's cut-off to the derating start, short enough that a limp joint is found
#: while the arm has barely moved, long enough that the extra read is a small share of the bus).
TORQUE_CHECK_PERIOD = 0.25


class TorqueWatch:
    """Schedules the reads of Torque_Enable and keeps what explains a servo found off.

    Args:
        robot: The robot: its control period, each motor's ``derating_start_temperature`` (degC)
            and protection ``temperature_limit`` (degC, the cut-off written to the servo at open).

    Attributes:
        every: Reads between two periodic checks (``TORQUE_CHECK_PERIOD`` / control period, >= 1).
        peak: (n,) degC, the highest temperature read of each servo since :meth:`restart`.
    """

    def __init__(self, robot: Robot):
        self.every = max(1, round(TORQUE_CHECK_PERIOD / robot.control_period))
        motors = robot.motors
        self.cool_below = np.array([m.derating_start_temperature for m in motors], dtype=float)
        self.limit = np.array(
            [np.nan if m.protection is None else m.protection.temperature_limit for m in motors],
            dtype=float,
        )
        self.peak = np.full(robot.n_joints, -np.inf)
        self._reads = 0
        self._warm = False  # a reading at or above its derating start since the last check

    def restart(self) -> None:
        """The host has just switched the torque on: a new watch."""
        self.peak.fill(-np.inf)
        self._reads = 0
        self._warm = False

    def due(self, temperature: np.ndarray, slow: bool = False) -> bool:
        """Whether to check at this read; ``temperature`` (n,) degC, the readings (NaN: never
        read); ``slow``: this read took over half its timeout (a periodic check waits)."""
        np.fmax(self.peak, temperature, out=self.peak)
        self._reads += 1
        cool = bool((temperature < self.cool_below).all())
        self._warm |= not cool
        if (self._reads >= self.every and not slow) or (cool and self._warm):
            self._reads = 0
            self._warm = not cool
            return True
        return False

    def describe(self, joint: int) -> str:
        """What a ``TORQUE_OFF`` of ``joint`` means; an overheat shutdown is named where the
        servo was read within 1 degC of its cut-off (it reports whole degrees)."""
        text = "torque off by the servo while commanded on"
        peak, limit = self.peak[joint], self.limit[joint]
        if np.isfinite(peak) and np.isfinite(limit) and peak >= limit - 1.0:
            text += f" (read {peak:.0f} degC, cut-off {limit:.0f} degC: an overheat shutdown)"
        return text
