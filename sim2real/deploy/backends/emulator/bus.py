"""The emulated servo bus: a pseudo-terminal, the servos on it, the MuJoCo plant behind them.

:class:`ServoBusEmulator` opens a pty and answers on it as the servos of a robot would, in the
Feetech SCS/STS protocol or Dynamixel Protocol 2.0; the vendors' SDKs open the pty's path like a
serial port. The plant, a one-env :class:`sim2real.deploy.backends.sim.plant.SimBackend` with its sensor
and thermal models, steps on its own thread in whole control periods until it has caught up with
the wall clock, taking the goal registers and writing the present ones, as a servo's firmware
samples on its own cycle: a reply waits for the register copy only, never for a step. A plant
more than ``_MAX_LAG`` behind moves its time origin up (``stats['plant_lag_resets']``). Registers:

- goal position or goal velocity (the operating mode register, the last one written, chooses the
  plant's control mode; the plant is rebuilt at its pose), torque on -> the plant's command,
  positions clipped to the min/max position limit registers; torque off: position mode commands
  the present angle every period (the joint sags, damped), velocity mode 0 rad/s;
- present position / velocity <- the plant's joint (``resolution`` ticks per turn, ``resolution /
  2`` at 0 rad), shifted by Homing_Offset as the servo does: present = actual - offset on Feetech
  (LeRobot's ``FeetechMotorsBus._get_half_turn_homings``), actual + offset on Dynamixel (e-Manual,
  Homing Offset(20)); goal positions are in the same frame;
- present current (or load) <- the actuator torque over the thermal model's ``torque_per_amp``;
  present temperature <- the modelled winding (whole degC); present voltage 12.0 V.

Bus timing (half duplex, 10 bits per byte: start, 8 data, stop): a reply is written when its last
byte would arrive on a real bus, ``n_instruction x 10 / baud`` after the host wrote the
instruction plus, for this and each earlier reply to it, the reply latency and ``n_reply x 10 /
baud``. The latency is the Return_Delay_Time register (x 2 us; factory default 250 = 500 us on
both vendors, :mod:`sim2real.deploy.backends.servo.control_tables`) unless ``latency_us`` overrides it; a
reply already late is sent at once and counted (``stats['late_replies']``). Every servo trips
``overheat`` when the modelled winding passes its temperature-limit register, as the real servo
does; other faults are injected on request (:class:`.faults.WireFaults`).
"""

from __future__ import annotations

import os
import random
import select
import threading
import time
import tty
from collections import Counter
from collections.abc import Sequence

import numpy as np

from sim2real.deploy.backends.emulator.dispatch import DynamixelDispatcher, FeetechDispatcher, Reply
from sim2real.deploy.backends.emulator.faults import WireFaults
from sim2real.deploy.backends.emulator.servo import EmulatedServo, WriteResult
from sim2real.deploy.backends.servo.control_tables import model_for_motor
from sim2real.deploy.backends.sim.options import plant_for
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.backends.worker import ServesOnThread
from sim2real.deploy.core.collector import collector_paused
from sim2real.robots import Robot, load_robot

PROTOCOLS = ("feetech", "dynamixel")
_MAX_LAG = 0.25  # s the plant may fall behind the wall clock before the origin moves


