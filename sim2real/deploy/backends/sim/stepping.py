"""The physics steps of one control period of the MuJoCo plant, each env's model computing its
sensors only in the step whose readings the plant reads.

The plant reads ``sensordata`` once per control period, after its ``decimation`` steps
(:class:`sim2real.deploy.backends.sim.legged_sensors.BaseSensorModel`): MuJoCo computes the
sensors in the forward pass at the start of each step, so what it reads is the last step's.
The sensors of the steps before are overwritten unread, and the acceleration-stage ones (a
legged robot's touch and accelerometer) cost a pass of ``mj_rnePostConstraint`` each step. So
every step but the last runs with ``mjDSBL_SENSOR`` set in the env's ``opt.disableflags``
(restored before the last step, and on any error). The sensors are outputs only: the
dynamics, and the readings of the last step, are the same bit for bit
(``tests/test_stepping.py``). A model without sensors steps as before; so does a model whose
readings depend on earlier steps (:func:`quiet_sensors`: a sensor's delay, sampling interval or
history, a plugin or user sensor), and every model on a MuJoCo without the flag.
"""

from __future__ import annotations

import mujoco
import numpy as np

#: MuJoCo's flag that skips the sensors in a forward pass (0: this MuJoCo has none).
SENSORS_OFF = int(getattr(mujoco.mjtDisableBit, "mjDSBL_SENSOR", 0))


def quiet_sensors(m: mujoco.MjModel) -> bool:
    """Whether ``m``'s sensors may skip every step of a period but the last: this MuJoCo has
    the flag, ``m`` has sensors, and each reading is the last step's alone (no sensor with a
    delay, a sampling interval or a history of samples, no plugin, no user sensor, whose
    callback may keep a state). Raises nothing."""
    if not SENSORS_OFF or m.nsensor == 0:
        return False
    for name in ("sensor_delay", "sensor_interval", "sensor_history"):  # MuJoCo 3.4 and later
        if np.any(getattr(m, name, 0)):
            return False
    return not (
        np.any(m.sensor_plugin >= 0) or np.any(m.sensor_type == mujoco.mjtSensor.mjSENS_USER)
    )


def step_period(views, quiet, nstep: int, substep=None, tick: int = 0) -> None:
    """``nstep`` physics steps of every env of ``views`` (the plant's per-env tuples, model and
    data first), the sensors computed in the last one only where ``quiet[e]`` (each env's
    :func:`quiet_sensors` of its model; module docstring). With
    ``substep`` (``substep(e, tick, sub)``, the actuators' compiled call before each step:
    delayed commands, a torque range that follows the joint speed) one step at a time, else one
    ``mj_step`` call of ``nstep - 1`` steps and one of the last. Raises what ``mj_step``
    raises (``mujoco.FatalError``), the flags restored."""
    step = mujoco.mj_step
    for e, view in enumerate(views):
        m, d = view[0], view[1]
        if not (quiet[e] and nstep > 1):  # as MuJoCo steps it
            if substep is None:
                step(m, d, nstep=nstep)
                continue
            for sub in range(nstep):
                substep(e, tick, sub)
                step(m, d)
            continue
        opt = m.opt
        flags = opt.disableflags
        opt.disableflags = flags | SENSORS_OFF
        try:
            if substep is None:
                step(m, d, nstep=nstep - 1)
                opt.disableflags = flags
                step(m, d)
                continue
            for sub in range(nstep):
                substep(e, tick, sub)
                if sub == nstep - 1:
                    opt.disableflags = flags
                step(m, d)
        finally:
            opt.disableflags = flags
