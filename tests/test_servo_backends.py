"""The servo-bus backends through the vendors' real SDKs against the wire-protocol emulator.

Feetech (``scservo_sdk``) on sim2real/robots/so101, Dynamixel Protocol 2.0 (``dynamixel_sdk``) on
sim2real/robots/arm3_xm430; the emulator (:class:`sim2real.deploy.backends.emulator.ServoBusEmulator`) answers on a
pty with the MuJoCo plant behind its registers. No SDK is mocked. Runs are a few seconds of wall
clock each.
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from sim2real.deploy.backends.emulator import ServoBusEmulator, WireFaults
from sim2real.deploy.backends.servo.calibration import CalibrationError, load_lerobot_calibration
from sim2real.deploy.backends.servo.servo_bus import ServoBusError
from sim2real.deploy.backends.servo.torque_watch import TORQUE_CHECK_PERIOD, TORQUE_OFF
from sim2real.deploy.cli.run_verdict import EXIT_CLEAN, EXIT_FAULT
from sim2real.deploy.core.backend import Backend, SimulatedPlant
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Runtime, WallClock
from sim2real.robots import load_robot
from tests.runtime_fixtures import adversarial_onnx

pytest.importorskip("scservo_sdk", reason="pip install '.[servo]'")
pytest.importorskip("dynamixel_sdk", reason="pip install '.[servo]'")

from sim2real.deploy.backends.servo.dynamixel import DynamixelBackend  # noqa: E402
from sim2real.deploy.backends.servo.feetech import FeetechBackend  # noqa: E402

# On the wall clock against an emulator on a pty, beside the suite, whose session make test nices
# as a scheduling group (tests/nice_session.py): a pty's bytes cross on a kernel worker, which
# waited behind a suite niced only process by process (nice 19 or SCHED_IDLE: replies later than
# the stale limit, 5-7 of these 19 tests failed).
pytestmark = [pytest.mark.wallclock, pytest.mark.alone]

CASES = {
    "feetech": ("so101", FeetechBackend),
    "dynamixel": ("arm3_xm430", DynamixelBackend),
}


@pytest.fixture(autouse=True)
def _short_gil_slices():
    """The emulator serves from a thread of this process: shorter GIL slices keep the SDK's
    busy receive loop from starving it (a real bus has no such coupling)."""
    old = sys.getswitchinterval()
    sys.setswitchinterval(2e-4)
    yield
    sys.setswitchinterval(old)


def _policy(tmp_path, robot):
    # the adversarial policy: uniform random actions, 2 % NaN (sim2real.deploy.policy.adversarial)
    return adversarial_onnx(tmp_path, robot, robot.control_mode)


def _deploy_run(tmp_path, protocol, emu, seconds, *extra):
    name, _ = CASES[protocol]
    robot = load_robot(name)
    report = tmp_path / f"{protocol}.json"
    argv = [
        "--backend",
        protocol,
        "--port",
        emu.port,
        "--robot",
        name,
        "--policy",
        str(_policy(tmp_path, robot)),
        "--duration",
        str(seconds),
        "--report",
        str(report),
        # these tests judge the bus and its faults, not deadline keeping (tests/test_runtime.py
        # does): a test machine running the emulator's plant next to deploy-run overruns
        "--overrun-limit",
        "0.5",
        *extra,
    ]
    # deploy-run in its own process: the emulator's thread and the SDK's busy receive loop
    # would otherwise share one GIL (a timing coupling a real bus does not have)
    done = subprocess.run(
        [sys.executable, "-m", "sim2real.deploy.cli.deploy_run", *argv],
        capture_output=True,
        text=True,
        timeout=120,
    )
    return done.returncode, json.loads(report.read_text()), done.stdout + done.stderr


def _full_read(backend, tries=10):
    """A frame with every joint (a reply may come late while the emulator steps its plant)."""
    for _ in range(tries):
        frame = backend.read()
        if not np.isnan(frame.position).any():
            return frame
    raise AssertionError(f"no full frame in {tries} reads: {backend.bus_summary()}")


# ---------------------------------------------------------------- contract and open()
def test_backends_keep_the_contract_and_only_the_sim_is_a_plant(so101):
    from sim2real.deploy.backends.sim.plant import SimBackend

    sim = SimBackend(so101)
    bus = FeetechBackend(so101, "/dev/null")
    assert isinstance(sim, Backend) and isinstance(bus, Backend)
    assert isinstance(sim, SimulatedPlant) and not isinstance(bus, SimulatedPlant)
    assert (bus.envs, bus.mode, bus.block_start, bus.block_length) == (1, "position", 56, 8)


def test_open_configures_each_servo_before_torque_and_close_turns_it_off(so101):
    with ServoBusEmulator(so101, "feetech") as emu:
        for s in emu.servos:  # what the catalog's [protection] must restore
            s.set("temperature_limit", 40)
            s.set("Overload_Torque", 99)
        backend = FeetechBackend(so101, emu.port)
        with backend:
            for s in emu.servos:
                assert s.get("torque_enable") == 1
                assert s.get("return_delay") == 0
                assert s.get("operating_mode") == 0  # position
                assert s.get("temperature_limit") == 70  # sim2real/robots/motors/sts3215.toml
                assert s.get("Overload_Torque") == 80
                # torque came on with the goal at the pose: nothing jumps
                assert abs(s.get("goal_position") - s.get("present_position")) <= 3
            frame = _full_read(backend)
            # sag: torque is off while open() configures the servos (longer on a loaded machine)
            np.testing.assert_allclose(frame.position[0], so101.home, atol=0.06)
            assert (frame.winding_temperature[0] == 25.0).all()
            assert np.allclose(backend.voltage, 12.0)
        assert all(s.get("torque_enable") == 0 for s in emu.servos)


@pytest.mark.parametrize("protocol", list(CASES))
def test_a_backend_opened_the_moment_the_emulator_prints_its_port_configures_every_servo(protocol):
    """The bench and a user's script open the port as soon as ``python -m
    sim2real.deploy.backends.emulator`` prints it. The emulator's set-up collection used to fall
    after the print: the first PING timed out, its late reply broke the next packet, and the
    Feetech SDK raised IndexError out of ``open()``."""
    from sim2real.deploy.harness.servo_hil import start_emulator, stop_emulator

    name, cls = CASES[protocol]
    robot = load_robot(name)
    proc, port = start_emulator(name, protocol)
    try:
        assert port is not None
        with cls(robot, port) as backend:
            frame = _full_read(backend)
            np.testing.assert_allclose(frame.position[0], robot.home, atol=0.06)
    finally:
        stop_emulator(proc)


def test_open_refuses_a_wrong_model_naming_the_id_and_the_expected_model(so101):
    with ServoBusEmulator(so101, "feetech") as emu:
        emu.servos[2].set("Model_Number", 1020)
        with pytest.raises(ServoBusError, match=r"servo ID 3 \(elbow_flex\).*1020.*expected 777"):
            FeetechBackend(so101, emu.port).open()
        emu.unplug(5)
        time.sleep(0.05)
        emu.servos[2].set("Model_Number", 777)
        with pytest.raises(ServoBusError, match=r"servo ID 5 \(wrist_roll\) did not answer"):
            FeetechBackend(so101, emu.port).open()


def test_lerobot_calibration_round_trip(tmp_path, so101):
    cal = {
        name: {
            "id": j + 1,
            "drive_mode": int(name == "elbow_flex"),
            "homing_offset": [-1207, 310, 0, -45, 512, 77][j],
            "range_min": 800,
            "range_max": 3200 + 20 * j,
        }
        for j, name in enumerate(so101.joint_names)
    }
    path = tmp_path / "so101_follower.json"
    path.write_text(json.dumps(cal))
    with ServoBusEmulator(so101, "feetech") as emu:
        with FeetechBackend(so101, emu.port, calibration=path) as backend:
            for j, s in enumerate(emu.servos):  # the offsets went to the servos' registers
                assert s.get("Homing_Offset") == cal[so101.joint_names[j]]["homing_offset"]
                assert s.get("min_position") == 800
            goal = np.array([[0.2, -0.3, 0.4, 0.1, -0.2, 0.3]])
            for _ in range(60):
                backend.write(goal)
                backend.read()
                time.sleep(so101.control_period)
            measured = _full_read(backend).position[0].copy()
            true = emu.plant.true_position()[0]
        # joint angle <- ticks through offset, mid-range zero and direction, both ways
        zero = np.array([(800 + 3200 + 20 * j) / 2 for j in range(6)])
        direction = np.array([1, 1, -1, 1, 1, 1])
        offsets = np.array([cal[n]["homing_offset"] for n in so101.joint_names])
        expected_ticks = np.round(zero + direction * goal[0] * 4096 / (2 * np.pi))
        actual_goal = (expected_ticks + offsets - 2048) * 2 * np.pi / 4096  # plant frame
        np.testing.assert_allclose(true, actual_goal, atol=0.03)
        np.testing.assert_allclose(measured, goal[0], atol=0.03)
    cal["gripper"]["range_max"] = 5000
    path.write_text(json.dumps(cal))
    with pytest.raises(CalibrationError, match="'gripper' range"):
        load_lerobot_calibration(path, so101.joint_names, [4096] * 6)


# ---------------------------------------------------------------- deploy-run on the bus
@contextlib.contextmanager
def _emulator(robot, protocol, **kwargs):
    """The emulator; arm3_xm430 lies flat on a table (no gravity on its joints): its XM430
    shoulder cannot hold arm3's links up (sim2real/robots/arm3_xm430/robot.toml), and the Dynamixel tests
    are about the bus, not a sagging arm."""
    with ServoBusEmulator(robot, protocol, **kwargs) as emu:
        saved = [m.opt.gravity.copy() for m in emu.plant.models]
        if robot.name == "arm3_xm430":
            for m in emu.plant.models:
                m.opt.gravity[:] = 0.0
        try:
            yield emu
        finally:
            for m, g in zip(emu.plant.models, saved, strict=True):
                m.opt.gravity[:] = g


def _when_running(emu, action, packets=200):
    """Call ``action`` (a fault) once the host has sent ``packets`` packets: deploy-run is up
    and has been running for about a second, whatever its start-up took."""

    def watch():
        while emu.stats["packets"] < packets:
            time.sleep(0.01)
        action()

    threading.Thread(target=watch, daemon=True).start()


def test_deploy_run_feetech_adversarial_policy_runs_clean(tmp_path):
    with ServoBusEmulator(load_robot("so101"), "feetech") as emu:
        code, report, out = _deploy_run(tmp_path, "feetech", emu, 3.0)
        assert all(s.get("torque_enable") == 0 for s in emu.servos)  # closed: torque off
    assert code == EXIT_CLEAN, out
    assert report["faults"]["by_cause"]["hard_limit"] == 0
    assert report["violations"] is None and report["realtime"]
    assert report["bus"]["sync_reads"] >= 250 and "bus               feetech" in out
    assert report["final_state"] == ["RUNNING"]


@pytest.mark.nightly  # 13-16 s (the slump, then deploy-run): the plant-level test of this is
# tests/test_envelope.py's, 2 s, in make test
def test_deploy_run_feetech_ramps_in_an_arm_slumped_below_its_workspace_box(tmp_path):
    """Torque off, the SO-101 slumps in the emulator (as it does while deploy-run starts on a
    busy machine) until its end effector is 5 cm below its workspace box's floor: deploy-run
    ramps it home and runs (before, the motion envelope braked every step of the ramp that went
    a little deeper on its way back: RAMP_IN to the end, a workspace intervention every tick)."""
    from sim2real.deploy.safety.guard import SafetyGuard

    so101 = load_robot("so101")
    envelope = SafetyGuard(so101, 1, "position").envelope
    with ServoBusEmulator(so101, "feetech") as emu:
        deadline = time.monotonic() + 30.0
        while envelope.workspace_margin(emu.plant.true_position()[0]).min() > -0.05:
            assert time.monotonic() < deadline, "the arm did not slump within 30 s"
            time.sleep(0.05)
        code, report, out = _deploy_run(tmp_path, "feetech", emu, 3.0)
    assert code == EXIT_CLEAN, out
    assert report["final_state"] == ["RUNNING"], out


class _Recorder:
    """A backend wrapper keeping every command and the emulated plant's joint angles then."""

    def __init__(self, backend, emu):
        self.backend, self.emu, self.commands, self.true = backend, emu, [], []

    def __getattr__(self, name):
        return getattr(self.backend, name)

    def write(self, command):
        self.commands.append(np.array(command))
        self.true.append(self.emu.plant.true_position().copy())
        self.backend.write(command)


