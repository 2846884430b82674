"""Kernel of the plant's motor thermal model (:meth:`sim2real.robots.thermal.TwoNodeThermalModel.step`).

One call advances every (env, joint) winding and housing node by one explicit Euler step, with the
arithmetic of the numpy reference (:meth:`~sim2real.robots.thermal.TwoNodeThermalModel.step_reference`) in
its order, so both give the same temperatures bit for bit (``tests/test_thermal.py``).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, _nrt=False)
def thermal_step(
    joint_torque: np.ndarray,
    dt: float,
    constants: np.ndarray,
    ambient: np.ndarray,
    winding: np.ndarray,
    housing: np.ndarray,
    current: np.ndarray,
    power: np.ndarray,
    flow: np.ndarray,
) -> None:
    """Advance the temperatures by ``dt`` s under ``joint_torque`` (envs, n) N m.

    Args:
        constants: (8, n) per joint: torque per amp (N m/A), ``T_ref`` (degC), ``alpha`` (1/K),
            ``R_ref`` (ohm), ``R_wh``, ``R_ha`` (K/W), ``C_w``, ``C_h`` (J/K), in that order.
        ambient: (envs, n) degC.
        winding, housing: (envs, n) degC, updated. current (A), power (W), flow (W): (envs, n),
            written (the last step's values).
    """
    envs, n = joint_torque.shape
    for j in range(n):
        per_amp, t_ref, alpha, r_ref = (
            constants[0, j],
            constants[1, j],
            constants[2, j],
            constants[3, j],
        )
        r_wh, r_ha = constants[4, j], constants[5, j]
        k_w, k_h = dt / constants[6, j], dt / constants[7, j]
        for e in range(envs):
            i = abs(joint_torque[e, j]) / per_amp
            p = (winding[e, j] - t_ref) * alpha
            p += 1.0
            p *= r_ref
            p *= i
            p *= i
            f = (winding[e, j] - housing[e, j]) / r_wh
            winding[e, j] += (p - f) * k_w
            f -= (housing[e, j] - ambient[e, j]) / r_ha
            housing[e, j] += f * k_h
            current[e, j] = i
            power[e, j] = p
            flow[e, j] = f
