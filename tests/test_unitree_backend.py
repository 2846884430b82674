"""``deploy-run --backend unitree`` over real DDS (Cyclone DDS on the loopback) against the
Unitree emulator (:class:`sim2real.deploy.backends.unitree.emulator.UnitreeEmulator`, the MuJoCo plant
behind the robot's own topics): the bring-up, the bytes on the wire, a walk with LowState lost,
and the faults: LowState stopped, bad CRCs, a hot motor. Each test has its own DDS domain.

The emulator serves from a thread of this process; deploy-run runs in its own process, as a
robot and its controller do. Runs are a few seconds each; assertions count ticks and messages,
not wall-clock time.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="pip install '.[unitree]'")

from sim2real.deploy.backends.unitree import unitree_go  # noqa: E402
from sim2real.deploy.backends.unitree.backend import UnitreeBackend  # noqa: E402
from sim2real.deploy.backends.unitree.bringup import BLEND_TIME, BringupError  # noqa: E402
from sim2real.deploy.backends.unitree.dds import DdsLink  # noqa: E402
from sim2real.deploy.backends.unitree.emulator import EmulatorFaults, UnitreeEmulator  # noqa: E402
from sim2real.deploy.backends.unitree.emulator.robot import TRACE_EVERY  # noqa: E402
from sim2real.deploy.backends.unitree.emulator.truth import walk_truth  # noqa: E402
from sim2real.deploy.cli.run_verdict import EXIT_BAD_INPUT, EXIT_CLEAN, EXIT_FAULT  # noqa: E402
from tests.runtime_fixtures import zero_action_onnx  # noqa: E402
from tests.unitree_reference import (  # noqa: E402
    crc_bitwise,
    go_lowcmd_c_struct,
    go_lowcmd_object,
    le_words,
)

# On the wall clock against an emulator: in a process of its own beside the suite, whose workers
# run at a lower priority (Makefile), so they do not starve it; it must still hold beside other jobs.
pytestmark = pytest.mark.wallclock

_DOMAINS = itertools.count()
#: s: the go2's gait from standing to its walking speed, left out of the walk's mean speed
GAIT_START_S = 1.0


def _domain() -> int:
    """A DDS domain of this test alone: ids 100-219 split into one block per pytest-xdist worker
    (DDS on the loopback is machine-wide: two tests in one domain would read each other's
    LowState), and within a block by process and test."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw"))
    size = 120 // workers
    return 100 + worker * size + (os.getpid() * 13 + next(_DOMAINS)) % size


@pytest.fixture(scope="module")
def stand_onnx(go2, tmp_path_factory):
    """An ONNX policy of go2's default spec whose action is 0: the home pose, whatever it
    observes."""
    return zero_action_onnx(go2, tmp_path_factory.mktemp("unitree") / "stand.onnx")


def _deploy_run(tmp_path, domain, policy, seconds, *extra):
    report = tmp_path / "run.json"
    argv = [
        "--backend", "unitree", "--network-interface", "lo", "--domain-id", str(domain),
        "--robot", "go2", "--policy", str(policy), "--duration", str(seconds),
        "--report", str(report),
        # these tests judge the link and its faults, not deadline keeping: the emulator's
        # plant shares this machine with deploy-run
        "--overrun-limit", "0.5",
        *extra,
    ]  # fmt: skip
    done = subprocess.run(
        [sys.executable, "-m", "sim2real.deploy.cli.deploy_run", *argv],
        capture_output=True,
        text=True,
        timeout=240,
    )
    out = done.stdout + done.stderr
    return done.returncode, json.loads(report.read_text()) if report.exists() else None, out


def _policy_started(emu, robot) -> int | None:
    """Index in ``emu.commands`` of the runtime's first command: the first whose gains are
    neither damping (kp 0) nor the bring-up's (``[unitree] ramp_kp``, until the hand-over
    blends them into the joints')."""
    ramp = robot.config.unitree.ramp_kp
    for i, (_, _q, k, _kd) in enumerate(list(emu.commands)):
        if (k > 0).all() and (k < ramp - 1e-3).all():
            return i
    return None


