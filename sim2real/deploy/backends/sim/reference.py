"""The numpy reference of the plant's encoder kernels (:mod:`sim2real.deploy.backends.sim.sensors_kernel`):
:class:`ReferenceJointSensorModel`, a :class:`~sim2real.deploy.backends.sim.sensors.JointSensorModel` with
the same constructor whose sampling and reading run in numpy. It gives the same readings and
stamps and draws the same numbers from the streams (``tests/test_sim_plant.py``).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.sim.sensors import JointSensorModel


class ReferenceJointSensorModel(JointSensorModel):
    """A :class:`~sim2real.deploy.backends.sim.sensors.JointSensorModel` whose encoder arithmetic runs in
    numpy (module docstring); the same arguments and attributes."""

    def _encode(self, sample: np.ndarray, q: np.ndarray) -> None:
        """:func:`sim2real.deploy.backends.sim.sensors_kernel.encoder_sample` in numpy."""
        sample *= self.noise_sigma[:, None]
        sample += q
        np.round(sample / self.encoder_quantum, out=sample)
        sample *= self.encoder_quantum
        sample[self._uniform < self.dropout_probability[:, None]] = np.nan

    def read(self, tick: int) -> None:
        """:meth:`JointSensorModel.read` in numpy (the reference of
        :func:`sim2real.deploy.backends.sim.sensors_kernel.encoder_read`)."""
        f = self.frame
        origin = tick - self.latency_ticks  # tick at which the arriving reading was sampled
        slot = origin % self._buf_stamp.shape[0]
        f.position[:] = self._buf_position[slot, self._env_index]
        f.position_stamp[:] = self._buf_stamp[slot, self._env_index][:, None]
        too_early = origin < 0
        if too_early.any():
            f.position[too_early] = np.nan
            f.position_stamp[too_early] = np.nan
        f.position_stamp[np.isnan(f.position)] = np.nan