@pytest.mark.parametrize("protocol", ["feetech", "dynamixel"])
def test_corrupt_replies_are_dropouts_and_never_commands(tmp_path, protocol):
    name, cls = CASES[protocol]
    robot = load_robot(name)
    with _emulator(robot, protocol, faults=WireFaults(corrupt=0.01)) as emu:
        with cls(robot, emu.port) as bus:
            backend = _Recorder(bus, emu)
            policy = OnnxPolicy(_policy(tmp_path, robot), robot)
            rt = Runtime(robot, policy, backend, clock=WallClock(robot.control_period))
            rt.start()
            rt.run(int(3.0 / robot.control_period))
            assert bus.dropouts["corrupt"] > 0, bus.bus_summary()
            assert emu.stats["corrupted"] >= bus.dropouts["corrupt"]
    commands = np.concatenate(backend.commands)
    assert np.isfinite(commands).all()
    assert rt.counters.faults["servo_error"][0] == 0 and rt.counters.faults["hard_limit"][0] == 0
    if robot.control_mode == "position":  # no command far from where the arm is
        assert np.abs(commands - np.concatenate(backend.true)).max() < 0.6
        assert (commands >= robot.soft_lower - 1e-9).all()
        assert (commands <= robot.soft_upper + 1e-9).all()
    else:
        assert (np.abs(commands) <= robot.velocity_limit + 1e-9).all()