def _when_running(emu, robot, action, after: float = 0.5):
    """Call ``action`` (a fault) ``after`` s once the runtime's commands arrive."""

    def watch():
        while _policy_started(emu, robot) is None:
            time.sleep(0.05)
        time.sleep(after)
        action()

    threading.Thread(target=watch, daemon=True).start()


# ------------------------------------------------------------------ bring-up and the wire
def test_bringup_then_lowcmd_on_the_wire_is_byte_identical_to_the_idl(go2):
    domain = _domain()
    with UnitreeEmulator(go2, domain_id=domain) as emu:
        backend = UnitreeBackend(go2, interface="lo", domain_id=domain, log=lambda s: None)
        listen = DdsLink(domain, "lo")
        raw = listen.reader("rt/lowcmd", unitree_go.LowCmd_)
        with backend:
            frame = backend.read()
            while np.isnan(frame.position).any():  # the hold took the last states
                time.sleep(0.005)
                frame = backend.read()
            # the IMU's own attitude (imu_state.quaternion) and the drives' velocities
            # (motor_state.dq) come through, as the estimator takes them
            attitude, velocity = frame.imu_orientation[0].copy(), frame.velocity[0].copy()
            # the bring-up stood the robot up: damping, then the ramp to home at its gains
            assert emu.damping_onsets, "no damping before the ramp"
            assert np.abs(emu.drivers.q_des - go2.home).max() < 1e-6
            target = np.asarray(go2.home) + np.linspace(-0.05, 0.05, go2.n_joints)
            raw.take_raw(64)  # what the hold thread sent
            backend.write(target[None])  # ends the hold: the ramp's gains blend into the joints'
            time.sleep(0.1)
            first = unitree_go.LowCmd_.deserialize(raw.take_raw(64)[-1][0])
            time.sleep(BLEND_TIME)
            backend.write(target[None])
            time.sleep(0.2)
            sent = [s for s, _ in raw.take_raw(64)]
        listen.close()
        bus = backend.bus_summary()
    assert not np.isnan(frame.position).any()
    assert abs(np.linalg.norm(attitude) - 1) < 1e-4 and np.isfinite(velocity).all()
    assert np.degrees(np.arccos(1 - 2 * (attitude[1] ** 2 + attitude[2] ** 2))) < 10  # standing
    assert bus["dropouts"]["bad_crc"] == 0 and bus["lowstate_received"] > 100
    assert emu.stats["lowcmd_bad_crc"] == 0 and emu.stats["lowcmd_received"] > 100
    # the hand-over: the first command still near the ramp's gains, no jump to the policy's
    slot0 = go2.config.unitree.motor_index.index(0)
    assert first.motor_cmd[0].kp > 0.8 * go2.config.unitree.ramp_kp > go2.config.joints[slot0].kp
    ours = sent[-1]
    # built field by field from the IDL: robot.toml's slots, kp and kd, the Go2's header
    motors = [(0, 0.0, 0.0, 0.0, 0.0, 0.0)] * 20
    for j, slot in enumerate(go2.config.unitree.motor_index):
        joint = go2.config.joints[j]
        q = float(np.float32(target[j]))
        motors[slot] = (1, q, 0.0, 0.0, float(np.float32(joint.kp)), float(np.float32(joint.kd)))
    crc = crc_bitwise(le_words(go_lowcmd_c_struct((0xFE, 0xEF), 0xFF, motors, 0, 0, 0)[:-4]))
    assert ours == go_lowcmd_object(motors, crc).serialize()
    # the close left the robot damped (kp 0, kd robot.toml's damping_kd), not stiff
    _, _, kp, kd = emu.commands[-1]
    assert (kp == 0).all() and np.allclose(kd, go2.config.unitree.damping_kd)


