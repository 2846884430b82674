"""Async inference of a chunked policy (sim2real/deploy/policy/lerobot_policy.py,
``inference="async"``; deploy-run ``--inference async``): the network call on a worker thread
(sim2real/deploy/policy/chunk_worker.py) beside the servo loop, with one policy period of
latency: the chunk asked at a policy tick is taken at the next, its first action dropped, the
previous chunk's last action held meanwhile. The cadence, a lockstep run's repeatability, the
state dict with a request pending, a late chunk's safe stop, the worker thread's end on every
exit path, and on the Feetech bus emulator no network call on the servo thread. The policies are
the small chunked ONNX files of tests/lerobot_folder.py (a chunk is ``gain`` x state + a ramp of
``step_deg`` per action)."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from sim2real.deploy.cli.deploy_run import deploy_run_main as deploy_run
from sim2real.deploy.cli.run_verdict import EXIT_BAD_INPUT, EXIT_CLEAN
from sim2real.deploy.core.modes import FAULT_CAUSES
from sim2real.deploy.policy.chunk_worker import THREAD_NAME
from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy
from sim2real.robots import load_robot
from tests.lerobot_folder import write_chunk_onnx


@pytest.fixture(scope="module")
def so101():
    return load_robot("so101")


def _workers() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == THREAD_NAME and t.is_alive()]


def _obs(policy, q):
    b = policy.spec.observation_blocks[0]
    return ((np.asarray(q) - np.asarray(b.offset)) / np.asarray(b.scale)).astype(np.float32)[None]


def _targets(policy, out) -> np.ndarray:
    """The held action back to joint targets, rad."""
    a = policy.spec.action
    return out[0] * np.asarray(a.scale) + np.asarray(a.offset)


def test_async_cadence_drops_the_late_action_and_holds_during_the_request(tmp_path, so101):
    """25 Hz beside 100 Hz, chunk 6, n_action_steps 4: the first policy tick holds the measured
    joints and asks; the next takes the chunk and plays its action 1 (action 0, for the time it
    was asked, dropped); actions 1 to 4, the next chunk asked at action 4's tick and taken one
    policy tick later: a chunk every 4 policy ticks, none computed on the calling thread."""
    path = write_chunk_onnx(tmp_path / "r.onnx", chunk_size=6, n_action_steps=4, fps=25.0)
    policy = LeRobotChunkPolicy(path, so101, inference="async")
    q = np.array([0.1, -0.2, 0.3, 0.2, -0.1, 0.5])
    obs = _obs(policy, q)
    lerobot_q = policy.to_lerobot(q).astype(float)
    targets, new = [], []
    try:
        for _ in range(4 * 10):  # 10 policy ticks of 4 servo ticks
            targets.append(_targets(policy, policy(obs)).copy())
            new.append(bool(policy.new_chunk[0]))
    finally:
        policy.close()
    ticks = np.array(targets)[::4]  # one per policy tick
    np.testing.assert_allclose(ticks[0], q, atol=1e-6)  # held at the measured joints
    for k in range(4):  # servo ticks inside a policy period hold the target
        np.testing.assert_array_equal(targets[4 * 3 + k], targets[4 * 3])
    for tick, i in zip(range(1, 9), [1, 2, 3, 4, 1, 2, 3, 4], strict=True):
        expected = policy.to_joints(0.5 * lerobot_q + 2.0 * i)  # the ramp's action i
        np.testing.assert_allclose(ticks[tick], expected, atol=1e-5)
    assert [k for k, n in enumerate(new) if n] == [4, 20, 36]  # every 4 policy ticks
    assert policy.calls[0] == 3 and policy.servo_thread_calls[0] == 0
    assert policy.policy_ticks[0] == 10


def test_chunk_size_equal_to_n_action_steps_plays_one_less(tmp_path, so101):
    """LeRobot's ACT default (chunk_size = n_action_steps): action 0 dropped, the chunk's other
    n - 1 actions played, a chunk every n - 1 policy ticks."""
    path = write_chunk_onnx(tmp_path / "r.onnx", chunk_size=4, n_action_steps=4, fps=25.0)
    policy = LeRobotChunkPolicy(path, so101, inference="async")
    obs = _obs(policy, np.zeros(6))
    new = []
    try:
        for _ in range(4 * 8):
            policy(obs)
            new.append(bool(policy.new_chunk[0]))
    finally:
        policy.close()
    assert [k // 4 for k, n in enumerate(new) if n] == [1, 4, 7]


def _rig(so101, path, inference="async"):
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.rig.chunk_hook import ChunkHook
    from sim2real.deploy.rig.rig import Rig

    backend = SimBackend(so101, "position", envs=1, seed=0)
    backend.open()
    rig = Rig(so101, LeRobotChunkPolicy(path, so101, inference=inference), backend, envs=1)
    rig.add(ChunkHook(rig))
    rig.start()
    return rig


def test_two_lockstep_runs_are_bit_identical_and_a_pending_request_round_trips(tmp_path, so101):
    """Two lockstep runs write the same commands tick for tick through many chunks; a run loaded
    from another's state taken while a request is pending (its chunk waited for and carried in
    the state) goes on exactly as that run. (A run whose state was taken is compared with the
    one loaded from it only: the smoother's state_dict changes its next commands by 1 ulp.)"""
    path = write_chunk_onnx(
        tmp_path / "a.onnx", chunk_size=6, n_action_steps=4, fps=25.0, image_shape=None,
        step_deg=1.5,
    )  # fmt: skip
    a, b, c = (_rig(so101, path) for _ in range(3))
    try:
        for _ in range(400):  # RAMP_IN, then 2.5 s of chunks
            a.runtime.tick()
            b.runtime.tick()
            np.testing.assert_array_equal(a.runtime.command, b.runtime.command)
        assert a.runtime.mode_names() == ["RUNNING"] and a.runtime.policy.calls[0] > 10
        for _ in range(16):  # to a tick that asked for a chunk
            if a.runtime.policy.state_dict()["pending"][0]:
                break
            a.runtime.tick()
        assert a.runtime.policy.state_dict()["pending"][0]
        c.runtime.load_state_dict(a.runtime.state_dict())
        for _ in range(60):
            a.runtime.tick()
            c.runtime.tick()
            np.testing.assert_array_equal(a.runtime.command, c.runtime.command)
        pa, pc = a.runtime.policy, c.runtime.policy
        assert (pa.calls == pc.calls).all() and pa.servo_thread_calls[0] == 0
    finally:
        for rig in (a, b, c):
            rig.close()
    assert _workers() == []


def test_the_policy_state_round_trips_with_a_request_pending(tmp_path, so101):
    path = write_chunk_onnx(tmp_path / "a.onnx", chunk_size=6, n_action_steps=3, fps=30.0)
    a = LeRobotChunkPolicy(path, so101, inference="async")
    b = LeRobotChunkPolicy(path, so101, inference="async")
    rng = np.random.default_rng(0)
    obs = [rng.uniform(-0.5, 0.5, (1, a.spec.obs_dim)).astype(np.float32) for _ in range(40)]
    try:
        for o in obs[:13]:
            a(o)
        st = a.state_dict()
        assert st["pending"][0] and st["pending_chunk"].shape == (1, 6, 6)
        b.load_state_dict(st)
        for o in obs[13:]:
            np.testing.assert_array_equal(a(o), b(o))
            assert (a.new_chunk == b.new_chunk).all()
        with pytest.raises(Exception, match="pending"):  # a sync state lacks the request
            b.load_state_dict(LeRobotChunkPolicy(path, so101).state_dict())
    finally:
        a.close()
        b.close()


class _Gate:
    """The real ONNX Runtime session behind a gate the test opens (a call that is not done
    when its chunk is due, without a timed wait)."""

    def __init__(self, session):
        self.session, self.open, self.answered = session, threading.Event(), 0

    def run(self, names, feed):
        self.open.wait()
        out = self.session.run(names, feed)
        self.answered += 1
        return out


def test_a_late_chunk_stops_the_robot_safely_as_an_overrun(tmp_path, so101):
    """On the wall clock a chunk still not done ``late_limit`` s into its wait: the env holds
    its target, asks nothing more, and the chunk hook stops it safely (cause overrun)."""
    path = write_chunk_onnx(tmp_path / "a.onnx", chunk_size=6, n_action_steps=4, image_shape=None)
    rig = _rig(so101, path)
    policy = rig.runtime.policy
    try:
        for _ in range(200):
            rig.runtime.tick()
            rig.after_tick(rig.runtime)
        assert rig.runtime.mode_names() == ["RUNNING"]
        gate = _Gate(policy.session)
        policy.session, policy.wall_clock, policy.late_limit = gate, True, 0.0
        for _ in range(40):  # past the next take of a gated call
            rig.runtime.tick()
            rig.after_tick(rig.runtime)
        assert policy.late[0] and policy.late_chunks[0] == 1
        assert FAULT_CAUSES[rig.runtime.cause[0]] == "overrun"
        assert rig.runtime.mode_names()[0] in ("SAFE_STOP", "FAULTED")
        gate.open.set()
    finally:
        gate.open.set()
        rig.close()
    assert _workers() == []


def test_a_reset_on_the_wall_clock_does_not_wait_for_the_pending_call(tmp_path, so101):
    """The end of RAMP_IN on hardware: the request pending is forgotten, the servo tick goes
    on (the gated call is still running when reset returns); the next request is answered."""
    path = write_chunk_onnx(tmp_path / "a.onnx", chunk_size=6, n_action_steps=4, image_shape=None)
    policy = LeRobotChunkPolicy(path, so101, inference="async")
    gate = _Gate(policy.session)
    policy.session, policy.wall_clock = gate, True
    obs = _obs(policy, np.zeros(6))
    try:
        policy(obs)  # a policy tick: asks
        assert policy.pending[0]
        policy.reset(np.ones(1, bool))
        assert gate.answered == 0 and not policy.pending[0]  # returned, the call still held
        gate.open.set()
        policy.wall_clock = False  # lockstep: the next take waits for its chunk
        for _ in range(8):
            policy(obs)
        assert policy.calls[0] == 1 and not policy.late[0]
    finally:
        gate.open.set()
        policy.close()
    assert _workers() == []


def _run(tmp_path, policy, *extra) -> tuple[int, dict]:
    report = tmp_path / "report.json"
    code = deploy_run(
        ["--robot", "so101", "--policy", str(policy), "--report", str(report), *extra]
    )
    return code, (json.loads(report.read_text()) if report.exists() else {})


def test_deploy_run_async_ends_its_worker_after_a_run_a_safe_stop_and_an_error(
    tmp_path, monkeypatch
):
    path = write_chunk_onnx(
        tmp_path / "a.onnx", chunk_size=6, n_action_steps=4, fps=25.0, image_shape=None
    )
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "3")
    assert code == EXIT_CLEAN and _workers() == []
    c = r["chunks"]
    assert c["inference"] == "async" and c["network_calls_on_servo_thread"] == 0
    assert c["policy_ticks_per_chunk"] == [4] and c["network_calls"] > 5
    # a safe stop (a stale joint reading): the run goes on to its end, the worker ends with it
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "3", "--inject",
                   "stale@2.5:0.3")  # fmt: skip
    assert r["faults"]["safe_stops"] >= 1 and _workers() == []
    # an error in the network call (raised on the servo thread at the take): the rig discarded
    calls = {"n": 0}
    real = LeRobotChunkPolicy._run

    def failing(self, feed):
        calls["n"] += 1
        if calls["n"] > 5:
            raise RuntimeError("the network call failed")
        return real(self, feed)

    monkeypatch.setattr(LeRobotChunkPolicy, "_run", failing)
    with pytest.raises(RuntimeError, match="the network call failed"):
        _run(tmp_path, path, "--backend", "sim", "--duration", "3")
    assert _workers() == []