@pytest.mark.parametrize("protocol", ["feetech", "dynamixel"])
def test_unplugged_servo_stops_safely_torque_off_exit_2(tmp_path, protocol):
    name, _ = CASES[protocol]
    robot = load_robot(name)
    with _emulator(robot, protocol) as emu:
        _when_running(emu, lambda: emu.unplug(2))
        code, report, out = _deploy_run(tmp_path, protocol, emu, 3.0)
        torque = [s.get("torque_enable") for s in emu.servos]
    assert code == EXIT_FAULT, out
    assert report["faults"]["by_cause"]["stale_sensor"] == 1, out
    assert report["bus"]["dropouts"]["timeout"] > 0
    assert torque == [0] * robot.n_joints
    # the safe stop came within the stale limit of the last reading: latched, run ended early
    assert report["final_state"] in (["FAULTED"], ["SAFE_STOP"])
    assert report["duration_s"] < 3.0 or report["final_state"] == ["SAFE_STOP"]
    # the report says what went stale: servo ID 2's joint on the SYNC READ, past the limit,
    # that servo named silent (reads without a reply)
    (stop,) = report["faults"]["stale_stops"]
    joint, limit = robot.joint_names[1], robot.stale_limit
    assert stop["stream"] == "SYNC READ" and f"{protocol} bus " in stop["reader"], stop
    assert joint in stop["joints"] and stop["joints"][joint] >= limit
    assert stop["other_side"]["joints"][joint].startswith("servo ID 2: "), stop["other_side"]
    assert stop["verdict"].startswith("SYNC READ: no fresh reading for ")
    assert "servo ID" in stop["verdict"] and " silent" in stop["verdict"], stop["verdict"]


