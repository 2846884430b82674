"""A ``stale_sensor`` stop says what went stale (sim2real.deploy.runtime.stale): the reader, the
joints, how long they had been without a fresh reading, what the other side and our own loop were
doing, in report.json (``faults.stale_stops``) and in the summary's one-line verdict.

Lockstep runs on the simulated plant (its encoders lost, or its frame frozen) and, on the wall
clock, a reader on this computer's clock whose robot falls silent against one whose process is
stalled (our loop late, the robot fine): the verdicts differ. The Unitree emulator's silent
LowState is checked in tests/test_unitree_backend.py.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from sim2real.deploy.backends.sim.faults import Fault, FaultInjector
from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.cli.deploy_run import deploy_run_main
from sim2real.deploy.cli.run_verdict import EXIT_FAULT
from sim2real.deploy.core.stale import arrivals_phrase, context, stale_context
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Mode, Runtime, WallClock
from sim2real.deploy.runtime.reference import ReferenceRuntime
from tests.runtime_fixtures import adversarial_onnx


def _runtime(tmp_path, robot, faults=(), runtime=Runtime, backend=None, clock=None):
    policy = OnnxPolicy(adversarial_onnx(tmp_path, robot, "position"), robot)
    backend = backend or SimBackend(robot, mode="position", seed=0)
    injector = FaultInjector(list(faults), backend) if faults else None
    rt = runtime(robot, policy, backend, clock=clock, injector=injector)
    rt.start()
    return rt


def test_deploy_run_names_the_silent_encoders_the_joints_and_the_time(tmp_path, arm3, capsys):
    """Every encoder reading lost from 1 s (the sim's dropout fault): one stale stop whose
    record names the plant's encoders, every joint, a time past the stale limit, the lost
    readings and our ticks on time (lockstep); the summary prints the verdict."""
    report = tmp_path / "run.json"
    policy = adversarial_onnx(tmp_path, arm3, "position")
    argv = ["--robot", "arm3", "--policy", str(policy), "--duration", "1.5",
            "--inject", "dropout@1:0.3", "--report", str(report)]  # fmt: skip
    assert deploy_run_main(argv) == EXIT_FAULT
    out = capsys.readouterr().out
    r = json.loads(report.read_text())
    limit = arm3.stale_limit
    (stop,) = r["faults"]["stale_stops"]
    assert r["faults"]["by_cause"]["stale_sensor"] == 1
    assert stop["stream"] == "encoders" and "sim plant's encoders" in stop["reader"]
    assert set(stop["joints"]) == set(arm3.joint_names)
    # past the limit (to the microsecond the report keeps), within a period of it
    assert all(limit <= s < limit + arm3.control_period for s in stop["joints"].values())
    assert stop["without_reading_s"] >= limit and 1.0 <= stop["t_s"] < 1.0 + 2 * limit
    assert stop["this_tick"]["no_reading"] == list(arm3.joint_names)
    assert stop["other_side"]["dropout_probability"] == 1.0
    assert stop["our_side"] == {"realtime": False, "late_s": 0.0}
    assert stop["verdict"] == (
        f"encoders: no fresh reading for {1e3 * stop['without_reading_s']:.0f} ms (every "
        "encoder reading lost: dropout probability 1; our ticks on time, lockstep)"
    )
    assert f"stale sensor      t {stop['t_s']:.2f} s: {stop['verdict']}; joints " in out
    # the report names the reader in general, stop or not: the plant's encoders at the end
    assert r["faults"]["reader"]["stream"] == "encoders"
    assert r["faults"]["reader"]["dropout_probability"] == 0.0


@pytest.mark.parametrize("runtime", [Runtime, ReferenceRuntime])
def test_a_frozen_frame_is_named_as_readings_arriving_old(tmp_path, arm3, runtime):
    """The sim's stale fault (the frame frozen: old readings repeat) on the compiled tick and
    its numpy reference: the same stop at the same tick, recorded as readings arriving but
    older than the stale limit, not as lost ones."""
    rt = _runtime(tmp_path, arm3, [Fault("stale", 1.0, 1.0)], runtime=runtime)
    rt.run(int(round(1.3 / rt.dt)))
    (stop,) = rt.stale_stops.records
    assert rt.cause_names() == ["stale_sensor"] and rt.mode[0] in (Mode.SAFE_STOP, Mode.FAULTED)
    assert stop["tick"] == int(round(1.0 / rt.dt)) + 10  # 10 periods of 5 ms: past 50 ms
    assert set(stop["joints"]) == set(arm3.joint_names) and not stop["this_tick"]["no_reading"]
    ages = stop["this_tick"]["reading_age_s"].values()
    assert all(a >= arm3.stale_limit for a in ages)
    assert "(readings arriving but 50 ms old (repeated or late); our ticks" in stop["verdict"]
    assert stop["verdict"].endswith("our ticks on time, lockstep)")


class WallClockReader:
    """The sim plant behind a reader on this computer's clock, as a hardware backend's: each
    frame is stamped now and each reading when it was received, NaN where none was (as the
    Unitree and ROS 2 backends do). ``silent``: the robot sends nothing more. :meth:`starve`
    stalls this process (``time.sleep`` in the loop's thread, between its wake-up and its next
    read), and the reader, a thread of this process held off as a collection holding the GIL
    would hold it, has received nothing new by that read."""

    def __init__(self, plant: SimBackend):
        self.plant, self.silent, self._starved = plant, False, False
        self._t0 = time.monotonic()
        plant.dropout_probability[:] = 0.0

    def __getattr__(self, name):
        return getattr(self.plant, name)

    def starve(self, seconds: float) -> None:
        time.sleep(seconds)
        self._starved = True

    def read(self):
        f = self.plant.read()
        f.time[:] = time.monotonic() - self._t0
        if self.silent or self._starved:
            f.position[:] = f.position_stamp[:] = np.nan
        else:
            f.position_stamp[:] = f.time[:, None]
        self._starved = False
        return f

    def stale_context(self, env: int = 0) -> dict:
        return context("test", "reader", "a reader thread on the wall clock", arrived=0,
                       other_side=arrivals_phrase(0, {}, "robot silent"))  # fmt: skip


@pytest.mark.wallclock
def test_the_verdict_tells_a_silent_robot_from_our_late_loop(tmp_path, arm3):
    """On the wall clock: the robot falls silent (our ticks on time) against our loop stalled
    100 ms with the robot sending: both make a real stale stop, the first blamed on the robot,
    the second on this computer, naming how late the loop was."""
    limit, stall = arm3.stale_limit, 0.1
    verdicts = {}
    for case in ("silent", "stalled"):
        reader = WallClockReader(SimBackend(arm3, mode="position", seed=0))
        rt = _runtime(tmp_path, arm3, backend=reader, clock=WallClock(arm3.control_period))
        at = int(round(0.3 / rt.dt))

        def fault(rt, at=at, case=case, reader=reader):
            if rt.ticks == at and case == "silent":
                reader.silent = True
            elif rt.ticks == at:
                reader.starve(stall)
            return rt.ticks > at + int(round(0.3 / rt.dt))

        rt.run(int(round(1.0 / rt.dt)), on_tick=fault)
        (stop,) = rt.stale_stops.records
        assert rt.cause_names() == ["stale_sensor"]
        assert set(stop["joints"]) == set(arm3.joint_names)
        assert stop["without_reading_s"] >= limit and stop["our_side"]["realtime"]
        verdicts[case] = stop
    silent, stalled = verdicts["silent"], verdicts["stalled"]
    assert silent["verdict"].startswith("reader: no fresh reading for ")
    assert silent["verdict"].endswith("(robot silent; our ticks on time)"), silent
    assert silent["our_side"]["late_s"] < 0.5 * silent["without_reading_s"]
    # the robot's silence is seen the stale limit later; the stall at the first read after it
    assert silent["tick"] > int(round(0.3 / arm3.control_period)) + 5
    assert stalled["tick"] == int(round(0.3 / arm3.control_period))
    assert stalled["without_reading_s"] >= stall and stalled["our_side"]["late_s"] >= stall
    assert "late: this computer, not the robot)" in stalled["verdict"], stalled


def test_a_backend_without_a_reader_context_gets_the_default(arm3):
    """A stand-in backend with no ``stale_context`` (nor the lifecycle mixin's): its class name
    and ``sensor frame``, nothing counted."""

    class Bare:
        pass

    ctx = stale_context(Bare())
    assert ctx["backend"] == "Bare" and ctx["stream"] == "sensor frame"
    assert ctx["arrived"] is None and ctx["other_side"] is None
    assert json.loads(json.dumps(ctx)) == ctx
