"""A serial-bus servo arm as a :class:`~sim2real.deploy.core.backend.Backend` (one robot, wall clock).

What Feetech STS and Dynamixel X buses share; :mod:`sim2real.deploy.backends.servo.feetech` and
:mod:`sim2real.deploy.backends.servo.dynamixel` bind it to their vendor's SDK (``scservo_sdk``,
``dynamixel_sdk``), which frames, checksums and times every packet.

``open()``: open the port at the baud rate, ping every servo and check its model number against
the robot's motor (``robot.toml`` motor -> :func:`~sim2real.deploy.backends.servo.control_tables.
model_for_motor`), switch torque off, write Return_Delay_Time 0 (LeRobot's ``configure_motors``
does the same: the factory 500 us per reply would eat half of a 100 Hz tick on six servos), the
operating mode, the servo's own protection registers from the motor catalog
(``sim2real/robots/motors/<motor>.toml`` ``[protection.registers]``) and the calibration's homing offset
and position limits, read the pose, and only then :meth:`enable` torque (goal = present pose
first, so nothing jumps). ``close()``: torque off (unless ``hold_on_close``), port closed.

Per tick, ``read()`` sends one SYNC READ of a contiguous register block (present position,
velocity, load or current, voltage, temperature) and collects the replies by servo ID through the
SDK's packet receiver, each with its status error byte. A reply that does not arrive within
``read_timeout`` or fails its checksum / CRC is a dropout: NaN for that joint in the frame,
counted by kind in :attr:`dropouts` (``timeout``, ``corrupt``). ``write(command)`` sends one SYNC
WRITE of goal positions (position mode) or goal velocities (velocity mode). ``advance()`` returns
at once: the runtime's wall clock paces the loop.

Hardware errors (overload, overheating, input voltage, ...: the status packet's error byte on
Feetech, Hardware_Error_Status on Dynamixel) are reported by :meth:`drive_errors`; the runtime
makes a safe stop of them (cause ``servo_error``). So is a servo found with its torque off while
the host has it on (:mod:`sim2real.deploy.backends.servo.torque_watch`: when Torque_Enable is read back).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sim2real.deploy.backends.servo import summary
from sim2real.deploy.backends.servo.calibration import (
    JointCalibration,
    calibration_arrays,
    default_calibration,
    load_lerobot_calibration,
)
from sim2real.deploy.backends.servo.control_tables import ServoModel, model_for_motor
from sim2real.deploy.backends.servo.torque_watch import TORQUE_OFF, TorqueWatch
from sim2real.deploy.core.backend import BackendLifecycle, SensorFrame, checked_command
from sim2real.deploy.core.latency import LatencyHistogram
from sim2real.robots import Robot
from sim2real.robots.errors import Sim2RealError

DROPOUT_KINDS = ("timeout", "corrupt")
#: Tries of the first pose read in ``open()`` before giving up.
OPEN_READ_TRIES = 5
#: Tries of each ping and configuration write in ``open()`` (a noisy bus loses replies; LeRobot's
#: motor bus retries the same way, ``num_retry``).
CONFIG_TRIES = 3


class ServoBusError(Sim2RealError, OSError):
    """The bus cannot be brought up: port, missing servo, wrong model, refused register write."""


class ServoBusBackend(BackendLifecycle):
    """Shared part of the servo-bus backends; use :class:`~sim2real.deploy.backends.servo.feetech.
    FeetechBackend` or :class:`~sim2real.deploy.backends.servo.dynamixel.DynamixelBackend`.

    Args:
        robot: The robot; every joint's motor must be a servo of this backend's protocol.
        port: Serial port (e.g. ``/dev/ttyACM0``, or the emulator's pty).
        baudrate: Bus baud rate, bit/s.
        calibration: LeRobot calibration JSON path, a list of :class:`JointCalibration` (joint
            order), or None (IDs 1..n, 2048 ticks = 0 rad, direction +1).
        mode: 'position' or 'velocity' (default robot.toml's); 'torque' is refused.
        hold_on_close: ``close()`` leaves the torque on (the arm holds its last goal).
        read_timeout: s to wait for the replies of one SYNC READ (default: 60 % of the control
            period: a late reply is a dropout, not an overrun).

    Attributes:
        envs: 1. mode: the control mode. frame: the last :class:`SensorFrame`.
        velocity, effort, voltage, temperature: (1, n) last present velocity (rad/s), load or
            current (N m estimate: load x peak torque, or current x gear ratio x torque constant x
            efficiency), input voltage (V) and temperature (degC); NaN where never read.
        dropouts: Counter of missing replies by kind (``DROPOUT_KINDS``).
        latched_errors: Servo ID -> OR of the hardware error bits it reported (and ``TORQUE_OFF``).
        reads: SYNC READs sent. read_cost, write_cost: :class:`LatencyHistogram` of the bus
            transactions (ns).
        torque_checks, check_cost: SYNC READs of Torque_Enable sent, and their cost (ns).

    Raises:
        ValueError: a motor of another protocol, torque mode, bad calibration.
        KeyError: a motor without a known control table.
    """

    protocol = ""  # set by the subclass

    def __init__(
        self,
        robot: Robot,
        port: str,
        baudrate: int = 1_000_000,
        calibration: str | Path | Sequence[JointCalibration] | None = None,
        mode: str | None = None,
        hold_on_close: bool = False,
        read_timeout: float | None = None,
    ):
        self.robot, self.port_name, self.baudrate = robot, str(port), int(baudrate)
        self.names = list(robot.joint_names)
        self.motors = [j.motor for j in robot.config.joints]
        self.models: list[ServoModel] = [model_for_motor(m) for m in self.motors]
        wrong = [m.name for m in self.models if m.protocol != self.protocol]
        if wrong:
            raise ValueError(
                f"{robot.name}: motors {sorted(set(wrong))} do not speak the {self.protocol} "
                "protocol"
            )
        self.mode = mode or robot.control_mode
        if self.mode not in ("position", "velocity"):
            raise ValueError(f"{self.protocol} backend: mode '{self.mode}' is not supported")
        self.envs, self.n = 1, robot.n_joints
        resolutions = [
            robot.motors[j].encoder_resolution or m.resolution for j, m in enumerate(self.models)
        ]
        if calibration is None:
            calibration = default_calibration(resolutions)
        elif isinstance(calibration, (str, Path)):
            calibration = load_lerobot_calibration(calibration, self.names, resolutions)
        self.calibration = list(calibration)
        self.ids = [c.servo_id for c in self.calibration]
        self._cal = calibration_arrays(self.calibration)
        self.hold_on_close = hold_on_close
        self.read_timeout = 0.6 * robot.control_period if read_timeout is None else read_timeout
        self.frame = SensorFrame.empty(1, self.n)
        nan = np.full((1, self.n), np.nan)
        self.velocity, self.effort = nan.copy(), nan.copy()
        self.voltage, self.temperature = nan.copy(), nan.copy()
        self.dropouts: Counter[str] = Counter({k: 0 for k in DROPOUT_KINDS})
        self.latched_errors: dict[int, int] = {}
        self.reads = 0
        self.read_cost, self.write_cost = LatencyHistogram(), LatencyHistogram()
        self.torque_checks, self.check_cost = 0, LatencyHistogram()
        self._watch = TorqueWatch(robot)
        self._errors = np.zeros((1, self.n), dtype=np.int64)
        #: per joint: reads in a row without its reply, and when it last replied (s, ``_t0``);
        #: corrupt replies since a read all servos answered; the last read's duration (ns)
        self._unanswered = np.zeros(self.n, dtype=np.int64)
        self._replied_at = np.full(self.n, -np.inf)
        self._corrupt_run = self._read_ns = 0
        self._ticks = np.zeros(self.n)
        self._goal = np.zeros(self.n)
        self._is_open = self._enabled = False
        self._t0 = time.monotonic()
        # the SYNC READ block: every present register we want, contiguous in the table
        model = self.models[0]
        self.quantities = self.present_quantities(model)
        names = [model.names[k] for k in self.quantities]
        regs = [model.register(k) for k in names]
        self.block_start = min(r.address for r in regs)
        self.block_length = max(r.address + r.size for r in regs) - self.block_start
        goal = "goal_position" if self.mode == "position" else "goal_velocity"
        self.goal_register = model.register(goal)

    # ------------------------------------------------------------------ protocol hooks
    def present_quantities(self, model: ServoModel) -> tuple[str, ...]:
        """Common names (``ServoModel.names`` keys) of the registers of the SYNC READ block."""
        raise NotImplementedError

    def _connect(self) -> None:
        """Open the SDK's port handler at ``baudrate`` and make its packet handler and groups."""
        raise NotImplementedError

    def _ping(self, servo_id: int) -> tuple[int, int]:
        """(model number, SDK result) of a PING."""
        raise NotImplementedError

    def _write_register(self, servo_id: int, address: int, data: bytes) -> tuple[int, int]:
        """(SDK result, status error byte) of a WRITE with reply."""
        raise NotImplementedError

    def _read_register(self, servo_id: int, address: int, length: int) -> bytes | None:
        """The bytes of a READ, or None on a failed communication."""
        raise NotImplementedError

    def _sync_read(self) -> tuple[dict[int, tuple[bytes, int]], int]:
        """One SYNC READ of the block: ({servo ID: (block bytes, error byte)}, corrupt replies)."""
        raise NotImplementedError

    def _read_torque(self) -> dict[int, int]:
        """One SYNC READ of Torque_Enable: {servo ID: value} of the servos that answered."""
        raise NotImplementedError

    def _sync_write(self, data: list[bytes]) -> None:
        """One SYNC WRITE of the goal register, ``data[j]`` to joint j's servo."""
        raise NotImplementedError

    def _hardware_error(self, j: int, error_byte: int) -> int:
        """Hardware error bits of joint ``j``'s servo from its status error byte (0: none)."""
        raise NotImplementedError

    def _close_port(self) -> None:
        raise NotImplementedError

    def _result_text(self, result: int) -> str:
        raise NotImplementedError

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        """Bring the bus up (module docstring) and enable torque; idempotent.

        Raises:
            ServoBusError: the port does not open, a servo does not answer its ping (names the ID
                and joint), a model number differs from robot.toml's motor (names the ID, the
                expected and the found model), a configuration write is refused, or the pose
                cannot be read.
        """
        if self._is_open:
            return
        self._connect()
        self._is_open = True
        try:
            self._check_servos()
            self.disable()
            for j in range(self.n):
                self._configure(j)
            self._read_pose()
            self.enable()
        except BaseException:
            self._close_port()
            self._is_open = False
            raise

    def close(self) -> None:
        """Torque off (unless ``hold_on_close``) and close the port; idempotent."""
        if not self._is_open:
            return
        try:
            if not self.hold_on_close:
                self.disable()
        finally:
            self._close_port()
            self._is_open = False

    def enable(self) -> None:
        """Torque on, every servo: first its goal is set to where it is (position mode: the
        last read pose; velocity mode: 0), so that nothing moves.

        Raises:
            ServoBusError: a servo refused (ID and error named).
        """
        if self.mode == "position":
            self._ticks_to_goal(self._ticks)
        else:
            self._goal[:] = 0.0
        self._sync_write(self._encode_goal())
        for j in range(self.n):
            self._set(j, "torque_enable", 1)
        self._enabled = True
        self._watch.restart()

    def disable(self) -> None:
        """Torque off, every servo that answers (an unplugged one cannot be reached)."""
        for j, sid in enumerate(self.ids):
            reg = self.models[j].register("torque_enable")
            self._write_register(sid, reg.address, reg.encode(0))
        self._enabled = False

    def _check_servos(self) -> None:
        for j, (sid, model) in enumerate(zip(self.ids, self.models, strict=True)):
            for _ in range(CONFIG_TRIES):
                found, result = self._ping(sid)
                if result == 0:
                    break
            if result != 0:
                raise ServoBusError(
                    f"servo ID {sid} ({self.names[j]}) did not answer a ping on {self.port_name} "
                    f"at {self.baudrate} bit/s: {self._result_text(result)}"
                )
            if found != model.model_number:
                raise ServoBusError(
                    f"servo ID {sid} ({self.names[j]}) has model number {found}, expected "
                    f"{model.model_number} ({self.motors[j]}, robot.toml's motor for that joint)"
                )

    def _configure(self, j: int) -> None:
        """Return delay, operating mode, protection registers, calibration of joint j."""
        model, cal = self.models[j], self.calibration[j]
        self._set(j, "return_delay", 0)
        self._set(j, "operating_mode", model.operating_modes[self.mode])
        protection = self.robot.motors[j].protection
        for name, reg in protection.registers.items() if protection else ():
            if not model.has(name) or model.register(name).address != reg.address:
                raise ServoBusError(
                    f"motor catalog {self.motors[j]}: protection register {name} at "
                    f"{reg.address} is not in the {model.name} control table"
                )
            self._set(j, name, reg.default)
        if cal.homing_offset is not None:
            self._set(j, "Homing_Offset", cal.homing_offset)
            self._set(j, "min_position", cal.range_min)
            self._set(j, "max_position", cal.range_max)

    def _set(self, j: int, name: str, value: int) -> None:
        reg = self.models[j].register(name)
        for _ in range(CONFIG_TRIES):
            result, _error = self._write_register(self.ids[j], reg.address, reg.encode(value))
            if result == 0:
                break
        else:
            raise ServoBusError(
                f"servo ID {self.ids[j]} ({self.names[j]}): writing {reg.name} = {value} failed: "
                f"{self._result_text(result)}"
            )

    def _read_pose(self) -> None:
        for _ in range(OPEN_READ_TRIES):
            self.read()
            if not np.isnan(self.frame.position).any():
                return
        missing = [self.ids[j] for j in np.flatnonzero(np.isnan(self.frame.position[0]))]
        raise ServoBusError(
            f"could not read the pose of servos {missing} in {OPEN_READ_TRIES} tries "
            f"(dropouts {dict(self.dropouts)})"
        )

    # ------------------------------------------------------------------ the three calls
    def read(self) -> SensorFrame:
        """One SYNC READ: the frame of this tick (:class:`SensorFrame`; NaN for joints whose reply
        was lost or corrupt). Also fills ``velocity``, ``effort``, ``voltage``, ``temperature``
        and :meth:`drive_errors`. The frame is overwritten by the next read."""
        t0 = time.perf_counter_ns()
        now = time.monotonic() - self._t0
        replies, corrupt = self._sync_read()
        self.reads += 1
        f = self.frame
        f.time[0] = now
        self._errors.fill(0)
        temperature_read = False
        for j, sid in enumerate(self.ids):
            reply = replies.get(sid)
            if reply is None:
                f.position[0, j] = f.position_stamp[0, j] = np.nan
                self._unanswered[j] += 1
                continue
            self._unanswered[j], self._replied_at[j] = 0, now
            data, error = reply
            self._decode(j, data)
            f.position[0, j] = self._to_rad(j, self._ticks[j])
            f.position_stamp[0, j] = now
            f.winding_temperature[0, j] = self.temperature[0, j]
            temperature_read = True
            bits = self._hardware_error(j, error) if error else 0
            if bits:
                self._errors[0, j] = bits
                self.latched_errors[sid] = self.latched_errors.get(sid, 0) | bits
        if temperature_read:
            f.temperature_stamp[0] = now
        missing = self.n - len([sid for sid in self.ids if sid in replies])
        corrupt = min(corrupt, missing)
        self.dropouts["corrupt"] += corrupt
        self.dropouts["timeout"] += missing - corrupt
        self._corrupt_run = self._corrupt_run + corrupt if missing else 0
        self._read_ns = cost = time.perf_counter_ns() - t0
        self.read_cost.add(0, cost)
        slow = cost > 0.5e9 * self.read_timeout
        if self._enabled and self._watch.due(self.temperature[0], slow):
            self._check_torque()
        return f

    def _check_torque(self) -> None:
        """Read Torque_Enable back; a servo found off that reports no hardware error at this
        read gets ``TORQUE_OFF`` in this read's :meth:`drive_errors` and in ``latched_errors``
        (again at every check while it stays off: an operator's reset does not resume it)."""
        t0 = time.perf_counter_ns()
        torque = self._read_torque()
        self.torque_checks += 1
        for j, sid in enumerate(self.ids):
            if torque.get(sid, 1) == 0 and not self._errors[0, j]:
                self._errors[0, j] |= TORQUE_OFF
                self.latched_errors[sid] = self.latched_errors.get(sid, 0) | TORQUE_OFF
        self.check_cost.add(0, time.perf_counter_ns() - t0)

    def write(self, command: np.ndarray) -> None:
        """One SYNC WRITE of goal positions (rad, clipped to each joint's calibrated range) or
        goal velocities (rad/s): ``command`` shaped (1, n_joints).

        Raises:
            ValueError: wrong shape or a non-finite value (nothing is written).
        """
        command = checked_command(command, self.n)
        t0 = time.perf_counter_ns()
        c = self._cal
        if self.mode == "position":
            ticks = c["zero"] + c["direction"] * command[0] / c["rad_per_tick"]
            self._ticks_to_goal(ticks)
        else:
            for j, model in enumerate(self.models):
                self._goal[j] = model.velocity_to_counts(c["direction"][j] * command[0, j])
        self._sync_write(self._encode_goal())
        self.write_cost.add(0, time.perf_counter_ns() - t0)

    def advance(self) -> None:
        """Nothing: the servos run on their own; the runtime's wall clock paces the loop."""

    # ------------------------------------------------------------------ reports
    def drive_errors(self) -> np.ndarray:
        """(1, n_joints) int64 hardware error bits reported at the last read (0: none)."""
        return self._errors

    def describe_drive_error(self, joint: int, bits: int) -> str:
        """``'servo ID 2 (shoulder_lift): error bits 0x20 (overload)'``, or ``'servo ID 2
        (shoulder_lift): torque off by the servo while commanded on, ...'`` (``TORQUE_OFF``)."""
        model, hardware = self.models[joint], bits & ~TORQUE_OFF
        parts = [self._watch.describe(joint)] if bits & TORQUE_OFF else []
        if hardware or not parts:
            names = [k for k, b in model.error_bits.items() if hardware & b] or ["unknown"]
            parts.insert(0, f"error bits {hardware:#04x} ({', '.join(names)})")
        return f"servo ID {self.ids[joint]} ({self.names[joint]}): " + "; ".join(parts)

    def stale_context(self, env: int = 0) -> dict:
        """What the SYNC READ saw of each servo
        (:func:`~sim2real.deploy.backends.servo.summary.stale_context`); ``env`` is 0."""
        return summary.stale_context(self)

    def bus_summary(self) -> dict:
        """Bus figures for the run's report
        (:func:`~sim2real.deploy.backends.servo.summary.bus_summary`)."""
        return summary.bus_summary(self)

    # ------------------------------------------------------------------ conversions
    def _to_rad(self, j: int, ticks: float) -> float:
        c = self._cal
        return c["direction"][j] * (ticks - c["zero"][j]) * c["rad_per_tick"][j]

    def _ticks_to_goal(self, ticks: np.ndarray) -> None:
        c = self._cal
        np.clip(np.round(ticks), c["range_min"], c["range_max"], out=self._goal)

    def _encode_goal(self) -> list[bytes]:
        reg = self.goal_register
        return [reg.encode(int(g)) for g in self._goal]

    def _decode(self, j: int, data: bytes) -> None:
        """Present registers of joint j from the block's bytes, in SI units."""
        model, start = self.models[j], self.block_start

        def value(name: str) -> int:
            reg = model.register(name)
            return reg.decode(data[reg.address - start : reg.address - start + reg.size])

        motor = self.robot.motors[j]
        direction = self._cal["direction"][j]
        self._ticks[j] = value("present_position")
        self.velocity[0, j] = direction * model.counts_to_velocity(value("present_velocity"))
        if "present_current" in self.quantities:
            amps = value("present_current") * model.current_unit
            torque = amps * motor.gear_ratio * motor.torque_constant * motor.gear_efficiency
        else:
            torque = value("present_load") * model.load_unit * motor.peak_torque
        self.effort[0, j] = direction * torque
        self.voltage[0, j] = value("present_voltage") * model.voltage_unit
        self.temperature[0, j] = value("present_temperature")
