"""The operator (sim2real.deploy.operator): the Unitree remote's bytes, the mapping file, the
sources without hardware (a recorded evdev stream, the keyboard through a pipe), the state
machine and its authority, and a scripted session through deploy-run on the MuJoCo plant with
three policies (walk, stand, lie) switched by the operator with blended hand-overs (over the
wire, on the wall clock: test_operator_wire.py)."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest

from sim2real.deploy.backends.unitree.remote import (
    BUTTONS,
    REMOTE_BYTES,
    RemoteScript,
    decode_remote,
    encode_remote,
)
from sim2real.deploy.operator.mapping import load_mapping
from sim2real.deploy.operator.sources import EvdevReplay, KeyboardSource
from tests.runtime_fixtures import zero_action_onnx

ROOT = Path(__file__).resolve().parents[1]
SESSION = ROOT / "tests" / "data" / "operator" / "xbox_session.jsonl"


# ---------------------------------------------------------------------- the remote's bytes
def test_the_remote_bytes_follow_unitree_rl_gyms_layout():
    """Buttons are bits of the uint16 at byte 2 (bit 8 A, bit 2 start, bit 3 select), the sticks
    float32 at 4 (lx), 8 (rx), 12 (ry), 20 (ly): built here field by field with struct."""
    raw = bytearray(REMOTE_BYTES)
    struct.pack_into("<H", raw, 2, (1 << 8) | (1 << 2))
    struct.pack_into("<f", raw, 4, -0.25)
    struct.pack_into("<f", raw, 8, 0.5)
    struct.pack_into("<f", raw, 20, 0.75)
    buttons, axes = decode_remote(bytes(raw))
    assert buttons == {"A", "start"}
    assert axes["lx"] == -0.25 and axes["rx"] == 0.5 and axes["ly"] == 0.75 and axes["ry"] == 0
    assert encode_remote(["A", "start"], lx=-0.25, rx=0.5, ly=0.75) == bytes(raw)
    assert BUTTONS[3] == "select" and BUTTONS[15] == "left"
    with pytest.raises(ValueError, match="40 bytes"):
        decode_remote(b"\0" * 39)
    assert decode_remote(np.frombuffer(bytes(raw), dtype=np.uint8))[0] == {"A", "start"}


def test_a_remote_script_holds_each_state_until_the_next(tmp_path):
    p = tmp_path / "remote.toml"
    p.write_text('[[step]]\nat = 1.0\nbuttons = ["start"]\n\n[[step]]\nat = 1.2\nly = 0.5\n')
    script = RemoteScript(p)
    assert decode_remote(script.at(0.5)) == (
        frozenset(),
        {k: 0.0 for k in decode_remote(script.at(0.5))[1]},
    )
    assert decode_remote(script.at(1.1))[0] == {"start"}
    b, a = decode_remote(script.at(5.0))
    assert not b and a["ly"] == 0.5
    from sim2real.deploy.operator.sources import ScriptedRemote

    p.write_text('runtime_starts = 1.0\n[[step]]\nat = 1.0\nbuttons = ["start"]\n')
    played = ScriptedRemote(p)
    assert not played.poll(-0.5).buttons and played.poll(0.1).buttons == {"start"}
    assert played.poll(0.1).stamp == 0.1 and played.source == "unitree"
    p.write_text('[[step]]\nat = 1.0\nbuttons = ["Z"]\n')
    with pytest.raises(ValueError, match="step 1: Unitree remote: unknown button 'Z'"):
        RemoteScript(p)


# ---------------------------------------------------------------------- the mapping file
def test_the_shipped_mappings_load_and_a_bad_one_names_its_field(tmp_path):
    for name in ("unitree", "xbox_evdev", "xbox_joy", "keyboard"):
        m = load_mapping(name)
        assert "damp" in m.actions and m.allowed("start") == [m.source]
    bad = tmp_path / "bad.toml"
    bad.write_text('source = "unitree"\n[actions]\ndamp = "select"\nstand = "BTN_START"\n')
    with pytest.raises(
        ValueError, match=r"bad.toml: actions.stand: 'BTN_START' is not a unitree button"
    ):
        load_mapping(bad)
    bad.write_text('source = "unitree"\n[actions]\nstand = "start"\n')
    with pytest.raises(ValueError, match="'damp' must have a button"):
        load_mapping(bad)
    bad.write_text('source = "joy"\n[actions]\ndamp = "button1"\n[authority]\nstart = ["anyone"]\n')
    with pytest.raises(ValueError, match=r"authority.start.*unknown requester 'anyone'"):
        load_mapping(bad)
    bad.write_text('source = "joy"\n[actions]\ndamp = "button1"\n[deadman]\ntimeout = -1\n')
    with pytest.raises(ValueError, match=r"deadman.timeout: Input should be greater than 0"):
        load_mapping(bad)


# ---------------------------------------------------------------------- sources
def test_a_recorded_evdev_stream_plays_on_the_runs_clock_then_falls_silent():
    src = EvdevReplay(SESSION)
    assert src.poll(0.0) is None  # nothing recorded yet
    f = src.poll(2.05)
    assert "BTN_SOUTH" in f.buttons and f.axes["ABS_Y"] == 0.0 and f.stamp == 2.05
    f = src.poll(3.0)
    assert not f.buttons and f.axes["ABS_Y"] == pytest.approx(-1.0, abs=1e-4)
    last = src.events[-1][0]
    f = src.poll(last + 10.0)
    assert f.stamp == last  # the pad said nothing after its last event: the dead-man's cue


def test_the_keyboard_source_reads_keys_from_its_descriptor():
    r, w = os.pipe()
    try:
        src = KeyboardSource(r)
        f = src.poll(1.0)
        assert not f.presses and f.stamp == 1.0
        os.write(w, b"w \n")
        f = src.poll(2.0)
        assert f.presses == {"w", "space", "enter"} and f.stamp == 2.0
        assert src.poll(3.0).stamp == 2.0
    finally:
        os.close(r)
        os.close(w)


def test_a_remote_script_plays_as_a_gamepad_stream_with_the_same_actions(tmp_path):
    """The shipped session translated for the Xbox pad: each remote button becomes the pad's
    button for the same action, the stick the pad's axis for the same command (evdev: up is
    negative), on the run's clock."""
    from sim2real.deploy.operator.play import translate, write_evdev

    script = RemoteScript(ROOT / "sim2real/deploy/operator/sessions/go2_remote.toml")
    states = translate(script, load_mapping("unitree"), load_mapping("xbox_evdev"))
    t0 = script.runtime_starts
    first_walk = next(s for s in states if "BTN_SOUTH" in s[1])
    assert first_walk[0] == pytest.approx(6.0 - t0)
    assert any("BTN_NORTH" in s[1] for s in states)  # B (lie down) -> Y
    assert any("BTN_EAST" in s[1] for s in states)  # select (damp) -> B
    assert min(s[2]["ABS_Y"] for s in states) == pytest.approx(-1.0)
    src = EvdevReplay(write_evdev(states, tmp_path / "pad.jsonl"))
    assert src.poll(6.6 - t0).axes["ABS_Y"] == pytest.approx(-1.0, abs=1e-4)


