"""Kernels of the simulated drives' per-tick checks (:class:`sim2real.deploy.backends.sim.plant.SimBackend`):
which envs' torque limits follow a hot winding (:func:`derating_due`) and the velocity loop's
anti-windup screen (:func:`windup_exceeded`). Each answers whether Python must act; the action
(setting MuJoCo's limits, clamping the setpoints) stays in the backend.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, _nrt=False)
def derating_due(
    winding: np.ndarray, start: np.ndarray, derated: np.ndarray, hot: np.ndarray
) -> bool:
    """Which envs a drive derates in: ``hot[e]`` (written, (envs,) bool) is whether any winding
    of env ``e`` (``winding`` (envs, n) degC) is above its derating start (``start`` (n,) degC);
    returns whether any env is hot or was derated before (``derated`` (envs,) bool), the
    envs whose torque limits must be set."""
    envs, n = winding.shape
    due = False
    for e in range(envs):
        h = False
        for j in range(n):
            if winding[e, j] > start[j]:
                h = True
                break
        hot[e] = h
        due = due or h or derated[e]
    return due


@numba.njit(cache=True, nogil=True, _nrt=False)
def windup_exceeded(setpoint: np.ndarray, q: np.ndarray, bound: np.ndarray) -> bool:
    """Velocity-mode anti-windup screen: turns ``setpoint`` (envs, n) rad, the drives' integrated
    setpoints, into their lag ``setpoint - q`` (in place) and returns whether any ``|lag|``
    exceeds ``bound`` (envs, n) rad (the present torque limit over the gain)."""
    envs, n = setpoint.shape
    wound = False
    for e in range(envs):
        for j in range(n):
            lag = setpoint[e, j] - q[e, j]
            setpoint[e, j] = lag
            if abs(lag) > bound[e, j]:
                wound = True
    return wound


@numba.njit(cache=True, nogil=True, _nrt=False)
def torque_speed_range(
    velocity: np.ndarray,
    limit: np.ndarray,
    stall: np.ndarray,
    no_load: np.ndarray,
    active: np.ndarray,
    out: np.ndarray,
) -> None:
    """One env's actuator torque range from its motors' torque-speed lines
    (:class:`sim2real.robots.torque_speed.TorqueSpeedEnvelope`, its ``limits`` the numpy reference):
    ``out`` (n, 2) N m, MuJoCo's ``jnt_actfrcrange`` rows of the joints, from the joint
    ``velocity`` (n,) rad/s, the current ``limit`` (n,) N m, the ``stall`` torque (n,) N m at
    the windings' temperature and the ``no_load`` speed (n,) rad/s; the limit alone where
    ``active`` (n,) is False."""
    for j in range(velocity.shape[0]):
        if not active[j]:
            out[j, 0] = -limit[j]
            out[j, 1] = limit[j]
            continue
        w = velocity[j] / no_load[j]
        upper = min(limit[j], stall[j] * (1.0 - w))
        lower = max(-limit[j], -stall[j] * (1.0 + w))
        out[j, 0] = lower
        out[j, 1] = max(upper, lower)


@numba.njit(cache=True, nogil=True, _nrt=False)
def actuator_step(
    history: np.ndarray,
    tick: int,
    sub: int,
    nstep: int,
    delay: np.ndarray,
    ctrl: np.ndarray,
    velocity: np.ndarray,
    limit: np.ndarray,
    stall: np.ndarray,
    no_load: np.ndarray,
    active: np.ndarray,
    out: np.ndarray,
) -> None:
    """One env's actuators before physics step ``sub`` (of ``nstep``) of control tick ``tick``
    (:class:`sim2real.deploy.backends.sim.actuators.ActuatorModel`): each joint's command ``delay`` (n,)
    physics steps old, from ``history`` (depth, n) (row ``t % depth`` the command of tick
    ``t``), into every row of ``ctrl`` (actuators per joint, n); and its torque range
    (:func:`torque_speed_range`) into ``out`` (n, 2)."""
    depth, n = history.shape
    for j in range(n):
        age = delay[j] - sub
        back = 0 if age <= 0 else (age + nstep - 1) // nstep
        u = history[(tick - back) % depth, j]
        for r in range(ctrl.shape[0]):
            ctrl[r, j] = u
    torque_speed_range(velocity, limit, stall, no_load, active, out)
