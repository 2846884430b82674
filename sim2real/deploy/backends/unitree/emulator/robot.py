"""The emulated Unitree robot: the MuJoCo plant behind the robot's own DDS topics.

:class:`UnitreeEmulator` joins a DDS domain (the loopback by default, domain 1 as Unitree's
simulation bridges), publishes ``rt/lowstate`` at the physics rate (500 Hz on the Go2, as the
robot's board), takes ``rt/lowcmd`` and answers the motion switcher, the way Unitree's own
unitree_mujoco bridge stands in for a robot. Nothing in the controller knows it talks to an
emulator.

Plant: a :class:`sim2real.deploy.backends.sim.plant.SimBackend` of the robot with its control period set
to the physics timestep and its sensors read at every step (encoders, IMU, foot contact: the
robot's sensor model at the board's rate), one affine PD actuator per joint
(:mod:`.drivers`). It steps on its own thread, paced by the wall clock: every period it takes the
LowCmd received since the last step (CRC checked: a bad one is dropped and counted), steps the
plant, lets each driver protect itself (its over-temperature cut-off), and publishes the LowState
(:mod:`.lowstate`), unless a fault (:mod:`.faults`) loses, delays or corrupts it. When the plant
falls more than ``MAX_LAG`` behind the wall clock (a machine slower than real time) its time
origin moves up and ``stats['plant_lag_resets']`` counts it.

The robot starts as a low-level program finds it (``start='lying'``, the default): lying down
after its own stand-down, legs folded (``LYING_POSES``; a robot without one collapses where it
stands), its drivers off. ``start='standing'``: the drivers hold the home pose with the joints'
kp/kd until the first LowCmd, as the plant of ``--backend sim`` starts.
"""

from __future__ import annotations

import dataclasses
import random
import threading
import time
from collections import Counter, deque

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.backends.unitree import family as families
from sim2real.deploy.backends.unitree.codec import MessageCodec
from sim2real.deploy.backends.unitree.dds import DdsLink
from sim2real.deploy.backends.unitree.emulator.band import ElasticBand, parse_band
from sim2real.deploy.backends.unitree.emulator.drivers import MotorDrivers, pd_model
from sim2real.deploy.backends.unitree.emulator.faults import EmulatorFaults
from sim2real.deploy.backends.unitree.emulator.lowstate import LowStateBuilder
from sim2real.deploy.backends.unitree.emulator.services import MotionSwitcherService
from sim2real.deploy.backends.unitree.family import TOPIC_LOWCMD, TOPIC_LOWSTATE
from sim2real.deploy.backends.unitree.remote import (
    TOPIC_CONTROLLER,
    RemoteScript,
    controller_message,
)
from sim2real.deploy.backends.worker import ServesOnThread
from sim2real.deploy.core.collector import collector_paused
from sim2real.deploy.core.latency import LatencyHistogram
from sim2real.robots import Robot, load_robot
from sim2real.robots.plant_motors import load_plant_motors

#: s the plant may fall behind the wall clock before its time origin moves up.
MAX_LAG = 0.25
#: Physics steps between two polls of the motion switcher's requests.
SERVICE_EVERY = 10
#: The folded pose a robot lies in after its own stand-down, rad, in Unitree's motor order: the
#: Go2's from unitree_mujoco's example/python/stand_go2.py (``stand_down_joint_pos``).
LYING_POSES = {
    "go2": (0.0473455, 1.22187, -2.44375, -0.0473455, 1.22187, -2.44375) * 2,
}
#: s of simulated time a lying robot settles on the floor before the emulator serves (our choice).
SETTLE_TIME = 1.0
#: Commands kept in :attr:`UnitreeEmulator.commands` (two minutes at the backend's 500 Hz stream,
#: ten at one a 50 Hz tick; about 700 bytes each).
COMMAND_LOG = 60_000
#: Physics steps between two ``rt/wirelesscontroller`` samples of a scripted remote (50 Hz at the
#: board's 500 Hz; our choice, a remote's own report rate is not published).
CONTROLLER_EVERY = 10
#: Physics steps between two samples of the base's true trajectory (:attr:`UnitreeEmulator.trace`).
TRACE_EVERY = 10
#: How the robot starts (``start``): the first is the default.
STARTS = ("lying", "standing")
START_HELP = (
    "lying: folded on the floor, drivers off (as after the robot's stand-down); "
    "standing: holding the home pose until the first LowCmd"
)
#: K above the motor's maximum winding temperature (robot.toml's motor) at which the emulated
#: driver cuts off, by default (our choice: Unitree publishes no cut-off temperature).
CUTOFF_MARGIN = 10.0


