"""The soak batch's per-env thermal and speed accumulators (:class:`BatchStats`), updated every
tick and kept by the checkpoints (``stats/<name>``)."""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.stateful import put, take
from sim2real.deploy.monitors.kernel import temperature_bands

#: The accumulators a checkpoint keeps (``stats/<name>``).
STATS = ("peak", "window_peak", "band_ticks", "over_ticks", "speed_peak")


class BatchStats:
    """The accumulators (:data:`STATS`) of ``backend``'s envs, as a stage of a checkpoint
    (:mod:`sim2real.deploy.core.stateful`).

    Attributes (each (envs, n), n the robot's joints):
        peak: degC, each winding's peak (from its temperature at the start).
        window_peak: degC, the peak since the last curve point (the batch resets it).
        band_ticks: ticks in the derating band (the motor's derating start and above).
        over_ticks: ticks over the motor's maximum winding temperature.
        speed_peak: rad/s, each joint's largest true speed (a wheel's against its limit).
    """

    def __init__(self, backend, robot):
        self.peak = backend.thermal.winding_temperature.copy()
        envs, n = self.peak.shape
        self.window_peak = self.peak.copy()
        self.band_ticks = np.zeros((envs, n), dtype=np.int64)
        self.over_ticks = np.zeros((envs, n), dtype=np.int64)
        self.speed_peak, self._speed = np.zeros((envs, n)), np.zeros((envs, n))
        self._t_start = np.array([m.derating_start_temperature for m in robot.motors])
        self._t_max = np.array([m.max_winding_temperature for m in robot.motors])

    def update(self, backend) -> None:
        """One tick: the windings' temperatures and the true joint speeds of ``backend``."""
        temperature_bands(
            backend.thermal.winding_temperature,
            self._t_start,
            self._t_max,
            self.peak,
            self.window_peak,
            self.band_ticks,
            self.over_ticks,
        )
        np.abs(backend.true_velocity(), out=self._speed)
        np.maximum(self.speed_peak, self._speed, out=self.speed_peak)

    def _fields(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in STATS}

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        return take(self._fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        put(self._fields(), state, env)