# ---------------------------------------------------------------------- the session
def test_a_scripted_gamepad_session_walks_switches_lies_down_and_stands_up(
    tmp_path, go2_policies, capsys
):
    """The recorded Xbox stream on the MuJoCo plant: walk on the stick, hand over to the
    standing policy and back, lie down (the lying policy's ramp, then damped), a walk refused
    while lying, stand up from the floor, walk again; then the pad falls silent and the dead-man
    stands the robot. No true violation, no fall but the operator's own lie-down, and every
    hand-over's command step within the smoother's limit."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    report = tmp_path / "run.json"
    p = go2_policies
    code = deploy_run_main(
        ["--robot", "go2", "--duration", "31",
         "--policy", f"walk={p['walk']}", "--policy", f"stand={p['stand']}",
         "--policy", f"lie={p['lie']}", "--operator", "xbox_evdev",
         "--operator-source", f"evdev:{SESSION}", "--report", str(report),
         "--telemetry", str(tmp_path / "run.mcap")]
    )  # fmt: skip
    r = json.loads(report.read_text())
    op = r["operator"]
    path = [(t["state"], t["to"]) for t in op["transitions"]]
    assert path == [
        ("STAND", "STAND"), ("STAND", "POLICY"), ("POLICY", "STAND"), ("STAND", "POLICY"),
        ("POLICY", "LIE"), ("LIE", "DAMP"), ("DAMP", "PASSIVE"), ("PASSIVE", "STAND"),
        ("STAND", "POLICY"), ("POLICY", "STAND"),
    ], path  # fmt: skip
    assert op["transitions"][-1]["requester"] == "deadman"
    assert [t["refused"] for t in op["refused"]] == ["in LIE: stand first"]
    assert op["switches"] == 6 and op["deadman_events"] == 1
    assert code == 0, capsys.readouterr().err
    assert r["violations"]["any"] == 0 and not r["hard_violations"]
    assert r["locomotion"]["true_falls"] == 0
    assert r["faults"]["by_cause"]["fall"] == 0
    assert 0 < op["handover_max_command_step_share_of_limit"] <= 1.0 + 1e-9
    assert r["locomotion"]["distance_m"] > 3.0
    from mcap.reader import make_reader

    with open(tmp_path / "run.mcap", "rb") as f:
        logged = [
            json.loads(m.data)
            for _, channel, m in make_reader(f).iter_messages()
            if channel.topic == "/operator"
        ]
    assert [(t["state"], t["to"]) for t in logged if t["refused"] is None] == path


def _operated_rig(robot, policies: dict, mapping, source):
    """A rig on the MuJoCo plant with the operator's hook (the first policy in control)."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.operator.hook import OperatorHook
    from sim2real.deploy.operator.machine import OperatorMachine
    from sim2real.deploy.rig.rig import Rig

    backend = SimBackend(robot, mode=next(iter(policies.values())).spec.action.mode, seed=0)
    backend.open()
    rig = Rig(robot, next(iter(policies.values())), backend, envs=1)
    machine = OperatorMachine(rig.runtime, policies, mapping, [source], log=lambda line: None)
    rig.add(OperatorHook(rig, machine))
    rig.start()
    return rig, machine


