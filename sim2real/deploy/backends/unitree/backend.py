"""A Unitree robot's low-level DDS interface as a :class:`~sim2real.deploy.core.backend.Backend` (one
robot, wall clock): ``deploy-run --backend unitree``.

The robot's PD runs on each motor's driver, ``tau = tau_ff + kp (q_des - q) + kd (dq_des - dq)``:
position mode sends the runtime's targets with the joints' ``kp``/``kd`` (robot.toml's or the
policy's drive; a wheel's speed in ``dq_des``: :mod:`.motor_command`), torque mode sends
``tau_ff`` with ``kp = kd = 0``; velocity mode is refused (no integral term in the drivers).
Joints map to motor slots through robot.toml's ``[unitree] motor_index``. Commands go out
on ``rt/lowcmd`` with their CRC (:mod:`sim2real.deploy.backends.unitree.crc`); states come in on
``rt/lowstate`` and are taken, all of them, at every :meth:`UnitreeBackend.read`. The frame's
joints, attitude and feet are the newest valid state's; its gyro and accelerometer readings are
the mean over every valid state since the previous read (the angle and velocity increments over
the control period, divided by it): a policy's gait is locked to its control ticks, so one state
per tick samples a trot's yaw-rate swing at the same phase every stride, and the base filter
integrated that aliased rate into a heading drift (the shipped Go2 on unitree_mujoco).

``open()`` is the bring-up (:mod:`sim2real.deploy.backends.unitree.bringup`: LowState, ``mode_machine``, the
motion switcher's check, damping, a ramp to the home pose and a hold there; the ramp's gains
until the policy runs, then handed over to the joints', :mod:`.handover`); ``close()`` damps for
``CLOSE_DAMPING_TIME``, the last command the robot keeps. Damping (``kp`` 0, ``kd`` robot.toml's
``[unitree] damping_kd``), never a frozen stiff pose, is what the runtime asks for
(:meth:`UnitreeBackend.damp`) on a legged robot's every safe stop.

:meth:`UnitreeBackend.bus_summary` counts the states as the servo bus counts its dropouts: a
failed CRC (``bad_crc``), a sample that does not decode (``malformed``), a ``tick`` not newer than
the last (``stale``: late, repeated or reordered), ``tick`` gaps (``lost``), and each motor's
``lost`` packets (``unitree_go``; a joint whose count rose in the newest sample is a missing
reading, NaN); :meth:`UnitreeBackend.stale_context` what the reader saw since it last took a
state (a stale stop's record). The drivers' error codes (``Family.errors``) are
:meth:`UnitreeBackend.drive_errors`; the runtime stops on them (cause ``servo_error``).
"""

from __future__ import annotations

import sys
import threading
import time
from collections import Counter

import numpy as np

from sim2real.deploy.backends.unitree import bringup, summary
from sim2real.deploy.backends.unitree import family as families
from sim2real.deploy.backends.unitree.codec import MessageCodec
from sim2real.deploy.backends.unitree.dds import DdsLink
from sim2real.deploy.backends.unitree.family import TOPIC_LOWCMD, TOPIC_LOWSTATE
from sim2real.deploy.backends.unitree.handover import StandHandover
from sim2real.deploy.backends.unitree.motor_command import fill_motor_commands
from sim2real.deploy.backends.worker import Worker
from sim2real.deploy.core.backend import BackendLifecycle, SensorFrame, checked_command
from sim2real.deploy.core.latency import LatencyHistogram
from sim2real.deploy.kinds import robot_kind
from sim2real.robots import Robot

DROPOUT_KINDS = ("lost", "stale", "bad_crc", "malformed")
#: Hz, the LowCmd stream's default rate: Unitree's low-level examples publish a LowCmd every 2 ms
#: (unitree_sdk2 example/go2/go2_low_level, unitree_mujoco example/python/stand_go2.py).
LOWCMD_RATE = 500.0
#: States kept between two reads: a control period of 500 Hz states with room to spare.
STATE_DEPTH = 64
#: s of damping ``close()`` sends before it leaves (our choice: 25 commands at 50 Hz).
CLOSE_DAMPING_TIME = 0.5
#: Driver error codes by name (Unitree's motors: 4 is over temperature, as the maintainers of
#: unitree_actuator_sdk answer for the A1 motor's error 4).
DRIVER_ERRORS = {4: "over temperature"}