def test_bringup_without_lowstate_names_the_interface_and_domain(go2, stand_onnx, capsys):
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    domain = _domain()  # nobody publishes there
    code = deploy_run_main(
        ["--backend", "unitree", "--network-interface", "lo", "--domain-id", str(domain),
         "--robot", "go2", "--policy", str(stand_onnx), "--lowstate-timeout", "1"]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == EXIT_BAD_INPUT
    assert f"no LowState on rt/lowstate within 1 s (interface lo, DDS domain {domain}" in err
    assert "--network-interface" in err and "--domain-id" in err


def test_bringup_refuses_an_active_sport_mode_and_says_how_to_release_it(go2):
    domain = _domain()
    with UnitreeEmulator(go2, domain_id=domain, sport_mode="normal") as emu:
        backend = UnitreeBackend(go2, interface="lo", domain_id=domain, log=lambda s: None)
        with pytest.raises(BringupError, match="high-level motion mode 'normal' active") as err:
            backend.open()
        assert emu.stats["lowcmd_received"] == 0  # refused before commanding anything
    assert "ReleaseMode" in str(err.value)


def test_bringup_stops_damped_when_the_robot_rejects_every_command_crc(go2):
    """A lying robot whose board rejects every LowCmd (its CRC fails: a wrong layout or
    firmware): the ramp is not followed, the bring-up says so and leaves the commands damping."""
    domain = _domain()
    faults = EmulatorFaults(corrupt_command=1.0)
    with UnitreeEmulator(go2, domain_id=domain, faults=faults, start="lying") as emu:
        backend = UnitreeBackend(go2, interface="lo", domain_id=domain, log=lambda s: None)
        with pytest.raises(BringupError, match="did not follow the ramp.*CRC the robot rejects"):
            backend.open()
        assert emu.stats["lowcmd_bad_crc"] == emu.stats["lowcmd_received"] > 0
        assert not emu.commands  # not one command taken
    assert backend.sent > 0 and backend._damping  # its last commands were damping


def test_unitree_hg_echoes_mode_machine_in_every_command(go2):
    """The unitree_hg family (G1, H1-2) on the Go2's description: the robot's mode_machine is
    read from LowState and carried by every LowCmd; CRCs hold both ways."""
    domain = _domain()
    with UnitreeEmulator(go2, family="unitree_hg", domain_id=domain, mode_machine=5) as emu:
        backend = UnitreeBackend(
            go2, interface="lo", domain_id=domain, family="unitree_hg", log=lambda s: None
        )
        with backend:
            backend.write(np.asarray(go2.home)[None])
            time.sleep(0.1)
            echoed = int(emu._cmd.message["mode_machine"])
        bus = backend.bus_summary()
    assert backend.mode_machine == 5 and echoed == 5 and bus["mode_machine"] == 5
    assert emu.stats["lowcmd_bad_crc"] == 0 and bus["dropouts"]["bad_crc"] == 0
    assert emu.stats["lowcmd_received"] > 100 and bus["family"] == "unitree_hg"


# ------------------------------------------------------------------ deploy-run and faults
def test_walks_with_one_percent_of_lowstate_lost_and_no_wrong_command(tmp_path, go2, go2_onnx):
    domain = _domain()
    with UnitreeEmulator(go2, domain_id=domain, faults=EmulatorFaults(lose=0.01)) as emu:
        code, report, out = _deploy_run(tmp_path, domain, go2_onnx, 5.0, "--command", "0.5,0,0")
        lost = emu.stats["lowstate_lost"]
        first = _policy_started(emu, go2)
        commands = list(emu.commands)
        trace, end = np.array(emu.trace), emu.damping_onsets[-1][0]
    assert code == EXIT_CLEAN, out
    assert report["final_state"] == ["RUNNING"] and report["locomotion"]["falls"] == 0, out
    bus = report["bus"]
    assert lost > 0 and bus["dropouts"]["lost"] > 0, bus  # counted, as the servo bus's dropouts
    assert bus["dropout_fraction"] >= 0.005, bus
    # no wrong command: from the runtime's first on, finite targets within the joint limits at
    # the gains of the hand-over's blend, then the joints' (no damping before the close)
    kp = np.array([j.kp for j in go2.config.joints])
    ramp = go2.config.unitree.ramp_kp
    close = next(i for i in range(first, len(commands)) if (commands[i][2] == 0).all())
    for _, q, k, _kd in commands[first:close]:  # up to the close's damping
        assert np.isfinite(q).all() and (k >= kp - 1e-4).all() and (k <= ramp).all()
        assert (q >= go2.position_lower).all() and (q <= go2.position_upper).all()
    assert np.allclose(commands[close - 1][2], kp)  # the joints' gains, once blended
    # still walking, as the emulator's plant saw it, once the gait has started from the stance
    # (the first second's acceleration from rest is not the walk; a busy machine's run has fewer
    # running seconds for it to be averaged with)
    steady_s = report["locomotion"]["running_s"] - GAIT_START_S
    truth = walk_truth(trace, end, steady_s, np.array([0.5, 0, 0]))
    assert truth["mean_forward_speed_m_s"] > 0.3, truth


def test_lowstate_stopped_damps_within_the_stale_limit_and_exits_2(tmp_path, go2, stand_onnx):
    domain = _domain()
    faults = EmulatorFaults()
    with UnitreeEmulator(go2, domain_id=domain, faults=faults) as emu:
        _when_running(emu, go2, lambda: faults.bursts.append((emu.elapsed, float("inf"))), 1.0)
        code, report, out = _deploy_run(tmp_path, domain, stand_onnx, 6.0)
        commands = list(emu.commands)
        silent_since = emu._last_published
    assert code == EXIT_FAULT, out
    assert report["faults"]["by_cause"]["stale_sensor"] == 1, out
    assert report["final_state"] in (["FAULTED"], ["SAFE_STOP"])
    # the commands after the last LowState (the 500 Hz stream's re-sent ones among them):
    # damping within the ticks of the stale limit, then damping only, never a stiff pose. The
    # staleness runs from the tick that read the last state (up to a period after it was
    # published) and is seen at the first tick past the limit: two periods beyond the limit's
    # whole periods, and one more allowed (a run damped 81 ms after the last state against 80;
    # a limit of whole periods, go2's 8 at 50 Hz, is seen at the tick after it: 201.9 ms
    # against 200 when this bound took the limit's ceiling)
    after = [(t, (kp == 0).all()) for t, _, kp, _ in commands if t > silent_since]
    ticks = int(np.floor(go2.stale_limit / go2.control_period + 1e-9)) + 3
    assert after and after[-1][1], "not damped at the end"
    first_damping = [damped for _, damped in after].index(True)
    delay = after[first_damping][0] - silent_since
    assert delay <= ticks * go2.control_period, (delay, after[: first_damping + 3])
    assert all(damped for _, damped in after[first_damping:])
    # the report says what went stale: rt/lowstate, every joint and the IMU, past the limit,
    # nothing arrived; and whose fault: the robot's, unless our loop was that late itself
    (stop,) = report["faults"]["stale_stops"]
    _check_stale_stop(stop, go2, domain)
    assert stop["other_side"]["arrived"] == 0 and stop["other_side"]["other_side"] == "robot silent"
    assert stop["other_side"]["newest_sample_age_s"] >= go2.stale_limit
    if stop["our_side"]["late_s"] < 0.5 * stop["without_reading_s"]:
        assert "(robot silent, newest sample " in stop["verdict"], stop["verdict"]
        assert stop["verdict"].endswith(" old; our ticks on time)"), stop["verdict"]
    assert "stale sensor      t " in out and stop["verdict"] in out


def _check_stale_stop(stop: dict, go2, domain: int) -> None:
    """A stale stop's record names rt/lowstate on this domain, every joint and the IMU, each
    without a fresh reading for at least the stale limit, and a verdict that blames this
    computer exactly where our loop's delay was half that time or more."""
    limit = go2.stale_limit
    assert stop["stream"] == "rt/lowstate", stop
    assert stop["reader"] == f"rt/lowstate over DDS (unitree_go, lo, domain {domain})"
    assert set(stop["joints"]) == set(go2.joint_names) and stop["imu_s"] >= limit
    assert all(s >= limit for s in stop["joints"].values())
    assert stop["verdict"].startswith("rt/lowstate: no fresh reading for ")
    ours = stop["our_side"]
    blamed = "this computer, not the robot" in stop["verdict"]
    assert ours["realtime"] and blamed == (ours["late_s"] >= 0.5 * stop["without_reading_s"])


def test_lowstate_all_bad_crc_is_named_as_refused_states(tmp_path, go2, stand_onnx):
    """Every LowState's CRC wrong from 1 s into the policy: the states keep arriving but are
    refused, and the stale stop's record and verdict say so (counted by kind), not silence."""
    domain = _domain()
    faults = EmulatorFaults()
    with UnitreeEmulator(go2, domain_id=domain, faults=faults) as emu:
        _when_running(emu, go2, lambda: setattr(faults, "corrupt_state", 1.0), 1.0)
        code, report, out = _deploy_run(tmp_path, domain, stand_onnx, 6.0)
    assert code == EXIT_FAULT, out
    (stop,) = report["faults"]["stale_stops"]
    _check_stale_stop(stop, go2, domain)
    other = stop["other_side"]
    assert other["arrived"] > 0 and other["refused"]["bad_crc"] == other["arrived"], other
    assert (
        f"{other['arrived']} samples arrived, all refused: bad_crc {other['arrived']}"
        in (stop["verdict"])
    )


@pytest.mark.nightly  # make test stays under 10 minutes
def test_bad_crcs_are_counted_by_the_robot_and_reported_by_the_runtime(tmp_path, go2, stand_onnx):
    domain = _domain()
    faults = EmulatorFaults(corrupt_state=0.05, corrupt_command=0.05)
    with UnitreeEmulator(go2, domain_id=domain, faults=faults) as emu:
        # 6 s: the stand-up (damping, then RAMP_IN) runs on the emulator's plant, which falls
        # behind the wall clock on a busy machine; 3 s ended in RAMP_IN there
        code, report, out = _deploy_run(tmp_path, domain, stand_onnx, 6.0)
        refused = emu.stats["lowcmd_bad_crc"]
        corrupted = emu.stats["lowstate_corrupted"]
    assert code == EXIT_CLEAN and report["final_state"] == ["RUNNING"], out
    assert refused > 0  # the robot dropped the damaged commands and counted them
    bus = report["bus"]
    assert 0 < bus["dropouts"]["bad_crc"] <= corrupted, bus  # never a corrupt state used
    assert "bad_crc" in out


@pytest.mark.nightly  # make test stays under 10 minutes
def test_hot_motor_meets_the_runtime_thermal_stop_before_its_driver_cuts_off(
    tmp_path, go2, stand_onnx
):
    """Motor slot 3 (FL_hip_joint) takes 2 kW of extra winding loss (a shorted turn): the
    runtime's thermal stop (robot.toml's motor maximum) comes first, damping; the loss goes on,
    the driver cuts off at its own limit, reported with its motor slot; no resume."""
    domain = _domain()
    faults = EmulatorFaults()
    with UnitreeEmulator(go2, domain_id=domain, faults=faults) as emu:
        _when_running(emu, go2, lambda: faults.heat.update({3: (2000.0, emu.elapsed)}), 0.5)
        code, report, out = _deploy_run(tmp_path, domain, stand_onnx, 10.0)
        cutoffs = list(emu.cutoff_log)
    assert code == EXIT_FAULT, out
    causes = report["faults"]["by_cause"]
    assert causes["over_temperature"] == 1 and causes["servo_error"] == 0, out
    assert report["final_cause"] == ["over_temperature"]
    assert [slot for _, slot in cutoffs] == [3]
    (error,) = report["faults"]["drive_errors"]
    assert error == "motor 3 (FL_hip_joint): driver error 0x4 (over temperature)", error
    hip = go2.motors[go2.joint_names.index("FL_hip_joint")]
    assert report["peak_winding_temperature_c"]["FL_hip_joint"] > hip.max_winding_temperature


def test_a_bridge_state_without_crc_is_refused_in_one_line_naming_the_flag(go2, stand_onnx):
    """A robot fills its LowState's CRC; Unitree's simulation bridge (the emulator's
    ``unitree_mujoco`` mode) leaves it 0. By default the backend refuses such states and says
    in one line which flag takes a simulator's; a real robot's bad CRC is refused as before."""
    domain = _domain()
    with UnitreeEmulator(go2, domain_id=domain, bridge="unitree_mujoco"):
        backend = UnitreeBackend(
            go2, interface="lo", domain_id=domain, lowstate_timeout=1.0, log=lambda s: None
        )
        with pytest.raises(BringupError) as err:
            backend.open()
    message = str(err.value)
    assert "--lowstate-unchecked" in message and "crc 0" in message and "\n" not in message
    assert backend.dropouts["bad_crc"] == backend.received > 100
    # a robot's corrupted states (a CRC that is not 0) stay refused with the flag given
    with UnitreeEmulator(go2, domain_id=domain, faults=EmulatorFaults(corrupt_state=1.0)):
        backend = UnitreeBackend(
            go2, interface="lo", domain_id=domain, lowstate_timeout=1.0, log=lambda s: None,
            lowstate_unchecked=True,
        )  # fmt: skip
        with pytest.raises(BringupError) as err:
            backend.open()
    assert "--lowstate-unchecked" not in str(err.value) and backend.unchecked == 0


@pytest.mark.nightly  # 14 s end to end: make test stays under 10 minutes
def test_walks_on_a_unitree_mujoco_like_bridge_with_the_command_stream(tmp_path, go2, go2_onnx):
    """The emulator as Unitree's simulation bridge (no CRC, tick or foot force; the PD torque
    computed when a LowCmd arrives and held): with --lowstate-unchecked and the 500 Hz command
    stream the Go2 stands up and walks; its dead foot sensors are found and the contacts come
    from the kinematics, so the summary's distance stays within 15 % of the simulator's truth
    (the foot sensors' zeros made it 7x the truth). The bridge's states were all taken."""
    domain = _domain()
    with UnitreeEmulator(go2, domain_id=domain, bridge="unitree_mujoco") as emu:
        code, report, out = _deploy_run(
            tmp_path, domain, go2_onnx, 8.0, "--command", "0.5,0,0", "--lowstate-unchecked"
        )
        trace = np.array(emu.trace)
        true_path = emu.true_distance
        resent = emu.stats["lowcmd_received"]
        start = _policy_started(emu, go2)
        started_at = emu.commands[start][0] if start is not None else np.inf
        ended_at = emu.commands[-1][0]  # the stream's last command: the run's close
    assert code == EXIT_CLEAN, out
    walk, bus = report["locomotion"], report["bus"]
    assert walk["falls"] == 0 and report["final_state"] == ["RUNNING"], out
    assert bus["lowstate_unchecked"] > 1000 and bus["dropouts"]["bad_crc"] == 0, bus
    assert bus["lowcmd_resent"] > 5 * bus["lowcmd_sent"] / 10 and resent > 2000, bus
    forward = trace[-1, 1] - trace[0, 1]
    # walking, judged on the plant's own time since the policy started: on a machine too busy
    # for the emulator's physics to keep up with the clock it simulates less of the walk
    walking = (trace[:, 0] >= started_at) & (trace[:, 0] <= ended_at)
    walked_s = walking.sum() * TRACE_EVERY * go2.physics_timestep
    assert walked_s > 1.0 and forward > 0.25 * walked_s, (forward, walked_s, trace[-1])
    assert abs(walk["distance_m"] / true_path - 1) < 0.15, (walk["distance_m"], true_path)
    # straight: the heading hold (default for a command without a yaw rate) keeps the policy's
    # own turn (about -4 deg/s, -20 deg over this walk without it) out of the path
    assert walk["heading_hold_gain"] > 0
    yaw = np.unwrap(trace[walking, 3])
    assert abs(np.degrees(yaw[-1] - yaw[0])) < 12.0, np.degrees(yaw[-1] - yaw[0])
    step = trace[walking][-1, 1:3] - trace[walking][0, 1:3]
    c, s = np.cos(yaw[0]), np.sin(yaw[0])
    along, across = c * step[0] + s * step[1], -s * step[0] + c * step[1]
    assert abs(across) < 0.2 * along, (along, across)