def test_buttons_act_on_rising_edges_and_a_requester_needs_its_right(tmp_path, go2_policies):
    """A button held when the pad's first frame arrives does nothing; a combination fires once
    when its last button goes down (its buttons do not fire the shorter ones); a source
    without the right ``start`` cannot start a policy, and its refusal is logged."""
    from sim2real.deploy.operator.mapping import Mapping
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.robots import load_robot

    robot = load_robot("go2")
    policies = {n: OnnxPolicy(go2_policies[n], robot) for n in ("walk", "stand")}
    stream = tmp_path / "pad.jsonl"
    events = [(0.0, "BTN_SOUTH", 1), (0.5, "BTN_SOUTH", 0), (1.0, "BTN_TL", 1),
              (1.2, "BTN_SOUTH", 1), (1.6, "BTN_SOUTH", 0), (1.8, "BTN_TL", 0),
              (2.0, "BTN_START", 1), (2.2, "BTN_START", 0), (3.0, "BTN_TL", 1),
              (3.2, "BTN_SOUTH", 1), (3.4, "BTN_SOUTH", 0), (3.6, "BTN_TL", 0)]  # fmt: skip
    stream.write_text(
        "\n".join(
            json.dumps({"t": t, "type": "EV_KEY", "code": c, "value": v}) for t, c, v in events
        )
    )
    base = {
        "source": "evdev",
        "actions": {"damp": "BTN_EAST", "stand": "BTN_START", "next_policy": "BTN_SOUTH"},
        "policies": {"walk": "BTN_TL+BTN_SOUTH"},
    }
    rig, m = _operated_rig(robot, policies, Mapping.model_validate(base), EvdevReplay(stream))
    rig.run(int(4.0 / robot.control_period))
    done = [(t.state, t.to, t.cause) for t in m.log if t.refused is None]
    assert done == [
        ("STAND", "STAND", "runtime started (RAMP_IN to home)"),
        ("STAND", "POLICY", "policy walk"),
        ("POLICY", "STAND", "stand"),
        ("STAND", "POLICY", "policy walk"),
    ], m.log
    assert m.switches == 2 and not [t for t in m.log if t.refused]  # next_policy never fired
    rig.close()
    strict = Mapping.model_validate({**base, "authority": {"start": ["joy"], "reset": ["joy"]}})
    rig, m = _operated_rig(robot, policies, strict, EvdevReplay(stream))
    rig.run(int(1.5 / robot.control_period))
    assert m.state == "STAND" and [t.refused for t in m.log if t.refused] == [
        "'evdev' lacks the right 'start'"
    ]
    # the guard's stop overrides the operator; leaving it needs the right reset, not start
    rig.runtime.supervision.safe_stop(np.ones(1, dtype=bool), "stale_sensor")
    rig.run(int(3.0 / robot.control_period))
    done = [t for t in m.log if t.refused is None]
    assert [t.to for t in done][-2:] == ["DAMP", "PASSIVE"]
    assert done[-2].cause == "runtime safe stop: stale_sensor"
    assert m.request("stand", "evdev") == (False, "'evdev' lacks the right 'reset'")
    assert m.request("stand", "joy") == (True, "standing up (RAMP_IN)")


