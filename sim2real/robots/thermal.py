"""Two-node motor thermal model (winding and housing); the derating law of drives and guard.

The model is the one motor datasheets are written for (maxon, "Technology - short and to the point",
thermal data lines 17-20)::

    C_w dT_w/dt = P_cu - (T_w - T_h) / R_wh
    C_h dT_h/dt = (T_w - T_h) / R_wh - (T_h - T_a) / R_ha
    P_cu        = I^2 R_ref (1 + alpha (T_w - T_ref))          copper loss, hot winding
    I           = |tau_joint| / (N k_t eta)                     motor current from joint torque

with the capacities taken from the datasheet time constants as maxon defines them,
``C_w = tau_w / R_wh`` and ``C_h = tau_motor / R_ha``. ``alpha = 0.00393 /K`` is the resistance
coefficient of annealed copper (IEC 60028). Iron and friction losses are neglected (a few percent
of the copper loss at the low speeds of an arm), which makes the model slightly optimistic.

Temperatures in degrees Celsius, torques in N m at the joint, currents in A, powers in W.
Arrays are shaped ``(envs, n_joints)``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sim2real.robots.schema import MotorConfig
from sim2real.robots.thermal_kernel import thermal_step


class TwoNodeThermalModel:
    """Winding and housing temperature of every motor, integrated with the physics.

    Args:
        motors: One :class:`~sim2real.robots.schema.MotorConfig` per joint.
        envs: Number of environments (batch size).
        ambient_temperature: degC, scalar or shaped (envs, 1) / (envs, n_joints).

    Attributes:
        winding_temperature: (envs, n_joints) degC, updated in place by :meth:`step`.
        housing_temperature: (envs, n_joints) degC.
        current: (envs, n_joints) A, motor current of the last step.
        power: (envs, n_joints) W, copper loss of the last step.
    """

    def __init__(self, motors: Sequence[MotorConfig], envs: int, ambient_temperature=25.0):
        def col(attr: str) -> np.ndarray:
            return np.array([getattr(m, attr) for m in motors], dtype=np.float64)

        self.n_joints = len(motors)
        self.envs = envs
        self.r_wh = col("thermal_resistance_winding_housing")
        self.r_ha = col("thermal_resistance_housing_ambient")
        self.c_w = col("thermal_time_constant_winding") / self.r_wh
        self.c_h = col("thermal_time_constant_housing") / self.r_ha
        self.r_ref = col("winding_resistance")
        self.t_ref = col("resistance_reference_temperature")
        self.alpha = col("copper_temperature_coefficient")
        #: N m at the joint per A of motor current: N k_t eta.
        self.torque_per_amp = col("gear_ratio") * col("torque_constant") * col("gear_efficiency")
        self.ambient = np.broadcast_to(
            np.asarray(ambient_temperature, dtype=np.float64), (envs, self.n_joints)
        ).copy()
        shape = (envs, self.n_joints)
        self.winding_temperature = np.empty(shape)
        self.housing_temperature = np.empty(shape)
        self.current = np.zeros(shape)
        self.power = np.zeros(shape)
        self._flow = np.zeros(shape)
        # the kernel's per-joint constants, rows in sim2real.robots.thermal_kernel.thermal_step's order
        self._constants = np.ascontiguousarray(
            np.stack(
                [
                    self.torque_per_amp,
                    self.t_ref,
                    self.alpha,
                    self.r_ref,
                    self.r_wh,
                    self.r_ha,
                    self.c_w,
                    self.c_h,
                ]
            )
        )
        self.reset()
        # compile (or load numba's cache of) the kernel before any tick: dt 0 changes nothing
        self.step(np.zeros(shape), 0.0)

    def kernel_arrays(self) -> dict[str, np.ndarray]:
        """The model's live arrays, by name, for a compiled step that keeps their addresses
        (:class:`sim2real.deploy.backends.sim.compiled_step.CompiledStep`): the arrays themselves,
        not copies, float64 and C-contiguous, never rebound.

        ``constants`` (8, n_joints), the per-joint constants in the row order of
        :func:`sim2real.robots.thermal_kernel.thermal_step` (torque per amp N m/A, ``t_ref``
        degC, ``alpha`` 1/K, ``r_ref`` ohm, ``r_wh`` and ``r_ha`` K/W, ``c_w`` and ``c_h`` J/K);
        (envs, n_joints) each: ``ambient``, ``winding_temperature``, ``housing_temperature``
        (degC), ``current`` (A), ``power`` (W) and ``flow`` (W, the kernel's scratch for the
        heat flows). Raises nothing.
        """
        return {
            "constants": self._constants,
            "ambient": self.ambient,
            "winding_temperature": self.winding_temperature,
            "housing_temperature": self.housing_temperature,
            "current": self.current,
            "power": self.power,
            "flow": self._flow,
        }

    def reset(self) -> None:
        """Both nodes at ambient temperature (a cold motor)."""
        self.winding_temperature[:] = self.ambient
        self.housing_temperature[:] = self.ambient
        self.current[:] = 0.0
        self.power[:] = 0.0

    def step(self, joint_torque: np.ndarray, dt: float) -> None:
        """Advance the temperatures by ``dt`` seconds under ``joint_torque`` (envs, n_joints), N m.

        Explicit Euler; with dt of a control period (ms) against thermal time constants of tens of
        seconds the integration error is far below a millikelvin. Allocates nothing. Compiled
        (:func:`sim2real.robots.thermal_kernel.thermal_step`); :meth:`step_reference` is its numpy
        reference, equal bit for bit.
        """
        thermal_step(
            np.asarray(joint_torque, dtype=np.float64),
            float(dt),
            self._constants,
            self.ambient,
            self.winding_temperature,
            self.housing_temperature,
            self.current,
            self.power,
            self._flow,
        )

    def step_reference(self, joint_torque: np.ndarray, dt: float) -> None:
        """:meth:`step` in numpy (the compiled kernel's tested reference)."""
        np.abs(joint_torque, out=self.current)
        self.current /= self.torque_per_amp
        # P = I^2 R_ref (1 + alpha (T_w - T_ref))
        np.subtract(self.winding_temperature, self.t_ref, out=self.power)
        self.power *= self.alpha
        self.power += 1.0
        self.power *= self.r_ref
        self.power *= self.current
        self.power *= self.current
        # heat flow winding -> housing
        np.subtract(self.winding_temperature, self.housing_temperature, out=self._flow)
        self._flow /= self.r_wh
        # winding: (P - flow) / C_w
        self.winding_temperature += (self.power - self._flow) * (dt / self.c_w)
        # housing: (flow - (T_h - T_a) / R_ha) / C_h
        self._flow -= (self.housing_temperature - self.ambient) / self.r_ha
        self.housing_temperature += self._flow * (dt / self.c_h)

    def steady_state(self, joint_torque: np.ndarray) -> np.ndarray:
        """Analytic steady-state winding temperature (degC) under a constant ``joint_torque``.

        From the model with dT/dt = 0: ``T_w - T_a = k (1 + alpha (T_w - T_ref))`` with
        ``k = I^2 R_ref (R_wh + R_ha)``, hence
        ``T_w = (T_a + k (1 - alpha T_ref)) / (1 - k alpha)``.

        Raises:
            ValueError: if ``k alpha >= 1`` (thermal runaway: no steady state exists).
        """
        current = np.abs(np.asarray(joint_torque, dtype=np.float64)) / self.torque_per_amp
        k = current**2 * self.r_ref * (self.r_wh + self.r_ha)
        if np.any(k * self.alpha >= 1.0):
            raise ValueError("thermal runaway: the copper loss grows faster than the heat it sheds")
        return (self.ambient + k * (1.0 - self.alpha * self.t_ref)) / (1.0 - k * self.alpha)


def derating_factor(
    temperature: np.ndarray,
    start: np.ndarray,
    maximum: np.ndarray,
    floor: np.ndarray | float = 0.0,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Fraction of the peak effort limit a drive allows at a winding ``temperature`` (degC).

    1 below ``start``, falling linearly to ``floor`` at ``maximum`` (the datasheet's maximum
    winding temperature), ``floor`` above it. Shapes broadcast; the result has the shape of
    ``temperature``. With ``floor = 0`` this is a linear derating to zero torque; the drive law of
    :class:`EffortDerating` uses ``floor = continuous / peak torque``.
    """
    out = np.empty_like(temperature, dtype=np.float64) if out is None else out
    np.subtract(maximum, temperature, out=out)
    out /= maximum - start
    np.clip(out, 0.0, 1.0, out=out)
    out *= 1.0 - np.asarray(floor)
    out += floor
    return out


class EffortDerating:
    """The thermal derating of each joint's effort limit: one law for the drive and the guard.

    Below the motor's ``derating_start_temperature`` the drive gives its peak torque (the joint's
    ``effort_limit``); across the derating band the limit falls linearly to a floor at
    ``max_winding_temperature``, and stays there above it. This is the foldback of servo drives'
    I^2 t protection (maxon EPOS4 Firmware Specification, "Thermal motor protection": once the
    winding's thermal reserve is used up the output current is limited to the configured nominal
    current), with the band of the motor spec instead of an I^2 t integral.

    The floor is the motor's ``continuous_torque``: the load whose steady-state winding temperature
    stays within the datasheet maximum (at the datasheet's 25 degC ambient), so a drive folded back
    to it cannot overheat its motor, while it still holds any load within its continuous rating.
    Where the arm's own weight needs more (``hold`` above the continuous torque: undersized motors)
    the floor is ``hold`` instead, as an integrator would configure the drive: a drive that drops
    its arm is worse than a hot motor, and the runtime's over-temperature safe stop protects the
    motor there.

    Args:
        robot: Robot description (joints' ``effort_limit``, their motors' temperatures and
            ``continuous_torque``).
        hold: (n,) N m, torque each drive must keep available to hold the arm against gravity,
            e.g. ``sim2real.robots.chain_bounds.motion_bounds(robot)[1]``; default 0.

    Attributes:
        start, maximum: (n,) degC, derating start and maximum winding temperature per joint.
        peak: (n,) N m, the underated effort limit.
        floor: (n,) fraction of ``peak`` left at and above ``maximum``:
            ``min(1, max(continuous_torque, hold) / peak)``.
    """

    def __init__(self, robot, hold: np.ndarray | None = None):
        motors = robot.motors
        self.start = np.array([m.derating_start_temperature for m in motors])
        self.maximum = np.array([m.max_winding_temperature for m in motors])
        self.peak = np.asarray(robot.effort_limit, dtype=np.float64)
        floor = np.array([m.continuous_torque for m in motors])
        if hold is not None:
            floor = np.maximum(floor, hold)
        self.floor = np.minimum(floor / self.peak, 1.0)

    def factor(self, temperature: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Fraction in [floor, 1] of the effort limit at ``temperature`` (degC, (..., n))."""
        return derating_factor(temperature, self.start, self.maximum, self.floor, out=out)