class ServoBusEmulator(ServesOnThread):
    """Servos of ``robot`` on a pseudo-terminal, backed by the MuJoCo plant.

    Use as a context manager (``with ServoBusEmulator(robot, 'feetech') as emu: emu.port``) or
    call :meth:`start` / :meth:`stop`; :meth:`serve` runs it in the calling thread.

    Args:
        robot: A :class:`robots.Robot` or a robot name / path for :func:`robots.load_robot`.
            Every joint's motor must be a serial-bus servo of ``control_tables.MODELS``.
        protocol: ``'feetech'`` or ``'dynamixel'``; default: the motors' protocol.
        baudrate: Bus baud rate (bit/s) of the timing model; written to the Baud_Rate registers.
        latency_us: Reply latency, us, overriding every servo's Return_Delay_Time.
        mode: Plant control mode, 'position' or 'velocity' (default: robot.toml's, or 'position'
            for 'torque'); the servos' operating mode registers start at it.
        ids: Bus ID of each joint (default 1..n in joint order, LeRobot's SO-101 numbering).
        faults: Wire faults to inject (default none); ``emu.faults`` may be changed while running.
        seed: Seed of the fault draws and the plant's sensor noise.
        plant_motors: A plant motors file (:mod:`sim2real.robots.plant_motors`): the servos as they
            really are, which the host's description does not know (None: as described).

    Attributes:
        port: Path of the pty's follower end (e.g. ``/dev/pts/5``) for the host's serial port.
        servos: The :class:`.servo.EmulatedServo` of each joint.
        plant: The present :class:`SimBackend`.
        stats: Counters: ``packets``, ``bad_checksum``, ``replies``, ``dropped``, ``corrupted``,
            ``late_replies``, ``plant_steps``, ``plant_lag_resets``.

    Raises:
        ValueError: unknown protocol or mode, a motor of another protocol, duplicate IDs.
        KeyError: a joint's motor has no known control table.
    """

    def __init__(
        self,
        robot: Robot | str,
        protocol: str | None = None,
        *,
        baudrate: int = 1_000_000,
        latency_us: float | None = None,
        mode: str | None = None,
        ids: Sequence[int] | None = None,
        faults: WireFaults | None = None,
        seed: int = 0,
        plant_motors: str | None = None,
    ):
        self.robot = robot if isinstance(robot, Robot) else load_robot(robot)
        self._plant_motors = plant_motors
        motors = [j.motor for j in self.robot.config.joints]
        models = [model_for_motor(m) for m in motors]
        found = {m.protocol for m in models}
        protocol = protocol or (found.pop() if len(found) == 1 else "")
        if protocol not in PROTOCOLS or {m.protocol for m in models} != {protocol}:
            raise ValueError(
                f"protocol '{protocol}': expected one of {PROTOCOLS}, matching every motor of "
                f"{self.robot.name} ({', '.join(sorted(set(motors)))})"
            )
        self.protocol, self.baudrate = protocol, int(baudrate)
        self.latency = None if latency_us is None else latency_us * 1e-6
        mode = mode or self.robot.control_mode
        mode = "position" if mode == "torque" else mode
        if mode not in ("position", "velocity"):
            raise ValueError(f"mode '{mode}': expected 'position' or 'velocity'")
        ids = list(ids) if ids is not None else list(range(1, self.robot.n_joints + 1))
        if len(ids) != self.robot.n_joints or len(set(ids)) != len(ids):
            raise ValueError(f"ids: expected {self.robot.n_joints} distinct IDs, got {ids}")
        self.servos = [
            EmulatedServo(model, sid, j, self.robot.motors[j], self.baudrate)
            for j, (model, sid) in enumerate(zip(models, ids, strict=True))
        ]
        for s in self.servos:
            s.set("operating_mode", s.model.operating_modes[mode])
        self.faults = faults if faults is not None else WireFaults()
        for sid, degc in self.faults.temperature_limit.items():
            self._servo(sid).set("temperature_limit", degc)
        self._seed = seed
        self._rng = random.Random(seed)
        self.plant = self._new_plant(mode)
        self._command = np.zeros((1, self.robot.n_joints))
        self._hold_present()
        dispatcher = FeetechDispatcher if protocol == "feetech" else DynamixelDispatcher
        self._dispatcher = dispatcher(self._on_write)
        self.stats: Counter[str] = Counter()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._plant_thread: threading.Thread | None = None
        self._pending_mode: str | None = None
        self._leader, self._follower = os.openpty()
        tty.setraw(self._follower)
        self.port = os.ttyname(self._follower)
        self._t0 = time.monotonic()
        self._steps = 0
        self._refresh()
        # a servo powers up holding where it is: its firmware copies the present position into
        # the goal register (Feetech STS and Dynamixel X alike), so torque on before any goal
        # write holds the joint instead of driving it to tick 0
        for servo in self.servos:
            if servo.model.has("goal_position"):
                servo.set("goal_position", servo.get("present_position"))

    # ------------------------------------------------------------------ lifecycle
    # (the context manager, start() and request_stop(): ServesOnThread)
    THREAD_NAME = "servo-bus-emulator"

    def _start_plant(self) -> None:
        if self._plant_thread is None:
            self._plant_thread = threading.Thread(target=self._run_plant, name="emulated-plant")
            self._plant_thread.daemon = True
            self._plant_thread.start()

    def stop(self) -> None:
        """Stop serving and close the pty (idempotent)."""
        self._stop.set()
        for thread in (self._thread, self._plant_thread):
            if thread is not None and thread is not threading.current_thread():
                thread.join(timeout=5.0)
        self._thread = self._plant_thread = None
        for fd in (self._leader, self._follower):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._leader = self._follower = -1

    @property
    def elapsed(self) -> float:
        """s since the emulator started (wall clock; the plant's time follows it)."""
        return time.monotonic() - self._t0

    def serve(self) -> None:
        """Answer packets until :meth:`stop` (blocking); the plant steps on a second thread. The
        garbage collector is paused while it serves
        (:func:`~sim2real.deploy.core.collector.collector_paused`): a full collection holds both
        threads for tens of milliseconds, a silent bus to the host."""
        with collector_paused():
            self._serve()

    def _serve(self) -> None:
        self._start_plant()
        period = self.robot.control_period
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._leader], [], [], period)
            except (OSError, ValueError):
                return
            received = time.monotonic()
            if not ready:
                continue
            try:
                data = os.read(self._leader, 4096)
            except OSError:
                return
            self._answer(data, received)

    def _run_plant(self) -> None:
        """Step the plant every control period until :meth:`stop` (the plant thread)."""
        period = self.robot.control_period
        while not self._stop.is_set():
            self._catch_up()
            next_step = self._t0 + (self._steps + 1) * period
            self._stop.wait(max(0.0, next_step - time.monotonic()))

    # ------------------------------------------------------------------ fault API
    def _servo(self, servo_id: int) -> EmulatedServo:
        for s in self.servos:
            if s.servo_id == servo_id:
                return s
        raise KeyError(f"no servo with ID {servo_id} (IDs: {[s.servo_id for s in self.servos]})")

    def unplug(self, servo_id: int, at: float | None = None) -> None:
        """Servo ``servo_id`` stops answering ``at`` s after start (default: now).

        Raises:
            KeyError: no such servo.
        """
        self._servo(servo_id)
        self.faults.unplug[servo_id] = self.elapsed if at is None else at

    def set_overload(self, servo_id: int, at: float | None = None) -> None:
        """Servo ``servo_id`` reports an overload from ``at`` s after start (default: now).

        Raises:
            KeyError: no such servo.
        """
        self._servo(servo_id)
        self.faults.overload[servo_id] = self.elapsed if at is None else at

    def cut_torque(self, servo_id: int) -> None:
        """Servo ``servo_id`` switches its torque off by itself and keeps no error bit: what a
        host sees of a Feetech overheat shutdown whose bit cleared (the winding cooled below the
        limit) before it read a status packet, or of a servo reset by a supply dip.

        Raises:
            KeyError: no such servo.
        """
        with self._lock:
            self._servo(servo_id).set("torque_enable", 0)

    def set_temperature_limit(self, servo_id: int, degc: int) -> None:
        """Write ``degc`` to the temperature-limit register of servo ``servo_id``.

        Raises:
            KeyError: no such servo.
        """
        with self._lock:
            self._servo(servo_id).set("temperature_limit", degc)

    # ------------------------------------------------------------------ the bus
    def _answer(self, data: bytes, received: float) -> None:
        with self._lock:
            exchanges = self._dispatcher.feed(data, self._answering())
        tb = 10.0 / self.baudrate
        for ex in exchanges:
            self.stats["packets"] += 1
            self.stats["bad_checksum"] += not ex.valid
            due = received + ex.instruction_bytes * tb
            for reply in ex.replies:
                due += self._latency(reply) + len(reply.packet) * tb
                self._send(reply, due)
            received = max(received, due)

    def _latency(self, reply: Reply) -> float:
        return self.latency if self.latency is not None else reply.servo.reply_delay()

    def _send(self, reply: Reply, due: float) -> None:
        f = self.faults
        if f.drop and self._rng.random() < f.drop:
            self.stats["dropped"] += 1
            return
        packet = reply.packet
        if f.corrupt and self._rng.random() < f.corrupt:
            packet = packet[:-1] + bytes((packet[-1] ^ 0x5A,))
            self.stats["corrupted"] += 1
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        else:
            self.stats["late_replies"] += 1
        try:
            os.write(self._leader, packet)
        except OSError:
            return
        self.stats["replies"] += 1

    def _answering(self) -> dict[int, EmulatedServo]:
        """ID -> servo of the servos still on the bus."""
        return {s.servo_id: s for s in self.servos if not s.unplugged}

    def _on_write(self, servo: EmulatedServo, result: WriteResult) -> None:
        names = servo.model.names
        if names["operating_mode"] in result.touched:
            value = servo.get("operating_mode")
            mode = {v: k for k, v in servo.model.operating_modes.items()}.get(value)
            if mode is not None and mode != self.plant.mode:
                self._pending_mode = mode  # the plant thread rebuilds it at its next step

    def _new_plant(self, mode: str) -> SimBackend:
        """The plant in ``mode``, on the plant motors file's motors when one was given."""
        robot, models = plant_for(self.robot, mode, self._plant_motors, 1)
        return SimBackend(robot, mode=mode, seed=self._seed, models=models)

    def _switch_mode(self, mode: str) -> None:
        """Rebuild the plant in ``mode`` at the present pose, keeping the motor temperatures (one
        mode for the whole bus: a bus mixing modes is not modelled)."""
        old = self.plant
        q = old.true_position()[0].copy()
        winding = old.thermal.winding_temperature.copy()
        housing = old.thermal.housing_temperature.copy()
        self.plant = self._new_plant(mode)
        self.plant.reset(q)
        self.plant.thermal.winding_temperature[:] = winding
        self.plant.thermal.housing_temperature[:] = housing
        self._hold_present()

    # ------------------------------------------------------------------ the plant
    def _catch_up(self) -> None:
        """Step the plant until its clock has caught up with the wall clock (the plant thread).

        The registers are read (goals) and written (present values) under the lock; the MuJoCo
        step itself runs outside it, so a packet is answered while the plant steps."""
        period = self.robot.control_period
        due = int((time.monotonic() - self._t0) / period)
        if due - self._steps > _MAX_LAG / period:
            self._t0 += (due - self._steps) * period
            self.stats["plant_lag_resets"] += 1
            due = self._steps
        if self._steps >= due:
            return
        with self._lock:
            if self._pending_mode is not None:
                self._switch_mode(self._pending_mode)
                self._pending_mode = None
            self._update_faults(self._steps * period)
            self._apply_commands()
            command = self._command.copy()
        while self._steps < due:
            self.plant.write(command)
            self.plant.advance()
            self._steps += 1
            self.stats["plant_steps"] += 1
            with self._lock:
                self._add_heat(self._steps * period, period)
                winding = self.plant.thermal.winding_temperature[0]
                for s in self.servos:
                    s.update_protection(float(winding[s.joint]))
                if self._steps < due:
                    self._update_faults(self._steps * period)
                    self._apply_commands()
                    command = self._command.copy()
        with self._lock:
            self._refresh()

    def _add_heat(self, now: float, dt: float) -> None:
        """The ``heat`` faults: extra winding loss (W) over ``dt`` s into the plant's thermal
        model (its winding heat capacity, ``time constant / R_wh``), while the servo's torque is
        on (a loss that needs motor current: with torque off it stops)."""
        thermal = self.plant.thermal
        for sid, (watts, at) in self.faults.heat.items():
            servo = self._servo(sid)
            if now >= at and servo.get("torque_enable") == 1:
                thermal.winding_temperature[0, servo.joint] += watts * dt / thermal.c_w[servo.joint]

    def set_heat(self, servo_id: int, watts: float, at: float | None = None) -> None:
        """Servo ``servo_id`` takes ``watts`` of extra winding loss from ``at`` s after start
        (default: now); see :class:`WireFaults` ``heat``.

        Raises:
            KeyError: no such servo.
        """
        self._servo(servo_id)
        self.faults.heat[servo_id] = (float(watts), self.elapsed if at is None else at)

    def _update_faults(self, now: float) -> None:
        for s in self.servos:
            sid = s.servo_id
            if not s.unplugged and sid in self.faults.unplug and now >= self.faults.unplug[sid]:
                s.unplugged = True
                s.set("torque_enable", 0)
            at = self.faults.overload.get(sid)
            if at is not None and now >= at and "overload" not in s.faults:
                s.trip("overload")

    def _hold_present(self) -> None:
        """Command the plant to stay where it is (position mode) or stop (velocity mode)."""
        if self.plant.mode == "position":
            self._command[0] = self.plant.true_position()[0]
        else:
            self._command[0] = 0.0

    def _apply_commands(self) -> None:
        """The plant's command from each servo's torque and goal registers (module docstring)."""
        position_mode = self.plant.mode == "position"
        q = self.plant.true_position()[0]
        for s in self.servos:
            j = s.joint
            on = s.get("torque_enable") != 0 and not s.unplugged
            if position_mode:
                if on:
                    lo, hi = s.get("min_position"), s.get("max_position")
                    ticks = (
                        min(max(s.get("goal_position"), lo), hi)
                        if lo < hi
                        else s.get("goal_position")
                    )
                    actual = ticks - self._homing_shift(s)
                    self._command[0, j] = s.model.ticks_to_rad(actual, s.resolution)
                else:
                    # torque off: the drive's P term acts on one period's motion only, so the
                    # joint sags, damped; velocity mode below commands 0 rad/s, held by the
                    # plant's PI velocity loop (SimBackend has no limp drive)
                    self._command[0, j] = q[j]
            else:
                v = s.model.counts_to_velocity(s.get("goal_velocity")) if on else 0.0
                if on and s.model.has("velocity_limit"):
                    vmax = s.model.counts_to_velocity(s.get("velocity_limit"))
                    v = min(max(v, -vmax), vmax)
                self._command[0, j] = v

    @staticmethod
    def _homing_shift(s: EmulatedServo) -> int:
        """present position - actual position, ticks (module docstring)."""
        offset = s.get("Homing_Offset")
        return -offset if s.model.protocol == "feetech" else offset

    def _refresh(self) -> None:
        """Present registers from the plant."""
        p = self.plant
        q, dq = p.true_position()[0], p.true_velocity()[0]
        torque = p.joint_torque()[0]
        current = torque / p.thermal.torque_per_amp[0]
        winding = p.thermal.winding_temperature[0]
        tick_ms = int(self.elapsed * 1000.0) % 32768
        for s in self.servos:
            j, m = s.joint, s.model
            actual = m.rad_to_ticks(float(q[j]), s.resolution)
            s.set_clipped("present_position", actual + self._homing_shift(s))
            s.set_clipped("present_velocity", m.velocity_to_counts(float(dq[j])))
            if m.has("present_current"):
                s.set_clipped("present_current", float(current[j]) / m.current_unit)
            if m.has("present_load"):
                peak = self.robot.motors[j].peak_torque
                s.set_clipped("present_load", float(torque[j]) / peak / m.load_unit)
            s.set_clipped("present_voltage", 12.0 / m.voltage_unit)
            s.set_clipped("present_temperature", float(winding[j]))
            s.set("moving", int(abs(dq[j]) > 2.0 * m.velocity_unit))
            if m.has("Realtime_Tick"):
                s.set("Realtime_Tick", tick_ms)