def test_an_arm_is_damped_and_started_again_from_the_keyboard_without_a_restart(tmp_path):
    """On arm3 (position mode, MuJoCo): space damps (a safe stop, held at rest: PASSIVE),
    enter stands it again (RAMP_IN to home, then RUNNING), in one run."""

    from sim2real.deploy.core.modes import RUNNING
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.robots import load_robot

    robot = load_robot("arm3")
    zero_action_onnx(robot, tmp_path / "still.onnx")
    policy = OnnxPolicy(tmp_path / "still.onnx", robot)
    r, w = os.pipe()
    try:
        rig, m = _operated_rig(
            robot, {"still": policy}, load_mapping("keyboard"), KeyboardSource(r)
        )
        ticks = int(1.0 / robot.control_period)
        rig.run(ticks)
        os.write(w, b" ")
        rig.run(3 * ticks)
        assert m.state == "PASSIVE"
        os.write(w, b"\n")
        rig.run(3 * ticks)
        assert m.state == "STAND" and rig.runtime.mode[0] == RUNNING
        assert [t.to for t in m.log] == ["STAND", "DAMP", "PASSIVE", "STAND"]
    finally:
        os.close(r)
        os.close(w)


def test_a_slow_ramp_in_moves_the_target_along_a_line_to_home_then_lets_go():
    from sim2real.deploy.core.modes import RAMP_IN, RUNNING
    from sim2real.deploy.runtime.handover import RampIn

    start, home = np.array([[0.0, 1.0], [2.0, 2.0]]), np.array([1.0, -1.0])
    ramp = RampIn(start, home, np.array([True, True]), ticks=4)
    target, mode = np.zeros((2, 2)), np.array([RAMP_IN, RUNNING], dtype=np.int8)
    assert not ramp.shape(target, mode)
    assert np.allclose(target[0], [0.25, 0.5]) and np.allclose(target[1], 0.0)  # RUNNING: its own
    for _ in range(2):
        ramp.shape(target, mode)
    assert ramp.shape(target, mode) and np.allclose(target[0], home)


# ---------------------------------------------------------------------- Runtime.switch_policy
def test_switch_policy_blends_the_targets_and_refuses_what_does_not_fit(go2_policies):
    """The hand-over blends for ``ticks`` ticks; after them the receiving policy alone commands
    (the lying policy's constant target); a policy for another robot, or a negative blend, is
    refused and the policy in control stays."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.core.modes import RUNNING
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime
    from sim2real.deploy.spec.policy_spec import PolicySpec
    from sim2real.policies.stand import LIE_POSE
    from sim2real.robots import load_robot

    robot = load_robot("go2")
    walk = OnnxPolicy(go2_policies["walk"], robot)
    lie = OnnxPolicy(go2_policies["lie"], robot)
    with SimBackend(robot, mode="position", seed=0) as backend:
        rt = Runtime(robot, walk, backend)
        rt.start()
        rt.run(40)
        assert rt.mode[0] == RUNNING
        rt.switch_policy(lie, blend_time=0.2)  # 10 ticks
        assert rt.policy is lie and rt.spec is lie.spec and rt.handover.ticks == 10
        rt.run(10)
        assert rt.handover is None and rt.last_handover.done == 10
        rt.run(1)
        assert np.allclose(rt.target[0], LIE_POSE["go2"], atol=1e-5)
        assert 0 < rt.last_handover.max_target_step < 1.0

        class ArmPolicy:  # a contract for another robot
            spec = PolicySpec.for_robot(load_robot("arm3"))

        with pytest.raises(ValueError, match="arm3"):
            rt.switch_policy(ArmPolicy())
        with pytest.raises(ValueError, match="blend_time must be >= 0"):
            rt.switch_policy(walk, -1.0)
        assert rt.policy is lie
