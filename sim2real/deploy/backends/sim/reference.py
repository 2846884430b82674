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


def reference_advance(plant) -> None:
    """:meth:`SimBackend.advance <sim2real.deploy.backends.sim.plant.SimBackend.advance>` as
    Python calls per env and per model (the path before its compiled step, whose tested
    reference it is): the derating, the commands or the actuators per physics step, the joint
    state, the divergence check, the anti-windup, the thermal step, the sensors.

    Raises:
        SimulationDivergedError: MuJoCo flagged a bad state in some env.
    """
    import mujoco

    command, torque, qpos = plant._command, plant._torque, plant._qpos
    plant._derate_drives()
    actuators = plant.actuators if plant.actuators.active else None
    if actuators is not None:
        actuators.start_period(plant.tick, command, plant.thermal.winding_temperature)
    for e, (m, d, ctrl, q, force, warnings) in enumerate(plant._views):
        if actuators is None:
            ctrl[:] = command[e]
            mujoco.mj_step(m, d, nstep=plant.decimation)
        else:
            qvel, limit, out = plant._qvel_views[e], plant.effort_limit[e], plant._actfrc[e]
            for sub in range(plant.decimation):
                actuators.before_step(e, sub, ctrl, qvel, limit, out)
                mujoco.mj_step(m, d)
        if np.count_nonzero(warnings):
            plant._check_divergence(e, d)
        torque[e] = force
        qpos[e] = q
    if not np.isfinite(qpos).all():
        for e, d in enumerate(plant.datas):
            plant._check_divergence(e, d)
    if plant.mode == "velocity":
        plant._anti_windup()
    plant.tick += 1
    plant.thermal.step(plant._torque, plant.control_period)
    plant._sample_sensors()