def board_rate_robot(robot: Robot) -> Robot:
    """``robot`` with its control period set to its physics timestep and every sensor (encoders,
    IMU, foot contact) read at that rate: the plant of a robot's board, which samples and
    reports at every physics step."""
    rate = 1.0 / robot.physics_timestep
    cfg = robot.config
    s = cfg.sensors
    sensors = s.model_copy(
        update={
            "encoder_rate": rate,
            "imu": s.imu.model_copy(update={"rate": rate}) if s.imu else None,
            "contact": s.contact.model_copy(update={"rate": rate}) if s.contact else None,
        }
    )
    control = cfg.control.model_copy(update={"control_rate": rate})
    config = cfg.model_copy(update={"sensors": sensors, "control": control})
    return dataclasses.replace(
        robot, config=config, control_period=robot.physics_timestep, decimation=1
    )


class UnitreeEmulator(ServesOnThread):
    """A Unitree robot's low-level DDS interface backed by the MuJoCo plant (module docstring).

    Use as a context manager (``with UnitreeEmulator('go2', domain_id=7) as emu:``) or call
    :meth:`start` / :meth:`stop`; :meth:`serve` runs it in the calling thread.

    Args:
        robot: A :class:`robots.Robot` with a ``[unitree]`` table, or a robot name / path.
        family: ``unitree_go`` or ``unitree_hg`` (default: robot.toml's).
        domain_id: DDS domain. interface: network interface (``lo``: this computer only).
        faults: Faults to inject (default none); ``emu.faults`` may be changed while running.
        seed: Seed of the fault draws and of the plant's sensor noise.
        sport_mode: The high-level mode the motion switcher reports active ('' : none).
        mode_machine: The ``mode_machine`` a ``unitree_hg`` robot reports.
        cutoff_temperature: degC at which each driver cuts off (default: the motor's maximum
            winding temperature + ``CUTOFF_MARGIN``).
        start: 'lying' (folded on the floor, the drivers off) or 'standing' (the drivers hold
            the home pose until the first LowCmd); see the module docstring.
        remote: A scripted wireless remote (:class:`~sim2real.deploy.backends.unitree.remote.
            RemoteScript`, a TOML file) played in every LowState's ``wireless_remote`` on the
            faults' clock; None: the remote's bytes stay zero (nothing held).
        bridge: None (a robot: CRC and tick filled, foot forces, each driver's PD at every
            physics step) or ``'unitree_mujoco'``: what Unitree's simulation bridge does
            (LowState without CRC, tick or foot forces; the PD torque computed on a LowCmd's
            arrival and held until the next; :mod:`.lowstate`, :mod:`.drivers`).
        band: ``LENGTH[@RELEASE]``: hang the robot from unitree_mujoco's elastic band
            (:mod:`.band`), released ``RELEASE`` s after the first LowCmd; None: no band.

    Attributes:
        plant: The :class:`SimBackend`. drivers: The :class:`.drivers.MotorDrivers`.
        stats: Counters: ``lowstate_published``, ``lowstate_lost``, ``lowstate_corrupted``,
            ``lowstate_delayed``, ``lowcmd_received``, ``lowcmd_bad_crc``,
            ``lowcmd_malformed``, ``lowcmd_ignored`` (a high-level mode active),
            ``plant_steps``, ``plant_lag_resets``, ``cutoffs``.
        command_to_state: :class:`LatencyHistogram` (ns): a LowCmd's source timestamp to the
            publication of the first LowState after the step that applied it.
        cutoff_log: (seconds after the first LowCmd, motor slot) of each driver cut-off.
        damping_onsets: (monotonic time, s since the last LowState published) of each switch
            of the commands to damping (every joint's kp 0, kd > 0).
        commands: The last ``COMMAND_LOG`` commands taken, in joint order: (monotonic time,
            q_des, kp, kd), each (n,).
        true_distance: m, the base's planar path length since the first LowCmd.
        trace: Rows (monotonic time s, x m, y m, yaw rad, vx m/s, vy m/s: the base's true
            planar position in the world and velocity in its heading frame) every
            ``TRACE_EVERY`` physics steps since the first LowCmd (:meth:`truth`).

    Raises:
        ValueError: no ``[unitree]`` table, a fault naming a motor slot no joint uses.
    """

    def __init__(
        self,
        robot: Robot | str,
        *,
        family: str | None = None,
        domain_id: int = 1,
        interface: str | None = "lo",
        faults: EmulatorFaults | None = None,
        seed: int = 0,
        sport_mode: str = "",
        mode_machine: int = 0,
        cutoff_temperature: float | None = None,
        start: str = "lying",
        bridge: str | None = None,
        plant_motors: str | None = None,
        remote: str | None = None,
        band: str | None = None,
    ):
        if bridge not in (None, "unitree_mujoco"):
            raise ValueError(f"bridge '{bridge}': expected None or 'unitree_mujoco'")
        self.bridge = bridge
        self.remote = RemoteScript(remote) if remote else None
        self.robot = robot if isinstance(robot, Robot) else load_robot(robot)
        cfg = self.robot.config.unitree
        if cfg is None:
            raise ValueError(f"{self.robot.directory / 'robot.toml'}: no [unitree] table")
        if start not in STARTS:
            raise ValueError(f"start '{start}': expected 'standing' or 'lying'")
        self.family = families.family(family or cfg.family)
        self.slots = np.array(cfg.motor_index)
        self.joint_of = {int(s): j for j, s in enumerate(self.slots)}
        self.faults = faults if faults is not None else EmulatorFaults()
        unknown = sorted((set(self.faults.silent) | set(self.faults.heat)) - set(self.joint_of))
        if unknown:
            raise ValueError(
                f"faults name motor slots {unknown}; the robot's: {sorted(self.joint_of)}"
            )
        self._build_plant(plant_motors, seed, band)
        if cutoff_temperature is None:
            cutoff = [m.max_winding_temperature + CUTOFF_MARGIN for m in self.robot.motors]
        else:
            cutoff = cutoff_temperature
        self.drivers = MotorDrivers(
            self.fast,
            self.slots,
            cutoff,
            hold_home=start == "standing",
            hold_torque=bridge is not None,
        )
        if start == "lying":
            self._lie_down()
        feet = None
        if self.family.has_feet and cfg.foot_index:
            feet = np.array(cfg.foot_index)
        self.builder = LowStateBuilder(
            self.family,
            self.slots,
            feet,
            cfg.foot_force_scale,
            cfg.motor_mode,
            mode_machine,
            bridge=bridge is not None,
        )
        self._open_dds(domain_id, interface, sport_mode)
        self._cmd = MessageCodec(self.family.low_cmd)
        self._rng = random.Random(seed)
        self._new_logs()
        self._damping = False
        self._pending: list[int] = []
        self._delayed: deque[tuple[float, bytes]] = deque()
        self._first_command: float | None = None
        self._last_published = time.monotonic()
        self._base = np.zeros((1, 13))
        self._xy = self.plant.true_base_state(out=self._base)[0, :2].copy()
        self.plant.read()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._t0 = time.monotonic()
        self._started = self._t0
        self._steps = 0

    def _build_plant(self, plant_motors: str | None, seed: int, band: str | None) -> None:
        """The plant at the board's rate (``fast``, ``period``, its PD ``model``), with the
        motors as they really are where a file says (:mod:`sim2real.robots.plant_motors`), and
        the gantry band."""
        self.fast = board_rate_robot(self.robot)
        self.period = self.fast.control_period
        self.model = pd_model(self.fast)
        plant_robot = self.fast
        if plant_motors is not None:  # the motors as they really are (sim2real.robots.plant_motors)
            plant = load_plant_motors(plant_motors, self.fast)
            plant_robot, self.model = plant.robot, plant.apply(self.model)
        self.plant = SimBackend(plant_robot, mode="position", seed=seed, models=[self.model])
        #: the gantry (``LENGTH[@RELEASE]``, :mod:`.band`); None: the robot stands on its own
        self.band = ElasticBand(self.plant, *parse_band(band)) if band else None

    def _open_dds(self, domain_id: int, interface: str | None, sport_mode: str) -> None:
        """The DDS link: lowstate written, lowcmd read, the motion switcher's service, and the
        scripted remote's topic."""
        self.link = DdsLink(domain_id, interface)
        self.domain_id, self.interface = domain_id, interface
        self._states = self.link.writer(TOPIC_LOWSTATE, self.family.low_state)
        self._commands = self.link.reader(TOPIC_LOWCMD, self.family.low_cmd, depth=16)
        self.service = MotionSwitcherService(self.link, sport_mode)
        #: the scripted remote's own topic too (rt/wirelesscontroller), every CONTROLLER_EVERY steps
        self._controller = None
        if self.remote is not None:
            from sim2real.deploy.backends.unitree.unitree_go import WirelessController_

            self._controller = self.link.generic_writer(TOPIC_CONTROLLER, WirelessController_)

    def _new_logs(self) -> None:
        """The counters, histograms and logs of a run."""
        self.stats: Counter[str] = Counter()
        self.command_to_state = LatencyHistogram()
        self.cutoff_log: list[tuple[float, int]] = []
        self.damping_onsets: list[tuple[float, float]] = []
        self.true_distance = 0.0
        self.trace: list[tuple[float, ...]] = []
        self.commands: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = deque(
            maxlen=COMMAND_LOG
        )

    def _lie_down(self) -> None:
        """The robot folded on the floor (``LYING_POSES``: dropped there, the drivers holding the
        pose for ``SETTLE_TIME``), then its drivers off; without a lying pose, the drivers off
        and the robot settling for ``SETTLE_TIME`` where it stood."""
        pose = LYING_POSES.get(self.robot.name)
        d = self.drivers
        if pose is not None:
            folded = np.asarray(pose)[self.slots]
            self.plant.reset(folded)
            d.q_des[:], d.mode[:] = folded, 1
            d.kp[:] = [j.kp for j in self.robot.config.joints]
            d.kd[:] = [j.kd for j in self.robot.config.joints]
        for _ in range(int(round(SETTLE_TIME / self.period))):
            self.plant.write(d.apply(self.model))
            self.plant.advance()
        d.mode[:] = 0
        d.kp[:] = d.kd[:] = 0.0

    # ------------------------------------------------------------------ lifecycle
    # (the context manager, start() and request_stop(): ServesOnThread)
    THREAD_NAME = "unitree-emulator"

    def stop(self) -> None:
        """Stop serving and leave the DDS domain (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._thread = None
        if self.link is not None:
            self.link.close()
            self.link = None

    @property
    def elapsed(self) -> float:
        """s since the first LowCmd (the faults' clock; 0 before it)."""
        return 0.0 if self._first_command is None else time.monotonic() - self._first_command

    def serve(self) -> None:
        """Step, take commands and publish states until :meth:`stop` (blocking), with the
        garbage collector paused (:func:`~sim2real.deploy.core.collector.collector_paused`: a
        full collection here is a gap in ``rt/lowstate`` longer than a robot's stale limit)."""
        with collector_paused():
            self._serve()

    def _serve(self) -> None:
        self._t0 = self._started = time.monotonic()
        self._steps = 0
        period = self.period
        while not self._stop.is_set():
            due = int((time.monotonic() - self._t0) / period)
            if due - self._steps > MAX_LAG / period:
                self._t0 += (due - self._steps) * period
                self.stats["plant_lag_resets"] += 1
                due = self._steps
            while self._steps < due and not self._stop.is_set():
                self._step()
                self._steps += 1
            self._stop.wait(max(0.0, self._t0 + (self._steps + 1) * period - time.monotonic()))

    # ------------------------------------------------------------------ one physics step
    def _step(self) -> None:
        self._take_commands()
        t = self.elapsed
        self._update_faults(t)
        if self.band is not None:
            self.band.apply(None if self._first_command is None else t)
        self.plant.write(self.drivers.apply(self.model))
        self.plant.advance()
        self.plant.read()  # the sensor frame of this step
        self.stats["plant_steps"] += 1
        self._heat(t)
        winding = self.plant.thermal.winding_temperature[0]
        for j in np.flatnonzero(self.drivers.protect(winding)):
            self.cutoff_log.append((t, int(self.slots[j])))
            self.stats["cutoffs"] += 1
        self.drivers.lost[self.drivers.silent] += 1
        base = self.plant.true_base_state(out=self._base)[0]
        xy = base[:2]
        if self._first_command is not None:
            self.true_distance += float(np.hypot(*(xy - self._xy)))
            if self._steps % TRACE_EVERY == 0:
                self.trace.append(_planar(time.monotonic(), base))
        self._xy[:] = xy
        self._publish(t)
        if self._steps % SERVICE_EVERY == 0:
            self.service.poll()

    def _take_commands(self) -> None:
        src = self._cmd._src
        for data, stamp in self._commands.take_raw(16):
            self.stats["lowcmd_received"] += 1
            if self._first_command is None:
                self._first_command = time.monotonic()
            if self.faults.corrupt_command and self._rng.random() < self.faults.corrupt_command:
                damaged = bytearray(data)
                damaged[4 + int(src[self._rng.randrange(len(src))])] ^= 0xFF
                data = bytes(damaged)
            try:
                valid = self._cmd.decode(data)
            except ValueError:
                self.stats["lowcmd_malformed"] += 1
                continue
            if not valid:
                self.stats["lowcmd_bad_crc"] += 1
                continue
            if self.service.mode:  # the robot's own controller has the motors
                self.stats["lowcmd_ignored"] += 1
                continue
            motor_cmd = self._cmd.message["motor_cmd"]
            if self.drivers.hold_torque:  # the bridge's PD, from the state at arrival
                self.drivers.take(
                    motor_cmd, self.plant.true_position()[0], self.plant.true_velocity()[0]
                )
            else:
                self.drivers.take(motor_cmd)
            self._pending.append(stamp)
            kp, kd = motor_cmd["kp"][self.slots], motor_cmd["kd"][self.slots]
            now = time.monotonic()
            self.commands.append((now, motor_cmd["q"][self.slots].copy(), kp, kd))
            damping = bool((kp == 0).all() and (kd > 0).all())
            if damping and not self._damping:
                self.damping_onsets.append((now, now - self._last_published))
            self._damping = damping

    def _update_faults(self, t: float) -> None:
        for slot, at in self.faults.silent.items():
            j = self.joint_of[slot]
            if self._first_command is not None and t >= at and not self.drivers.silent[j]:
                self.drivers.silent[j] = True

    def _heat(self, t: float) -> None:
        """The ``heat`` faults: extra winding loss (W) over a step into the thermal model (its
        winding heat capacity) while the driver is on."""
        thermal, on = self.plant.thermal, self.drivers.on
        for slot, (watts, at) in self.faults.heat.items():
            j = self.joint_of[slot]
            if self._first_command is not None and t >= at and on[j]:
                thermal.winding_temperature[0, j] += watts * self.period / thermal.c_w[j]

    def _publish(self, t: float) -> None:
        f, now = self.faults, time.monotonic()
        while self._delayed and self._delayed[0][0] <= now:
            self._write(self._delayed.popleft()[1])
        started = self._first_command is not None
        if started and (f.in_burst(t) or (f.lose and self._rng.random() < f.lose)):
            self.stats["lowstate_lost"] += 1
            return
        self.builder.fill(self.plant, self.drivers)
        if self.remote is not None:
            remote = self.remote.at(t)
            self.builder.message["wireless_remote"][:] = np.frombuffer(remote, np.uint8)
            if self._steps % CONTROLLER_EVERY == 0:
                self._controller.write(controller_message(remote))
        corrupt = bool(f.corrupt_state) and self._rng.random() < f.corrupt_state
        self.stats["lowstate_corrupted"] += corrupt
        sample = self.builder.encode(corrupt=corrupt)
        delay = f.delay(t) if started else 0.0
        if delay > 0 or self._delayed:
            self._delayed.append((now + delay, sample))
            self.stats["lowstate_delayed"] += 1
            return
        self._write(sample)

    def _write(self, sample: bytes) -> None:
        self._states.write_raw(sample)
        self._last_published = time.monotonic()
        self.stats["lowstate_published"] += 1
        if self._pending:
            now = time.time_ns()
            for stamp in self._pending:
                self.command_to_state.add(0, max(0, now - stamp))
            self._pending.clear()

    # ------------------------------------------------------------------ report
    def counters(self) -> dict:
        """The emulator's figures: its counters, the LowState rate achieved (Hz), the
        command-to-state latency (us percentiles), the drivers cut off (motor slots), each switch
        to damping's delay after the last LowState published (s), the base's true path length
        (m)."""
        wall = time.monotonic() - self._started
        return {
            **dict(self.stats),
            "lowstate_rate_hz": self.stats["lowstate_published"] / wall if wall > 0 else 0.0,
            "command_to_state_us": self.command_to_state.summary(),
            "cutoff_slots": [slot for _, slot in self.cutoff_log],
            "damping_onsets_after_last_state_s": [round(d, 4) for _, d in self.damping_onsets],
            "true_distance_m": self.true_distance,
        }

    def save_trace(self, path) -> None:
        """Write :attr:`trace` (``trace``, (rows, 6)) and the damping onsets' monotonic times
        (``damping_onsets``) to the ``.npz`` file ``path``."""
        np.savez(
            path,
            trace=np.array(self.trace, dtype=np.float64).reshape(-1, 6),
            damping_onsets=np.array([t for t, _ in self.damping_onsets], dtype=np.float64),
        )


def _planar(t: float, base: np.ndarray) -> tuple[float, ...]:
    """(t, x, y, yaw, vx, vy) of a true base state (MuJoCo's free joint: position, quaternion
    w x y z, world linear velocity): the velocity rotated into the heading frame."""
    w, x, y, z = base[3:7]
    yaw = float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
    c, s = np.cos(yaw), np.sin(yaw)
    vx, vy = base[7], base[8]
    return (t, float(base[0]), float(base[1]), yaw, float(c * vx + s * vy), float(c * vy - s * vx))
