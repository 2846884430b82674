"""The backend contract: what the runtime reads from and writes to, simulated or real.

Two interfaces:

- :class:`Backend`, the one contract every backend keeps and the only one the runtime
  (:class:`sim2real.deploy.runtime.Runtime`) and ``deploy-run`` rely on: a lifecycle (``open`` / ``close``,
  also as a context manager; ``enable`` / ``disable`` switch the drives' torque), and per control
  tick ``read() -> SensorFrame``, ``write(command)``, ``advance()``. A simulated backend steps its
  physics in ``advance``; a hardware backend returns at once from it (the wall clock paces).
- :class:`SimulatedPlant`, what only a simulation has: ground truth (true joint state, end
  effector), the fault-injection hooks of :class:`sim2real.deploy.backends.sim.faults.FaultInjector` (sensor
  dropout and latency settings) and external forces. ``deploy-run`` uses them when
  ``isinstance(backend,
  SimulatedPlant)``, and only then.

Implementations: :class:`sim2real.deploy.backends.sim.plant.SimBackend` (both), the serial-bus servo
backends :class:`sim2real.deploy.backends.servo.feetech.FeetechBackend` and
:class:`sim2real.deploy.backends.servo.dynamixel.DynamixelBackend`, and a Unitree robot's DDS interface
:class:`sim2real.deploy.backends.unitree.backend.UnitreeBackend` (``Backend`` only).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from sim2real.deploy.core.stale import default_context

if TYPE_CHECKING:
    import mujoco

    from sim2real.robots.thermal import TwoNodeThermalModel


@dataclass
class SensorFrame:
    """One read of the robot's proprioceptive sensors, for a batch of ``envs`` robots.

    A backend reuses one frame and overwrites it on every read: copy what you keep.

    Attributes:
        time: (envs,) s, backend clock when the frame was read.
        position: (envs, n_joints) rad, encoder readings that arrived in this frame, quantized and
            noisy; NaN where no reading arrived (dropout, or a sensor slower than the control rate).
        position_stamp: (envs, n_joints) s, when each reading was sampled (earlier than ``time``
            by the sensor latency); NaN where ``position`` is NaN.
        velocity: (envs, n_joints) rad/s, the joint velocity each drive reported with its encoder
            reading (noisy); NaN where none arrived or the drives report none.
        winding_temperature: (envs, n_joints) degC, as the drive reports it (quantized, at the
            drive's reporting rate: the last reported value is repeated in between).
        temperature_stamp: (envs,) s, when ``winding_temperature`` was last sampled.

    Floating-base (legged) robots only; None for a fixed-base arm:
        imu_angular_velocity: (envs, 3) rad/s, the gyroscope in the IMU site's frame (noise and
            bias included); NaN where no reading arrived.
        imu_acceleration: (envs, 3) m/s^2, the accelerometer's specific force in the IMU
            site's frame (about ``+9.81`` along the site's up axis at rest); NaN likewise.
        imu_stamp: (envs,) s, when the IMU reading was sampled; NaN when none arrived.
        imu_orientation: (envs, 4) the IMU's own attitude estimate, unit quaternion
            ``[w, x, y, z]`` of the IMU site's frame to the world (yaw arbitrary), as an AHRS
            module (Unitree's LowState ``imu_state.quaternion``) reports it; NaN where the IMU
            sends none or no reading arrived.
        foot_force: (envs, n_feet) N, each foot's measured normal contact force (noisy).
        foot_contact: (envs, n_feet) bool, ``foot_force`` above the contact threshold.
        contact_stamp: (envs,) s, when the foot forces were sampled; NaN when none arrived.

    A policy with a ``height_scan`` block only (None otherwise; filled by the height map's source,
    :mod:`sim2real.deploy.runtime.height_map`):
        height_scan: (envs, points) m, the elevation map's sensor height above the terrain at
            each point of the block's scan; NaN where no map arrived.
        height_scan_stamp: (envs,) s, when that map was made; NaN when none arrived.
    """

    time: np.ndarray
    position: np.ndarray
    position_stamp: np.ndarray
    winding_temperature: np.ndarray
    temperature_stamp: np.ndarray
    velocity: np.ndarray | None = None
    imu_angular_velocity: np.ndarray | None = None
    imu_acceleration: np.ndarray | None = None
    imu_stamp: np.ndarray | None = None
    imu_orientation: np.ndarray | None = None
    foot_force: np.ndarray | None = None
    foot_contact: np.ndarray | None = None
    contact_stamp: np.ndarray | None = None
    height_scan: np.ndarray | None = None
    height_scan_stamp: np.ndarray | None = None

    @classmethod
    def empty(cls, envs: int, n_joints: int, n_feet: int | None = None) -> SensorFrame:
        """A frame with no readings (NaN). ``n_feet``: None for a fixed-base arm (no IMU and
        contact fields), else the number of feet of a floating-base robot."""
        nan = np.full((envs, n_joints), np.nan)
        legged = {}
        if n_feet is not None:
            legged = dict(
                imu_angular_velocity=np.full((envs, 3), np.nan),
                imu_acceleration=np.full((envs, 3), np.nan),
                imu_stamp=np.full(envs, np.nan),
                imu_orientation=np.full((envs, 4), np.nan),
                foot_force=np.full((envs, n_feet), np.nan),
                foot_contact=np.zeros((envs, n_feet), dtype=bool),
                contact_stamp=np.full(envs, np.nan),
            )
        return cls(
            time=np.zeros(envs),
            position=nan.copy(),
            position_stamp=nan.copy(),
            winding_temperature=nan.copy(),
            temperature_stamp=np.full(envs, np.nan),
            velocity=nan.copy(),
            **legged,
        )

    def arrays(self) -> dict[str, np.ndarray]:
        """The frame's fields that hold arrays (name -> array): every field of an arm's frame
        but the floating-base ones, which are None."""
        return {k: v for k, v in vars(self).items() if v is not None}


@runtime_checkable
class Backend(Protocol):
    """What the runtime needs of a robot. Arrays are (envs, n_joints).

    Attributes:
        envs: Number of robots behind the backend (1 for real hardware).
        mode: Control mode of ``write``: 'position' (rad), 'velocity' (rad/s) or 'torque' (N m).
        frame: The :class:`SensorFrame` the last ``read`` returned (overwritten by the next).

    Lifecycle: ``open()`` connects and prepares the robot and ends with the drives' torque on
    (``enable``); ``close()`` switches it off (unless the backend was told to hold) and releases
    the connection. Both are idempotent; ``with backend:`` calls them.

    Optional: ``damp(envs)`` ((envs,) bool), for drives with a damping mode of their own (a
    Unitree robot's drivers: kp 0, a damping kd). The runtime calls it on every tick of a legged
    robot with the envs it lays down (SAFE_STOP, FAULTED); their commands are then damping.

    Optional: ``stale_context(env) -> dict``, what the backend's reader saw of env ``env``'s
    stream (:mod:`sim2real.deploy.core.stale`: the stream, samples arrived and refused since the
    last one taken, the newest one's age); the runtime asks at each ``stale_sensor`` stop and the
    report once at the end. :class:`BackendLifecycle` gives every backend a default (nothing
    counted); a backend without it gets :func:`sim2real.deploy.core.stale.default_context`.
    """

    envs: int
    mode: str
    frame: SensorFrame

    def open(self) -> None: ...

    def close(self) -> None: ...

    def enable(self) -> None: ...

    def disable(self) -> None: ...

    def read(self) -> SensorFrame: ...

    def write(self, command: np.ndarray) -> None: ...

    def advance(self) -> None: ...

    def drive_errors(self) -> np.ndarray | None:
        """(envs, n_joints) int64 hardware error bits each drive reported at the last ``read``
        (0: none; the bits are the backend's, see :meth:`describe_drive_error`), or None for a
        backend whose drives report none (the simulation)."""
        ...

    def describe_drive_error(self, joint: int, bits: int) -> str:
        """Human-readable name of drive ``joint``'s error ``bits`` (e.g. 'servo ID 2: 0x20
        overload')."""
        ...

    def __enter__(self) -> Backend: ...

    def __exit__(self, *exc) -> None: ...


@runtime_checkable
class SimulatedPlant(Protocol):
    """What only a simulated backend has: ground truth, fault-injection hooks, external forces.

    Attributes:
        models: The compiled MuJoCo model of each env (gravity, dynamics).
        thermal: The plant-side motor thermal model (true winding temperatures, degC).
        dropout_probability: (envs,) probability that an encoder reading is lost.
        latency_ticks: (envs,) int encoder latency in control ticks (at most
            ``max_latency_ticks``).
    """

    models: list[mujoco.MjModel]
    thermal: TwoNodeThermalModel
    dropout_probability: np.ndarray
    latency_ticks: np.ndarray
    max_latency_ticks: int

    def true_position(self) -> np.ndarray:
        """(envs, n_joints) rad, the simulator's joint angles."""
        ...

    def true_velocity(self) -> np.ndarray:
        """(envs, n_joints) rad/s, the simulator's joint velocities."""
        ...

    def joint_torque(self) -> np.ndarray:
        """(envs, n_joints) N m, actuator torque at the end of the last control period."""
        ...

    def end_effector_position(self, out: np.ndarray | None = None) -> np.ndarray:
        """(envs, 3) m, the end-effector site in the world frame."""
        ...

    def set_external_force(self, env: int, force: np.ndarray, body: str | None = None) -> None:
        """Apply a constant force (N, world frame, (3,)) to ``env`` until changed."""
        ...


class BackendLifecycle:
    """Mixin: ``with backend:`` opens and closes a backend (``open`` / ``close`` of the class);
    the default ``stale_context`` of a backend whose reader counts nothing.

    Attributes:
        commands_gains: The backend sends each joint's ``kp`` and ``kd`` (its robot's, the
            policy's drive in deploy-run) with every command, as a Unitree LowCmd does: it runs
            a policy's own gains. False (this default): the drives keep gains of their own (a
            servo's registers), and deploy-run refuses a policy trained with others.
    """

    commands_gains: bool = False

    def stale_context(self, env: int = 0) -> dict:
        """What the reader saw of env ``env``'s stream (:mod:`sim2real.deploy.core.stale`); this
        default names the class and counts nothing. Allocates: call it at a stop, not per tick."""
        return default_context(self, env)

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def checked_command(command: np.ndarray, n: int) -> np.ndarray:
    """``command`` as float64 (1, ``n``), checked before a hardware backend writes it.

    Raises:
        ValueError: wrong shape or a non-finite value (the backend then writes nothing).
    """
    command = np.asarray(command, dtype=np.float64)
    if command.shape != (1, n):
        raise ValueError(f"command: expected shape (1, {n}), got {command.shape}")
    if not np.isfinite(command).all():
        raise ValueError(f"command rejected, non-finite values: {command.tolist()}")
    return command
