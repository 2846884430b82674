"""The numpy reference of the plant's encoder kernels (:mod:`sim2real.deploy.backends.sim.sensors_kernel`):
:class:`ReferenceJointSensorModel`, a :class:`~sim2real.deploy.backends.sim.sensors.JointSensorModel` with
the same constructor whose sampling and reading run in numpy. It gives the same readings and
stamps and draws the same numbers from the streams (``tests/test_sim_plant.py``); and
:func:`reference_advance`, the plant's control period as Python calls per env, the reference of
its compiled step (:mod:`sim2real.deploy.backends.sim.plant_kernel`).
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
        if self.has_velocity:  # the velocity reported with each angle read
            f.velocity[:] = self._buf_velocity[slot, self._env_index]
            f.velocity[too_early] = np.nan


def reference_advance(plant) -> None:
    """:meth:`SimBackend.advance <sim2real.deploy.backends.sim.plant.SimBackend.advance>` as
    Python calls per env and per model (the path before its compiled step, whose tested
    reference it is), through the plant's public interface (``kernel_arrays``, ``env_views``
    and its step methods): the derating, the commands or the actuators per physics step, the
    joint state, the divergence check, the anti-windup, the thermal step, the sensors.

    Raises:
        SimulationDivergedError: MuJoCo flagged a bad state in some env.
    """
    import mujoco

    arrays = plant.kernel_arrays()
    command, torque, qpos = arrays["command"], arrays["torque"], arrays["qpos"]
    plant.drives.derate(plant.thermal.winding_temperature)
    actuators = plant.actuators if plant.actuators.active else None
    if actuators is not None:
        actuators.start_period(plant.tick, command, plant.thermal.winding_temperature)
    for e in range(plant.envs):
        v = plant.env_views(e)
        m, d, ctrl = v["model"], v["data"], v["ctrl"]
        if actuators is None:
            ctrl[:] = command[e]
            mujoco.mj_step(m, d, nstep=plant.decimation)
        else:
            qvel, limit, out = v["qvel"], plant.effort_limit[e], v["actfrc"]
            for sub in range(plant.decimation):
                actuators.before_step(e, sub, ctrl, qvel, limit, out)
                mujoco.mj_step(m, d)
        if np.count_nonzero(v["warnings"]):
            plant.check_divergence(e)
        torque[e] = v["force"]
        qpos[e] = v["qpos"]
    if not np.isfinite(qpos).all():
        for e in range(plant.envs):
            plant.check_divergence(e)
    if plant.mode == "velocity":
        plant.drives.anti_windup(qpos)
    plant.tick += 1
    plant.thermal.step(torque, plant.control_period)
    plant.sample_sensors()
