"""The emulated robot's LowState: what its board reports, from the plant's sensor model.

Per motor slot of a joint: ``q`` the encoder reading of the plant's sensor model (quantized,
noisy; frozen while the motor is silent), ``dq`` and ``tau_est`` the plant's joint velocity and
actuator torque, ``temperature`` the modelled winding (whole degC), ``mode`` the driver's (0 when
off), ``unitree_go``: ``lost`` the motor's lost packets and ``reserve[0]`` its error code;
``unitree_hg``: both ``temperature`` sensors and ``motorstate`` the error code. IMU: the
gyroscope and accelerometer of the sensor model (the IMU site's frame), the base's true
orientation as ``quaternion`` (w, x, y, z) and ``rpy``. ``foot_force`` (``unitree_go``): each
foot's measured normal force over ``[unitree] foot_force_scale``, in its slot. ``tick``: the
plant's clock in ms.

``bridge=True`` builds the state as unitree_mujoco's bridge does (its
``simulate_python/unitree_sdk2py_bridge.py``, read, not copied): ``crc`` and ``tick`` 0, no
``foot_force`` (0), the true joint angles and velocities and the true attitude.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.backends.unitree.codec import MessageCodec
from sim2real.deploy.backends.unitree.emulator.drivers import MotorDrivers
from sim2real.deploy.backends.unitree.family import Family


def _rpy(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad, ZYX) of the unit quaternion (w, x, y, z)."""
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


class LowStateBuilder:
    """Fills and encodes the LowState of ``family`` from the plant (module docstring).

    Args:
        family: The message family. slots: (n,) motor slot of each joint. feet: (n_feet,) the
            ``foot_force`` slot of each foot, or None. foot_force_scale: N per count.
        motor_mode: The mode byte of a driver that is on. mode_machine: ``unitree_hg``'s.
        bridge: The state of unitree_mujoco's bridge (module docstring).
    """

    def __init__(
        self,
        family: Family,
        slots: np.ndarray,
        feet: np.ndarray | None,
        foot_force_scale: float,
        motor_mode: int,
        mode_machine: int = 0,
        bridge: bool = False,
    ):
        self.bridge = bool(bridge)
        self.family, self.slots, self.feet = family, np.asarray(slots), feet
        self.scale, self.motor_mode = foot_force_scale, motor_mode
        self.codec = MessageCodec(family.low_state)
        self.message = self.codec.message
        if family.has_mode_machine:
            self.message["mode_machine"] = mode_machine
        else:
            self.message["head"] = (0xFE, 0xEF)
            self.message["level_flag"] = 0xFF
        self._q = np.zeros(len(self.slots))
        self._base = np.zeros((1, 13))

    def fill(self, plant: SimBackend, drivers: MotorDrivers) -> None:
        """The record from the plant's present state and sensor frame."""
        m, s = self.message, self.slots
        f = plant.frame
        answering = ~drivers.silent
        self._q[answering] = f.position[0, answering]
        ms = m["motor_state"]
        ms["q"][s] = self._q
        velocity = f.velocity[0]  # the plant's drives' reading where they report one
        ms["dq"][s] = np.where(np.isfinite(velocity), velocity, plant.true_velocity()[0])
        ms["tau_est"][s] = plant.joint_torque()[0]
        ms["mode"][s] = np.where(drivers.on, self.motor_mode, 0)
        winding = np.clip(np.rint(plant.thermal.winding_temperature[0]), 0, 255)
        if self.family.name == "unitree_go":
            ms["temperature"][s] = winding
            ms["lost"][s] = drivers.lost % (1 << 32)
            ms["reserve"][s, 0] = drivers.error
        else:
            ms["temperature"][s, 0] = ms["temperature"][s, 1] = winding
            ms["motorstate"][s] = drivers.error
        imu = m["imu_state"]
        imu["gyroscope"] = f.imu_angular_velocity[0]
        imu["accelerometer"] = f.imu_acceleration[0]
        quat = f.imu_orientation[0]  # the plant's IMU's own attitude, as the robot's sends it
        if not np.isfinite(quat).all():  # an IMU modelled without one: the true attitude
            quat = plant.true_base_state(out=self._base)[0, 3:7]
        imu["quaternion"] = quat
        imu["rpy"] = _rpy(*quat)
        if self.feet is not None:
            ff = np.clip(np.rint(f.foot_force[0] / self.scale), -32768, 32767)
            m["foot_force"][self.feet] = ff
        m["tick"] = int(round(plant.time * 1000.0)) % (1 << 32)
        if self.bridge:  # unitree_mujoco's bridge: the simulator's truth, no tick, no feet
            ms["q"][s] = plant.true_position()[0]
            ms["dq"][s] = plant.true_velocity()[0]
            true_imu = plant.base_sensors.true_imu()[0]
            imu["gyroscope"], imu["accelerometer"] = true_imu[:3], true_imu[3:]
            quat = plant.true_base_state(out=self._base)[0, 3:7]
            imu["quaternion"], imu["rpy"] = quat, _rpy(*quat)
            if self.feet is not None:
                m["foot_force"][self.feet] = 0
            m["tick"] = 0

    def encode(self, corrupt: bool = False) -> bytes:
        """The DDS sample of the record; ``corrupt``: its CRC off by one bit."""
        sample = self.codec.encode(crc=not self.bridge)
        if not corrupt:
            return sample
        damaged = bytearray(sample)
        damaged[-1] ^= 0x01  # the last byte of the crc member
        return bytes(damaged)
