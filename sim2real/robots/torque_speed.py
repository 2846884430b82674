"""A DC motor's torque-speed envelope at the joint: the torque its drive can deliver at a speed.

A brushed or field-oriented brushless motor on a supply of voltage ``V`` draws the current
``I = (V - k_e w_m) / R`` at rotor speed ``w_m`` (back-EMF constant ``k_e``, equal to the torque
constant ``k_t`` in SI units; winding resistance ``R``). Through a gear of ratio ``N`` and
efficiency ``eta``, at the joint speed ``w`` the torque the supply allows is the line

    tau(w) = tau_stall (1 - w / w_0),   tau_stall = w_0 k_t^2 N^2 eta / R,

from the stall torque at rest to zero at the no-load speed ``w_0 = V / (k_e N)``: the motor file's
``max_velocity`` (rad/s at the output, the no-load speed at the rated voltage). The drive's
current limit caps it at the effort limit (the peak torque, derated when hot:
:class:`sim2real.robots.thermal.EffortDerating`). Both quadrants: driving against the motion (braking)
the back-EMF adds to the supply, ``-tau_stall (1 + w / w_0)``, capped the same way. The winding's
resistance rises with its temperature (``R = R_ref (1 + alpha (T - T_ref))``, the motor file's
copper coefficient), so a hot motor's line falls (Isaac Lab's ``DCMotor`` actuator draws the
same line from a saturation torque; here it follows from the datasheet constants).

A motor without ``max_velocity`` has no envelope (its limits are the effort limit alone).
"""

from __future__ import annotations

import numpy as np


class TorqueSpeedEnvelope:
    """The envelope of a robot's motors, one per joint.

    Args:
        motors: The joints' :class:`sim2real.robots.schema.MotorConfig` (n,).

    Attributes:
        no_load_speed: (n,) rad/s at the joint (``inf`` for a motor without one).
        stall_coefficient: (n,) N m at the joint, ``w_0 k_t^2 N^2 eta / R_ref`` (the stall torque
            at the reference temperature; 0 without an envelope).
        active: (n,) bool, the joints whose motor has an envelope.
    """

    def __init__(self, motors):
        def col(name):
            return np.array([float(getattr(m, name)) for m in motors])

        speed = [m.max_velocity for m in motors]
        self.active = np.array([s is not None for s in speed])
        self.no_load_speed = np.array([np.inf if s is None else float(s) for s in speed])
        kt, ratio, eta, r = (
            col(k)
            for k in ("torque_constant", "gear_ratio", "gear_efficiency", "winding_resistance")
        )
        coefficient = np.where(self.active, self.no_load_speed, 0.0) * kt**2 * ratio**2 * eta / r
        self.stall_coefficient = np.where(self.active, coefficient, 0.0)
        self.t_ref = col("resistance_reference_temperature")
        self.alpha = col("copper_temperature_coefficient")

    @property
    def any(self) -> bool:
        """Whether any joint has an envelope."""
        return bool(self.active.any())

    def stall_torque(self, winding_temperature: np.ndarray) -> np.ndarray:
        """(..., n) N m at the joint: the stall torque at ``winding_temperature`` (..., n) degC."""
        return self.stall_coefficient / (1.0 + self.alpha * (winding_temperature - self.t_ref))

    def limits(
        self, velocity: np.ndarray, effort_limit: np.ndarray, winding_temperature: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` (..., n) N m: the torque range at joint ``velocity`` (..., n)
        rad/s under the current limit ``effort_limit`` (..., n) N m; the effort limit alone
        where a joint has no envelope. The numpy reference of
        :func:`sim2real.deploy.backends.sim.drives_kernel.torque_speed_range`."""
        stall = self.stall_torque(winding_temperature)
        w = np.where(self.active, velocity / self.no_load_speed, 0.0)
        upper = np.where(self.active, np.minimum(effort_limit, stall * (1.0 - w)), effort_limit)
        lower = np.where(self.active, np.maximum(-effort_limit, -stall * (1.0 + w)), -effort_limit)
        return lower, np.maximum(upper, lower)