def test_async_with_temporal_ensembling_is_refused_in_one_line(tmp_path, capsys):
    path = write_chunk_onnx(tmp_path / "e.onnx", chunk_size=6, n_action_steps=1, coeff=0.01)
    code, _ = _run(tmp_path, path, "--backend", "sim", "--duration", "1")
    err = capsys.readouterr().err.strip().splitlines()
    assert code == EXIT_BAD_INPUT and "Traceback" not in "\n".join(err)
    assert "temporal_ensemble_coeff 0.01 with async inference" in err[-1]
    assert "--inference sync" in err[-1]
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "2", "--inference", "sync")
    assert code == EXIT_CLEAN and r["chunks"]["inference"] == "sync"


# ---------------------------------------------------------------- the Feetech bus emulator
@pytest.mark.wallclock
@pytest.mark.alone  # the bus on a pty misses replies beside another process at normal priority
def test_async_runs_no_network_call_on_the_servo_thread_on_the_feetech_emulator(tmp_path):
    """The same export on the bus, sync then async: sync runs every network call inside a
    servo tick; async runs none there (counted, not timed: holds on a busy machine), at the
    same cadence. A loaded machine may stop a run safely (a stale reading, a late chunk): judged
    up to there."""
    from sim2real.deploy.backends.emulator import ServoBusEmulator

    pytest.importorskip("scservo_sdk", reason="the Feetech SDK (extra 'servo') is not installed")
    path = write_chunk_onnx(
        tmp_path / "a.onnx", chunk_size=6, n_action_steps=4, fps=25.0, image_shape=None,
        step_deg=1.5,
    )  # fmt: skip
    so101 = load_robot("so101")
    reports = {}
    for inference in ("sync", "async"):
        with ServoBusEmulator(so101, "feetech") as emu:
            _, r = _run(
                tmp_path, path, "--backend", "feetech", "--port", emu.port, "--duration", "4",
                "--overrun-limit", "1", "--inference", inference,
            )  # fmt: skip
        assert r["faults"]["by_cause"]["hard_limit"] == 0
        by = r["faults"]["by_cause"]  # a loaded machine: a stale reading, a late chunk
        assert r["faults"]["safe_stops"] == by["stale_sensor"] + by["overrun"]
        reports[inference] = r["chunks"]
    sync, asyn = reports["sync"], reports["async"]
    assert (
        sync["network_calls"] > 3 and sync["network_calls_on_servo_thread"] == sync["network_calls"]
    )
    assert asyn["network_calls"] > 3 and asyn["network_calls_on_servo_thread"] == 0
    assert asyn["policy_ticks_per_chunk"] == [4]
    assert _workers() == []