def _deploy_run_with_fault(tmp_path, protocol, robot, seconds, fault, *args):
    """``_deploy_run`` against an emulator whose ``fault(*args)`` is set once the runtime is
    RUNNING. One more try when the run stopped before the fault was even set (stale replies in
    its first ticks: the in-process emulator starved of CPU on a busy machine, which is not what
    these tests judge; a real servo answers in microseconds)."""
    for _ in range(2):
        with _emulator(robot, protocol) as emu:
            injected = threading.Event()
            set_fault = getattr(emu, fault)
            _when_running(emu, lambda f=set_fault, done=injected: (f(*args), done.set()))
            code, report, out = _deploy_run(tmp_path, protocol, emu, seconds)
        if injected.is_set():
            break
    assert injected.is_set(), out
    return code, report, out


@pytest.mark.parametrize("protocol", ["feetech", "dynamixel"])
def test_overload_error_bit_stops_safely_naming_the_servo(tmp_path, protocol):
    robot = load_robot(CASES[protocol][0])
    code, report, out = _deploy_run_with_fault(tmp_path, protocol, robot, 3.0, "set_overload", 3)
    assert code == EXIT_FAULT, out
    assert report["faults"]["by_cause"]["servo_error"] == 1, out
    (error,) = report["faults"]["drive_errors"]
    assert error.startswith("servo ID 3") and "overload" in error and "0x20" in error
    assert "servo error       servo ID 3" in out


