"""The backend interface: what the runtime reads from and writes to, simulated or real."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np


@dataclass
class SensorFrame:
    """One read of the robot's proprioceptive sensors, for a batch of ``envs`` robots.

    A backend reuses one frame and overwrites it on every read: copy what you keep.

    Attributes:
        time: (envs,) s, backend clock when the frame was read.
        position: (envs, n_joints) rad, encoder readings that arrived in this frame, quantized and
            noisy; NaN where no reading arrived (dropout, or a sensor slower than the control rate).
        position_stamp: (envs, n_joints) s, when each reading was sampled (earlier than ``time``
            by the sensor latency); NaN where ``position`` is NaN.
        winding_temperature: (envs, n_joints) degC, as the drive reports it (quantized, at the
            drive's reporting rate: the last reported value is repeated in between).
        temperature_stamp: (envs,) s, when ``winding_temperature`` was last sampled.
    """

    time: np.ndarray
    position: np.ndarray
    position_stamp: np.ndarray
    winding_temperature: np.ndarray
    temperature_stamp: np.ndarray

    @classmethod
    def empty(cls, envs: int, n_joints: int) -> SensorFrame:
        nan = np.full((envs, n_joints), np.nan)
        return cls(
            time=np.zeros(envs),
            position=nan.copy(),
            position_stamp=nan.copy(),
            winding_temperature=nan.copy(),
            temperature_stamp=np.full(envs, np.nan),
        )


class Backend(Protocol):
    """What the runtime needs of a robot: read, write, advance. Arrays are (envs, n_joints)."""

    envs: int
    mode: str

    def read(self) -> SensorFrame: ...

    def write(self, command: np.ndarray) -> None: ...

    def advance(self) -> None: ...