def _stderr(text: str) -> None:
    print(f"unitree: {text}", file=sys.stderr, flush=True)


class UnitreeBackend(BackendLifecycle):
    """A Unitree robot over DDS (module docstring).

    Args:
        robot: The robot; its robot.toml needs a ``[unitree]`` table.
        interface: Network interface the robot is on (e.g. ``eth0``; ``lo`` for the emulator);
            None: Cyclone DDS chooses.
        domain_id: DDS domain (0 on the robots, 1 in Unitree's simulation bridges).
        family: ``unitree_go`` or ``unitree_hg``; default robot.toml's ``[unitree] family``.
        mode: 'position' or 'torque' (default robot.toml's).
        lowstate_timeout: s ``open()`` waits for the first LowState.
        check_sport_mode: ask the motion switcher whether a high-level mode is active.
        lowcmd_rate: Hz at which the last command is re-sent between the runtime's (and the
            bring-up's) commands, from the backend's own thread, each with its CRC
            (``LOWCMD_RATE``, the rate of Unitree's own low-level examples); 0: one LowCmd a
            control period. A driver applies its last command until the next; a simulation
            bridge that computes the PD torque only when a command arrives holds that torque.
        lowstate_unchecked: accept LowState samples that carry no CRC and no tick (both 0), as
            Unitree's simulation bridges (unitree_mujoco) publish them: such a sample is taken
            as it arrives, the newest one per read. Samples with a CRC are still checked. Never
            on a robot: a real robot fills both, and a sample without them is corrupt.
        log: Where bring-up stages are printed (default: stderr, ``unitree: ...``).

    Attributes:
        envs: 1. mode: the control mode. frame: the last :class:`SensorFrame`.
        dropouts: Counter of states lost or refused by kind (``DROPOUT_KINDS``).
        motor_lost: (n_joints,) int64, packets each joint's motor lost (``unitree_go``).
        received: LowState samples taken. sent: LowCmd samples written.
        read_cost, write_cost: :class:`LatencyHistogram` (ns) of a read and a write (the DDS
            layer's cost per tick). state_age: :class:`LatencyHistogram` of the newest state's
            age at a read (its source timestamp to now: meaningful when the robot's clock is
            synchronised with this computer's, as on the loopback).
        mode_machine: the robot's ``mode_machine`` (``unitree_hg``), once open.

    Raises:
        ValueError: no ``[unitree]`` table, velocity mode, an unknown family.
    """

    #: every LowCmd carries each joint's kp and kd: a policy's own drive runs as it is
    commands_gains = True

    def __init__(
        self,
        robot: Robot,
        interface: str | None = None,
        domain_id: int = 0,
        family: str | None = None,
        mode: str | None = None,
        lowstate_timeout: float = bringup.LOWSTATE_TIMEOUT,
        check_sport_mode: bool = True,
        log=_stderr,
        lowstate_unchecked: bool = False,
        lowcmd_rate: float | None = None,
    ):
        cfg = robot.config.unitree
        if cfg is None:
            raise ValueError(
                f"{robot.directory / 'robot.toml'}: no [unitree] table (family, motor_index, "
                "damping_kd): --backend unitree needs the robot's motor slots"
            )
        self.robot, self.config, self.log = robot, cfg, log
        self.family = families.family(family or cfg.family)
        self.mode = mode or robot.control_mode
        if self.mode not in ("position", "torque"):
            raise ValueError(
                f"--backend unitree: mode '{self.mode}' is not supported (the motor drivers run "
                "a PD: 'position' or 'torque')"
            )
        self.interface, self.domain_id = interface, int(domain_id)
        self.lowstate_timeout, self.check_sport_mode = lowstate_timeout, check_sport_mode
        self.lowstate_unchecked = bool(lowstate_unchecked)
        rate = LOWCMD_RATE if lowcmd_rate is None else float(lowcmd_rate)
        if not (np.isfinite(rate) and rate >= 0):
            raise ValueError(f"--lowcmd-rate: expected a rate >= 0 Hz, got {lowcmd_rate}")
        #: s between two LowCmd at most (None: one a control period, no re-sending)
        self.resend_period = 1.0 / rate if rate > 0 else None
        self.resent = 0  # LowCmd re-sent by the stream thread
        self._last_send: tuple | None = None
        self._last_send_at = 0.0
        self._stream = Worker("unitree-lowcmd", self._stream_loop)
        #: samples refused for their CRC whose ``crc`` field was 0 (a bridge that fills none)
        self.zero_crc = 0
        #: samples taken unchecked (``lowstate_unchecked``: no CRC, no tick)
        self.unchecked = 0
        self.envs, self.n = 1, robot.n_joints
        self.names = list(robot.joint_names)
        self.slots = np.array(cfg.motor_index, dtype=np.int64)
        self.kp = np.array([j.kp for j in robot.config.joints])
        self.kd = np.array([j.kd for j in robot.config.joints])
        self.damping_kd = np.broadcast_to(np.asarray(cfg.damping_kd, dtype=np.float64), self.n)
        #: joint indices of the velocity-driven joints (wheels): speed targets in ``dq``
        self._wheels = np.flatnonzero(robot.velocity_driven)
        self.ramp_kp = self.kp if cfg.ramp_kp is None else np.broadcast_to(cfg.ramp_kp, self.n)
        self.ramp_kd = self.kd if cfg.ramp_kd is None else np.broadcast_to(cfg.ramp_kd, self.n)
        self.period = robot.control_period
        self.feet = None
        self.frame = robot_kind(robot).sensor_frame(robot, 1)  # an IMU and feet: a floating base
        if self.family.has_feet and self.frame.foot_contact is not None and cfg.foot_index:
            self.feet = np.array(cfg.foot_index, dtype=np.int64)
        self.contact_threshold = (
            robot.config.sensors.contact.threshold if robot.config.sensors.contact else 0.0
        )
        self._state = MessageCodec(self.family.low_state)
        self._cmd = MessageCodec(self.family.low_cmd)
        self.dropouts: Counter[str] = Counter({k: 0 for k in DROPOUT_KINDS})
        self.motor_lost = np.zeros(self.n, dtype=np.int64)
        self.received = self.sent = self.reads = 0
        self.read_cost, self.write_cost = LatencyHistogram(), LatencyHistogram()
        self.state_age = LatencyHistogram()
        self.mode_machine: int | None = None
        self.latched_errors = np.zeros(self.n, dtype=np.int64)
        self._errors = np.zeros((1, self.n), dtype=np.int64)
        self._last_tick: int | None = None
        self._refused = 0  # states refused (bad CRC, malformed) since the last accepted one
        #: ``received`` and ``dropouts`` when the last state was taken, and the source stamps
        #: (ns, time.time_ns) of the newest state received and taken (summary.stale_context)
        self.at_taken = {"received": 0, **self.dropouts}
        self.newest_stamp_ns = self.taken_stamp_ns = 0
        self._tick_step: int | None = None
        self._prev_lost: np.ndarray | None = None
        #: gyro (rad/s) and accelerometer (m/s^2) readings summed over the valid states since
        #: the previous read, and their count (the frame's IMU reading is their mean)
        self._imu_sum = np.zeros(6)
        self._imu_count = 0
        self._last_fresh = -np.inf
        self._damping = False
        self._enabled = False
        self._link: DdsLink | None = None
        self._reader = self._writer = None
        self._lock = threading.Lock()
        self._read_lock = threading.Lock()
        self._hold_reads = False
        self._hold = Worker("unitree-hold", self._hold_loop)
        self._hold_target = np.asarray(robot.home, dtype=np.float64).copy()
        stand = (self.ramp_kp, self.ramp_kd, self.kp, self.kd, robot.home, robot.velocity_driven)
        self.handover = StandHandover(*stand)
        self._t0 = time.monotonic()
        self._opened_at = None
        #: s: the bring-up (open to at home), and the hold at home before the runtime's first
        #: command (its rig was built before the bring-up: only its start); None before each
        self.bringup_s: float | None = None
        self.held_at_home_s: float | None = None

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        """Join the domain and bring the robot up (module docstring); idempotent.

        Raises:
            sim2real.deploy.backends.unitree.bringup.BringupError: no LowState, a high-level mode still
                active, a pose the robot did not follow; the robot is left damped.
            sim2real.deploy.backends.unitree.dds.DdsError: the domain cannot be joined.
        """
        if self._link is not None:
            return
        self._link = DdsLink(self.domain_id, self.interface)
        self._reader = self._link.reader(TOPIC_LOWSTATE, self.family.low_state, STATE_DEPTH)
        self._writer = self._link.writer(TOPIC_LOWCMD, self.family.low_cmd)
        self._opened_at = time.monotonic()
        if self.resend_period is not None:  # re-send the last command when nothing else was
            self._stream.start()
        try:
            bringup.bring_up(self)
            self.bringup_s = time.monotonic() - self._opened_at
        except BaseException:
            self._close_link(damp=self.sent > 0)
            raise
        self._enabled = True
        self._hold_reads = True
        self._hold.start()

    def close(self) -> None:
        """Damping for ``CLOSE_DAMPING_TIME`` (the last command the robot keeps), then leave the
        domain; idempotent."""
        self._hold.stop()
        self._close_link(damp=True)

    def _close_link(self, damp: bool) -> None:
        if self._link is None:
            return
        try:
            if damp:
                self._damping = True
                end = time.monotonic() + CLOSE_DAMPING_TIME
                while time.monotonic() < end:
                    self._send(self._hold_target)
                    time.sleep(self.period)
        finally:
            self._stream.stop()
            self._reader = self._writer = None
            self._link.close()
            self._link = None
            self._enabled = False

    def enable(self) -> None:
        """The drivers' PD takes the commands again (after :meth:`disable`)."""
        self._damping = False
        self._enabled = True

    def disable(self) -> None:
        """Damping from the next command on (kp 0, ``damping_kd``): the robot lies down."""
        self._damping = True
        self._enabled = False

    def damp(self, envs: np.ndarray) -> None:
        """The runtime's request: damping (``envs[0]`` True) or the commands (False)."""
        self._damping = bool(envs[0]) or not self._enabled

    # ------------------------------------------------------------------ the command stream
    def _stream_loop(self, stop: threading.Event) -> None:
        """Re-send the last command every ``resend_period`` s when nothing else was sent."""
        period = self.resend_period
        while not stop.wait(period):
            last = self._last_send
            if last is not None and time.monotonic() - self._last_send_at >= 0.9 * period:
                self._send(*last)
                self.resent += 1

    # ------------------------------------------------------------------ hold until the runtime
    def _hold_loop(self, stop: threading.Event) -> None:
        """Until the runtime's first command, every control period: send the home pose, and
        until the runtime's first read, take the states (their counters stay whole; none for
        ``bringup.BRINGUP_STALE``, as in the bring-up: damping from then on)."""
        next_t = time.monotonic()
        while not stop.is_set():
            with self._read_lock:
                if self._hold_reads:
                    self._read()
                    if time.monotonic() - self._t0 - self._last_fresh > bringup.BRINGUP_STALE:
                        self._damping = True
            self._send(self._hold_target, self.ramp_kp, self.ramp_kd)
            next_t += self.period
            stop.wait(max(0.0, next_t - time.monotonic()))

    # ------------------------------------------------------------------ the three calls
    def read(self) -> SensorFrame:
        """Take every LowState received since the last read; the frame from the newest valid
        one (NaN where none arrived, or where that joint's motor lost its packet). The frame is
        overwritten by the next read."""
        with self._read_lock:  # the bring-up's hold thread reads until this first call
            self._hold_reads = False
            return self._read()

    def _read(self) -> SensorFrame:
        t0 = time.perf_counter_ns()
        now = time.monotonic() - self._t0
        f = self.frame
        f.time[0] = now
        newest, newest_stamp, newest_lost = None, 0, None
        decoded = None
        for data, stamp in self._reader.take_raw(STATE_DEPTH):
            self.received += 1
            self.newest_stamp_ns = stamp
            decoded = data
            try:
                valid = self._state.decode(data)
            except ValueError:
                self.dropouts["malformed"] += 1
                self._refused += 1
                continue
            unchecked = int(self._state.message["crc"]) == 0
            if not valid and not (unchecked and self.lowstate_unchecked):
                self.dropouts["bad_crc"] += 1
                self.zero_crc += unchecked
                self._refused += 1
                continue
            if unchecked and not valid:  # a simulator's sample: no tick to order it by
                self.unchecked += 1
            elif not self._fresh_tick(int(self._state.message["tick"])):
                continue
            lost = self.family.lost(self._state.message, self.slots)
            if lost is not None:
                lost = lost.astype(np.int64)
                if self._prev_lost is not None:
                    increase = (lost - self._prev_lost) % (1 << 32)
                    self.motor_lost += increase
                    newest_lost = increase > 0
                self._prev_lost = lost
            newest, newest_stamp = data, stamp
            imu = self._state.message["imu_state"]
            self._imu_sum[:3] += imu["gyroscope"]
            self._imu_sum[3:] += imu["accelerometer"]
            self._imu_count += 1
        if newest is None:
            self._no_reading(f)
        else:
            if decoded is not newest:  # the newest valid sample is not the one in the record
                self._state.decode(newest)
            self._fill(f, now, newest_lost)
            self._last_fresh, self.taken_stamp_ns = now, newest_stamp
            at = self.at_taken  # the counts now (no new dict: a few ints per read)
            at["received"] = self.received
            for kind in DROPOUT_KINDS:
                at[kind] = self.dropouts[kind]
            self.state_age.add(0, max(0, time.time_ns() - newest_stamp))
        self.reads += 1
        self.read_cost.add(0, time.perf_counter_ns() - t0)
        return f

    def _fresh_tick(self, tick: int) -> bool:
        """Whether ``tick`` is newer than the last accepted one; counts stale and lost states."""
        last = self._last_tick
        if last is not None:
            step = ((tick - last + (1 << 31)) % (1 << 32)) - (1 << 31)  # signed, wrapping
            if step <= 0:
                self.dropouts["stale"] += 1
                return False
            if self._tick_step is None or step < self._tick_step:
                self._tick_step = step
            # the states in the gap that arrived refused are counted as such, not as lost
            self.dropouts["lost"] += max(0, round(step / self._tick_step) - 1 - self._refused)
        self._last_tick = tick
        self._refused = 0
        return True

    def _no_reading(self, f: SensorFrame) -> None:
        f.position[0] = f.position_stamp[0] = f.velocity[0] = np.nan
        self._errors.fill(0)
        if f.imu_stamp is not None:
            f.imu_angular_velocity[0] = f.imu_acceleration[0] = np.nan
            f.imu_orientation[0] = np.nan
            f.imu_stamp[0] = f.contact_stamp[0] = np.nan

    def _fill(self, f: SensorFrame, now: float, lost: np.ndarray | None) -> None:
        m, fam = self._state.message, self.family
        ms = m["motor_state"]
        f.position[0] = ms["q"][self.slots]
        f.velocity[0] = ms["dq"][self.slots]  # the drives' own velocity reading
        f.position_stamp[0] = now
        if lost is not None and lost.any():
            f.position[0, lost] = f.position_stamp[0, lost] = f.velocity[0, lost] = np.nan
        f.winding_temperature[0] = fam.temperature(m, self.slots)
        f.temperature_stamp[0] = now
        if self.mode_machine is None:
            self.mode_machine = fam.mode_machine(m)
        if self.config.driver_errors:
            self._errors[0] = fam.errors(m, self.slots)
            self.latched_errors |= self._errors[0]
        if f.imu_stamp is not None:
            imu = m["imu_state"]
            mean = self._imu_sum / max(self._imu_count, 1)
            f.imu_angular_velocity[0] = mean[:3]
            f.imu_acceleration[0] = mean[3:]
            self._imu_sum[:] = 0.0
            self._imu_count = 0
            quat = np.asarray(imu["quaternion"], dtype=np.float64)  # w, x, y, z
            norm = np.linalg.norm(quat)
            # the IMU's own attitude; a zero quaternion (a bridge that fills none): no attitude
            f.imu_orientation[0] = quat / norm if norm > 0.5 else np.nan
            f.imu_stamp[0] = now
            if self.feet is not None:
                force = m["foot_force"][self.feet] * self.config.foot_force_scale
                f.foot_force[0] = force
                f.foot_contact[0] = force > self.contact_threshold
            else:  # no foot sensors (unitree_hg): the estimator's contact is the kinematics'
                f.foot_force[0] = np.nan
                f.foot_contact[0] = False
            f.contact_stamp[0] = now

    def write(self, command: np.ndarray) -> None:
        """One LowCmd: position targets (rad) with the joints' kp/kd, or torques (N m), or
        damping while the runtime asks for it; ``command`` shaped (1, n_joints). The first
        call ends the bring-up's hold; the policy's first is logged (a gantry may let go).

        Raises:
            ValueError: wrong shape or a non-finite value (nothing is written).
        """
        command = checked_command(command, self.n)
        if self._hold.running:
            self._hold.stop()
            now = time.monotonic()
            self.held_at_home_s = now - self._opened_at - (self.bringup_s or 0.0)
        stood = not self.handover.policy
        self.handover.command(None if self._last_send is None else self._last_send[0])
        if stood and self.handover.policy:  # once: the moment a gantry may let go
            self.log(f"      the policy runs; its gains take over within {bringup.BLEND_TIME:g} s")
        t0 = time.perf_counter_ns()
        self._send(command[0])
        self.write_cost.add(0, time.perf_counter_ns() - t0)

    def _send(self, target: np.ndarray, kp=None, kd=None) -> None:
        """Encode and write one LowCmd: damping, or ``target`` as the mode's command; with
        ``kp``/``kd`` ((n,) or scalars), ``target`` is a position target with those gains."""
        with self._lock:
            if self._writer is None:  # closed meanwhile (the stream thread's last turn)
                return
            # a copy: the runtime reuses its command buffer for the next tick's
            self._last_send = (np.array(target, dtype=np.float64), kp, kd)
            self._last_send_at = time.monotonic()
            kind = "damping" if self._damping else "hold" if kp is not None else self.mode
            if kind == "damping":
                kp, kd = 0.0, self.damping_kd
            elif kind == "position":  # the stand's law handed over to the policy's
                target, kp, kd = self.handover.law(target)
            mc = self._cmd.message["motor_cmd"]
            args = (self.slots, self._wheels, self.config.motor_mode, kind, target, kp, kd)
            fill_motor_commands(mc, *args)
            self.family.init_command(self._cmd.message, self.mode_machine or 0)
            self._writer.write_raw(self._cmd.encode())
            self.sent += 1

    def watch_modes(self, mode: np.ndarray) -> None:
        """The stand's gains hold until the runtime's env 0 is RUNNING (``mode``: its (envs,) mode
        array, read only), then hand over (:mod:`.handover`); unwatched: at the first command."""
        self.handover.watch(mode)

    def advance(self) -> None:
        """Nothing: the robot runs on its own; the runtime's wall clock paces the loop."""

    # ------------------------------------------------------------------ reports
    def drive_errors(self) -> np.ndarray:
        """(1, n_joints) int64 driver error codes of the newest state (0: none)."""
        return self._errors

    def describe_drive_error(self, joint: int, bits: int) -> str:
        """``'motor 3 (FL_hip_joint): driver error 0x4 (over temperature)'``."""
        name = DRIVER_ERRORS.get(int(bits), "unknown")
        return (
            f"motor {int(self.slots[joint])} ({self.names[joint]}): driver error {bits:#x} ({name})"
        )

    def bus_summary(self) -> dict:
        """Figures for the run's report (:func:`~sim2real.deploy.backends.unitree.summary.
        bus_summary`: states, dropouts, costs, ages, driver errors)."""
        return summary.bus_summary(self)

    def stale_context(self, env: int = 0) -> dict:
        """What ``rt/lowstate``'s reader saw since the last state it took
        (:func:`~sim2real.deploy.backends.unitree.summary.stale_context`); ``env`` is 0."""
        return summary.stale_context(self)