@pytest.mark.parametrize("protocol", ["feetech", "dynamixel"])
def test_overheating_servo_meets_the_runtime_thermal_stop_first(tmp_path, protocol):
    """A servo takes 200 W of extra winding loss (a binding gearbox): the runtime's own thermal
    stop (max_winding_temperature, 5 K below the servo's cut-off in the catalog) fires first; the
    loss goes on while the arm is held, so the servo's protection trips after it, and that is
    reported with the servo's ID and no resume follows (its torque is off)."""
    robot = load_robot(CASES[protocol][0])
    servo_limit = robot.motors[2].protection.temperature_limit
    # ~3 s to the servo's limit
    code, report, out = _deploy_run_with_fault(tmp_path, protocol, robot, 8.0, "set_heat", 3, 200.0)
    assert code == EXIT_FAULT, out
    assert report["faults"]["by_cause"]["over_temperature"] == 1, out
    assert report["faults"]["by_cause"]["servo_error"] == 0, out  # the runtime's stop came first
    # no resume: stopping (SAFE_STOP until at rest) or latched (FAULTED), never RUNNING again
    assert report["final_cause"] == ["over_temperature"]
    assert report["final_state"] in (["SAFE_STOP"], ["FAULTED"])
    peak = report["peak_winding_temperature_c"][robot.joint_names[2]]
    assert robot.motors[2].max_winding_temperature < peak
    (error,) = report["faults"]["drive_errors"]  # the servo tripped at its own limit after it
    assert error.startswith("servo ID 3") and "overheat" in error, error
    assert peak >= servo_limit - 1


@pytest.mark.parametrize("protocol", ["feetech", "dynamixel"])
def test_a_servo_that_cut_its_torque_unseen_is_a_drive_error_naming_it(protocol):
    """A servo that switched its torque off leaving no error bit to read (a Feetech servo clears
    its overheat bit once the winding cools below its limit) is found by reading Torque_Enable
    back: a drive error of that servo within a check period; none while the host itself has the
    torque off."""
    name, cls = CASES[protocol]
    robot = load_robot(name)
    reads = 4 * int(np.ceil(TORQUE_CHECK_PERIOD / robot.control_period))  # room for a lost reply
    with _emulator(robot, protocol) as emu, cls(robot, emu.port) as bus:
        _full_read(bus)
        emu.cut_torque(2)
        for _ in range(reads):
            bus.read()
            if bus.drive_errors().any():
                break
        errors = bus.drive_errors()[0].tolist()
        assert errors == [0, TORQUE_OFF] + [0] * (robot.n_joints - 2), bus.bus_summary()
        assert bus.latched_errors == {2: TORQUE_OFF}
        text = bus.describe_drive_error(1, TORQUE_OFF)
        assert text.startswith(f"servo ID 2 ({robot.joint_names[1]}): torque off"), text
        assert "overheat" not in text  # it was never read near its cut-off
        checks = bus.torque_checks
        bus.disable()  # the host's own torque off is no error, and nothing to check
        for _ in range(reads):
            bus.read()
            assert not bus.drive_errors().any()
        assert bus.torque_checks == checks >= 1


@pytest.mark.parametrize("protocol", ["feetech", "dynamixel"])
def test_a_servo_shut_down_unseen_in_a_thermal_stop_latches_it_and_never_resumes(
    tmp_path, protocol
):
    """The race a host can lose: a Feetech servo cuts its torque at its temperature limit and
    clears its overheat bit as soon as the winding has cooled below it, moments later; a host
    that read no status packet in between never sees the bit. Made deterministic here: servo 3
    heats (its own cut-off raised out of reach) until the runtime's thermal stop holds the arm,
    then switches its torque off leaving no bit to read. Once cooled, the runtime must not
    resume with that joint limp: the stop latches (FAULTED), naming servo 3."""
    name, _ = CASES[protocol]
    robot = load_robot(name)
    motor = robot.motors[2]
    cut_at = motor.max_winding_temperature + 2.0  # past the runtime's stop, below the servo's

    def heat_then_cut():
        emu.set_temperature_limit(3, 200)  # no shutdown of its own: the cut below is the only one
        emu.set_heat(3, 100.0)
        while emu.plant.thermal.winding_temperature[0, 2] < cut_at:
            time.sleep(0.002)
        emu.cut_torque(3)

    with _emulator(robot, protocol) as emu:
        _when_running(emu, heat_then_cut)
        code, report, out = _deploy_run(tmp_path, protocol, emu, 15.0)
        torque = [s.get("torque_enable") for s in emu.servos]
    assert code == EXIT_FAULT, out
    assert report["faults"]["by_cause"]["over_temperature"] == 1, out
    assert report["faults"]["safe_stops"] == 1, out  # no second stop after a resume
    assert report["final_cause"] == ["over_temperature"]
    # the stop ended (at rest, cooled below the derating start) and latched instead of resuming
    assert report["final_state"] == ["FAULTED"], out
    assert report["duration_s"] < 15.0
    (error,) = report["faults"]["drive_errors"]
    assert error.startswith("servo ID 3") and "torque off" in error, error
    assert "servo error       servo ID 3" in out
    assert torque == [0] * robot.n_joints
