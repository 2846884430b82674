"""When the runtime may call a joint at rest: not below what its estimator can resolve.

The runtime ends RAMP_IN and a safe stop when every joint's *estimated* speed is below a rest
speed. The estimate of a joint at rest is not zero: it carries the encoder's noise through the
filter. At the arms' default encoder noise the largest estimated speed of an arm at rest lies above
``REST_SPEED`` on most ticks (docs/measurements.md), so those transitions waited for a lucky
tick, and a safe stop ended by its timeout.

:func:`rest_speed` is therefore ``REST_SPEED`` or :data:`REST_SIGMAS` times the filter's own
steady-state velocity standard deviation (:func:`steady_velocity_sigma`, the largest over the
joints), whichever is larger. The drives of the legged robots report their velocity: their
filters resolve less than ``REST_SPEED`` and keep it.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.modes import REST_SPEED
from sim2real.deploy.core.state import RobotState
from sim2real.robots import Robot

#: Standard deviations of the filter's steady-state velocity below which an estimated speed is
#: indistinguishable from rest (our choice). The filter's variance assumes white acceleration of
#: half the acceleration limit (``PROCESS_NOISE_FRACTION``), which a joint at rest has not: the
#: measured spread of its estimate at rest is about half to two thirds of that standard deviation
#: (docs/measurements.md), so two of them are nearly three measured ones.
REST_SIGMAS = 2.0

#: Readings the probe filter absorbs at most before its covariance has settled; it stops when
#: the velocity variance changes by less than :data:`_SETTLED` (relative) from one to the next.
_MAX_READINGS = 20000
_SETTLED = 1e-12


def steady_velocity_sigma(robot: Robot) -> np.ndarray:
    """(n,) rad/s, the steady-state posterior velocity standard deviation of the runtime's joint
    filter (``JointStateEstimator(robot, envs)``, its defaults), reading every joint each
    ``max(control_period, 1 / encoder_rate)`` s with no latency (and the drives' velocity where
    robot.toml has ``velocity_noise_sigma``).

    Found by running that filter itself (a one-env probe, the compiled kernel) on a joint at
    rest until ``sqrt(P[1, 1])`` settles; its covariance does not depend on the readings' values.
    """
    from sim2real.deploy.estimation.joints import JointStateEstimator  # joints imports tuning

    n = robot.n_joints
    sensors = robot.config.sensors
    period = max(robot.control_period, 1.0 / sensors.encoder_rate)
    probe = JointStateEstimator(robot, 1)
    probe.reset(np.zeros(n), 0.0)
    frame = SensorFrame.empty(1, n)
    frame.position[:] = 0.0
    if sensors.velocity_noise_sigma is not None:
        frame.velocity[:] = 0.0
    state = RobotState.zeros(1, n)
    last = probe.covariance[0, :, 1, 1].copy()
    for k in range(1, _MAX_READINGS + 1):
        frame.time[:] = k * period
        frame.position_stamp[:] = k * period
        probe.update(frame, state)
        now = probe.covariance[0, :, 1, 1]
        if np.all(np.abs(now - last) <= _SETTLED * now):
            break
        last = now.copy()
    return np.sqrt(probe.covariance[0, :, 1, 1].copy())


def rest_speed(robot: Robot) -> float:
    """rad/s, the speed below which every joint's estimate must be for the runtime to call the
    robot at rest (the end of RAMP_IN, of a safe stop): ``max(REST_SPEED, REST_SIGMAS *
    max(steady_velocity_sigma(robot)))`` (module docstring). so101 0.42, arm3 0.33, arm6 0.17,
    ur5 0.26 rad/s; go2, go2w, h1, h1_2 ``REST_SPEED``."""
    return float(max(REST_SPEED, REST_SIGMAS * steady_velocity_sigma(robot).max()))
