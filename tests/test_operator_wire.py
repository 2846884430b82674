"""The operator over the wire, on the wall clock: the Unitree emulator's scripted remote (in
LowState's bytes and on rt/wirelesscontroller) read by deploy-run --backend unitree, and a second
ROS 2 process publishing sensor_msgs/Joy and calling the node's ~/resume, which the operator's
authority table refuses."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from sim2real.deploy.backends.unitree.remote import encode_remote

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------- over DDS and ROS 2
def _press(lines: list[str], at: float, buttons: str, hold: float = 0.2, **axes) -> None:
    extra = "".join(f"{k} = {v}\n" for k, v in axes.items())
    lines.append(f"[[step]]\nat = {at}\nbuttons = [{buttons}]\n{extra}")
    lines.append(f"[[step]]\nat = {at + hold}\n{extra}")


@pytest.mark.nightly  # 17 s end to end: make test stays under 10 minutes
@pytest.mark.wallclock
def test_the_unitree_emulator_plays_a_remote_that_walks_stands_and_damps(tmp_path, go2_policies):
    """The emulator's LowState carries a scripted remote; deploy-run --backend unitree reads it
    from rt/lowstate with a reader of its own. Each press is repeated (a press that comes while
    the runtime is still starting is refused or ignored, never acted on twice)."""
    import subprocess
    import sys

    from sim2real.deploy.backends.unitree.emulator.robot import UnitreeEmulator

    lines: list[str] = []
    for at in (6.5, 7.5, 8.5):
        _press(lines, at, '"A"', ly=1.0)
    for at in (10.5, 11.0):
        _press(lines, at, '"start"')
    for at in (12.5, 13.0):
        _press(lines, at, '"select"')
    script = tmp_path / "remote.toml"
    script.write_text("\n".join(lines))
    domain = 220 + os.getpid() % 10
    report = tmp_path / "run.json"
    p = go2_policies
    with UnitreeEmulator("go2", domain_id=domain, remote=str(script)):
        done = subprocess.run(
            [sys.executable, "-m", "sim2real.deploy.cli.deploy_run", "--backend", "unitree",
             "--network-interface", "lo", "--domain-id", str(domain), "--robot", "go2",
             "--policy", f"walk={p['walk']}", "--policy", f"stand={p['stand']}",
             "--operator", "unitree", "--duration", "11", "--overrun-limit", "0.5",
             "--report", str(report)],
            capture_output=True, text=True, timeout=240,
        )  # fmt: skip
    out = done.stdout + done.stderr
    r = json.loads(report.read_text())
    path = [(t["state"], t["to"], t["requester"]) for t in r["operator"]["transitions"]]
    assert path == [
        ("STAND", "STAND", "runtime"), ("STAND", "POLICY", "unitree"),
        ("POLICY", "STAND", "unitree"), ("STAND", "DAMP", "unitree"),
        ("DAMP", "PASSIVE", "runtime"),
    ], out  # fmt: skip
    assert done.returncode == 0, out
    assert r["faults"]["by_cause"]["fall"] == 0 and r["final_cause"] == ["operator"]


@pytest.mark.nightly
@pytest.mark.wallclock
def test_a_second_ros2_process_drives_the_run_through_joy_and_may_not_resume_it(
    tmp_path, go2_policies, monkeypatch
):
    """deploy-run --operator xbox_joy --ros2 in its own process; this process publishes
    sensor_msgs/Joy on /joy (A until the robot walks, the left stick forward, then Y until it
    lies down, damped) and calls the node's ~/resume, which the mapping's authority refuses (only the pad
    may resume). Each step waits for the transition it asked for: no step is timed."""
    pytest.importorskip("rclpy", reason="the extra 'ros2' (ROS 2 Kilted wheels) is not installed")
    import subprocess
    import sys
    import threading
    import time

    from sensor_msgs.msg import Joy
    from std_srvs.srv import Trigger

    from sim2real.deploy.ros2.context import NodeThread

    domain = 100 + (os.getpid() + int(time.time())) % 100
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    report = tmp_path / "run.json"
    p = go2_policies
    run = subprocess.Popen(
        [sys.executable, "-m", "sim2real.deploy.cli.deploy_run", "--robot", "go2",
         "--policy", f"walk={p['walk']}", "--policy", f"stand={p['stand']}",
         "--policy", f"lie={p['lie']}",
         "--operator", "xbox_joy", "--ros2", "--realtime", "--duration", "14",
         "--report", str(report)],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    lines: list[str] = []
    threading.Thread(
        target=lambda: lines.extend(iter(run.stderr.readline, "")), daemon=True
    ).start()
    state = {"buttons": [0] * 11, "axes": [0.0] * 8}

    def seen(text: str) -> bool:
        return any(text in line for line in list(lines))

    with NodeThread("joy_pad") as pad:
        pub = pad.node.create_publisher(Joy, "/joy", 10)
        resume = pad.node.create_client(Trigger, "/deploy_runtime/resume")
        stop = threading.Event()

        def publish():  # joy_node's autorepeat: the state at 20 Hz
            while not stop.wait(0.05):
                msg = Joy()
                msg.buttons, msg.axes = list(state["buttons"]), list(state["axes"])
                pub.publish(msg)

        threading.Thread(target=publish, daemon=True).start()

        def press_until(button: int, text: str, timeout: float = 60.0) -> None:
            end = time.monotonic() + timeout
            while not seen(text) and time.monotonic() < end and run.poll() is None:
                state["buttons"][button] = 1
                time.sleep(0.2)
                state["buttons"][button] = 0
                time.sleep(0.3)
            assert seen(text), "".join(lines)

        press_until(0, "STAND -> POLICY (policy walk; joy")
        state["axes"][1] = 1.0  # forward
        assert resume.wait_for_service(timeout_sec=30)
        future = resume.call_async(Trigger.Request())
        end = time.monotonic() + 10
        while not future.done() and time.monotonic() < end:
            time.sleep(0.02)
        answer = future.result()
        time.sleep(1.0)
        state["axes"][1] = 0.0
        press_until(3, "POLICY -> LIE (lie_down; joy")
        end = time.monotonic() + 30
        while not seen("LIE -> DAMP (lain down") and time.monotonic() < end:
            time.sleep(0.05)
        stop.set()
        run.wait(timeout=60)
    assert not answer.success and "'ros2' lacks the right 'resume'" in answer.message
    r = json.loads(report.read_text())
    assert r["ros2"]["services_refused"] == 1
    refused = r["operator"]["refused"]
    assert any(t["requester"] == "ros2" and "resume" in t["cause"] for t in refused), refused
    assert r["final_cause"] == ["operator"] and run.returncode == 0, "".join(lines)


@pytest.mark.wallclock
def test_the_emulator_publishes_the_scripted_remote_on_rt_wirelesscontroller_too(tmp_path):
    """The scripted remote's state also goes out as unitree_sdk2's WirelessController_ on
    rt/wirelesscontroller; the operator's controller source reads the same buttons and sticks
    as LowState's bytes carry."""
    import time

    from sim2real.deploy.backends.unitree.emulator.robot import UnitreeEmulator
    from sim2real.deploy.backends.unitree.remote import controller_message, decode_controller
    from sim2real.deploy.operator.sources import UnitreeController

    raw = encode_remote(["A", "R1"], lx=-0.5, ly=0.25, rx=1.0)
    assert decode_controller(controller_message(raw)) == (
        {"A", "R1"}, {"lx": -0.5, "ly": 0.25, "rx": 1.0, "ry": 0.0}
    )  # fmt: skip
    script = tmp_path / "remote.toml"
    script.write_text('[[step]]\nat = 0.0\nbuttons = ["A", "R1"]\nly = 0.25\n')
    domain = 230 + os.getpid() % 3
    with UnitreeEmulator("go2", domain_id=domain, remote=str(script)):
        src = UnitreeController(domain, "lo")
        try:
            frame, end = None, time.monotonic() + 30
            while (frame is None or not frame.buttons) and time.monotonic() < end:
                frame = src.poll(time.monotonic())
                time.sleep(0.05)
        finally:
            src.close()
    assert frame.buttons == {"A", "R1"} and frame.axes["ly"] == 0.25
