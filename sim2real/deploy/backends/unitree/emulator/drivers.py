"""The emulated motor drivers: the last command each took, its PD on the plant, its own
over-temperature cut-off, a motor gone silent.

Each driver applies ``tau = tau_ff + kp (q_des - q) + kd (dq_des - dq)`` at every physics step,
as a Unitree motor's FOC driver does with the last LowCmd it took (and keeps applying it when
none comes). On the plant this is one MuJoCo actuator per joint with gain 1, control
``tau_ff + kp q_des + kd dq_des`` and affine bias ``-kp q - kd dq`` (:meth:`MotorDrivers.apply`
sets both), so that MuJoCo's implicit integrator treats the damping term as its own position
servo's; the joint's actuator force is limited to its effort limit (robot.toml), which the
plant derates from the winding temperature as every simulated drive does.

``hold_torque`` drivers behave as unitree_mujoco's bridge does instead: the PD torque is computed
once, from the joint state when a command arrives, and held until the next one (a real driver
recomputes it at its own rate: between two commands 20 ms apart the bridge's joints get no
damping).

A driver is on while its last command's ``mode`` byte is non-zero; off, silent or cut off, it
applies nothing. The cut-off: a winding above ``cutoff_temperature`` switches the driver off for
good and reports error code 4 (Unitree's motors' over-temperature code, as the backend reads it:
:data:`sim2real.deploy.backends.unitree.backend.DRIVER_ERRORS`).
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.robots import Robot

#: The driver error code of the over-temperature cut-off.
OVER_TEMPERATURE = 4


def pd_model(robot: Robot) -> mujoco.MjModel:
    """The plant model with one affine PD actuator per joint (module docstring): the position
    servos of ``robot.mjspec('position')`` with gain 1 and no control range."""
    model = robot.plant_model("position")
    n = robot.n_joints
    model.actuator_gainprm[:n, 0] = 1.0
    model.actuator_biasprm[:n, :3] = 0.0
    model.actuator_ctrllimited[:n] = 0
    return model


class MotorDrivers:
    """The drivers of a robot's joints, in joint order (module docstring).

    Args:
        robot: The robot. slots: (n,) the motor slot of each joint.
        cutoff_temperature: degC, each driver's own cut-off (scalar or (n,)).
        hold_home: Start holding the home pose with the joints' kp/kd (a robot standing);
            else every driver starts off (limp).
        hold_torque: unitree_mujoco's bridge: the PD torque computed on a command's arrival and
            held (module docstring).

    Attributes:
        q_des, dq_des, tau_ff, kp, kd: (n,) the last command taken (rad, rad/s, N m, N m/rad,
            N m s/rad). mode: (n,) its mode byte. cut_off, silent: (n,) bool. error: (n,)
            int64 error code reported. lost: (n,) int64 packets lost (a silent motor's grow).
    """

    def __init__(
        self,
        robot: Robot,
        slots: np.ndarray,
        cutoff_temperature,
        hold_home: bool,
        hold_torque: bool = False,
    ):
        self.hold_torque = bool(hold_torque)
        n = robot.n_joints
        self.n, self.slots = n, np.asarray(slots)
        self.cutoff_temperature = np.broadcast_to(np.asarray(cutoff_temperature, float), n)
        self.q_des = np.asarray(robot.home, dtype=np.float64).copy()
        self.dq_des, self.tau_ff = np.zeros(n), np.zeros(n)
        self.kp = np.array([j.kp for j in robot.config.joints]) if hold_home else np.zeros(n)
        self.kd = np.array([j.kd for j in robot.config.joints]) if hold_home else np.zeros(n)
        self.mode = np.full(n, 1 if hold_home else 0, dtype=np.int64)
        self.cut_off = np.zeros(n, dtype=bool)
        self.silent = np.zeros(n, dtype=bool)
        self.error = np.zeros(n, dtype=np.int64)
        self.lost = np.zeros(n, dtype=np.int64)
        self._ctrl = np.zeros((1, n))
        #: (n,) N m, the torque held since the last command (``hold_torque``)
        self.held = np.zeros(n)

    @property
    def on(self) -> np.ndarray:
        """(n,) bool: the drivers that apply their command."""
        return (self.mode != 0) & ~self.cut_off & ~self.silent

    def take(self, motor_cmd: np.ndarray, q=None, dq=None) -> None:
        """The command of each joint from a LowCmd record's ``motor_cmd`` (a silent motor
        takes none); ``hold_torque``: its PD torque at the joint state ``q``, ``dq`` (rad,
        rad/s, (n,)), held."""
        s, keep = self.slots, ~self.silent
        for name, field in (
            ("mode", "mode"),
            ("q_des", "q"),
            ("dq_des", "dq"),
            ("tau_ff", "tau"),
            ("kp", "kp"),
            ("kd", "kd"),
        ):
            getattr(self, name)[keep] = motor_cmd[field][s][keep]
        if self.hold_torque and q is not None:
            self.held[:] = (
                self.tau_ff + self.kp * (self.q_des - q) + self.kd * (self.dq_des - np.asarray(dq))
            )

    def apply(self, model: mujoco.MjModel) -> np.ndarray:
        """Set the actuators' bias to ``-kp q - kd dq`` and return the control (1, n)
        ``tau_ff + kp q_des + kd dq_des`` (zero where a driver is off)."""
        on = self.on
        if self.hold_torque:  # the torque of the last command's arrival, no PD in between
            model.actuator_biasprm[: self.n, 1:3] = 0.0
            self._ctrl[0] = np.where(on, self.held, 0.0)
            return self._ctrl
        kp, kd = np.where(on, self.kp, 0.0), np.where(on, self.kd, 0.0)
        model.actuator_biasprm[: self.n, 1] = -kp
        model.actuator_biasprm[: self.n, 2] = -kd
        self._ctrl[0] = np.where(on, self.tau_ff, 0.0) + kp * self.q_des + kd * self.dq_des
        return self._ctrl

    def protect(self, winding: np.ndarray) -> np.ndarray:
        """Cut off the drivers whose winding (degC, (n,)) passed ``cutoff_temperature``; returns
        the (n,) bool of the ones cut off now."""
        new = self.on & (winding > self.cutoff_temperature)
        self.cut_off |= new
        self.error[new] = OVER_TEMPERATURE
        return new

    def go_silent(self, joints: np.ndarray) -> None:
        """The motors of ``joints`` ((n,) bool) answer nothing more (their torque is off)."""
        self.silent |= joints
