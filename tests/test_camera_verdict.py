"""A camera policy's soak verdict (:mod:`sim2real.eval.soak.camera_verdict`): a frozen camera
stops the robot safely (a stale stop, latched, reset by the operator, running again) and is not
a failed session; a latch with no injected cause still fails; every stale-camera stop is
counted while only a bounded sample is kept; each failure names the camera fault before it.
The shipped camera arm policy on arm3, one session of a few simulated seconds."""

from __future__ import annotations

import copy
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from sim2real.deploy.backends.sim.camera import CameraFaults
from sim2real.eval.report.build import session_checks
from sim2real.eval.report.schema import Thresholds
from sim2real.eval.report.summary import camera_lines
from sim2real.eval.soak import camera_verdict as cv
from tests.soak_fixtures import short_session
from tests.test_camera import egl_works, needs_gl  # noqa: F401 - the skipif names egl_works
from tests.test_camera_arm import POLICY

#: A camera that freezes often: a spell of 10 frames (0.33 s at 30 Hz, past the policy's 0.19 s
#: stale limit) starts at 5 % of its fresh frames; nothing else.
FREEZING = CameraFaults(freeze=0.05, freeze_frames=10)


def _frozen_batch(out, resume=False):
    """The batch of one 14-s session of the camera policy whose camera freezes
    (:data:`FREEZING`), checkpointed every 3 s, the operator resetting a latch after 1 s; the
    runtime's and the verdict's kept stops limited to 1 each. Returns ``(result, batch)``."""
    from sim2real.deploy.runtime import stale
    from sim2real.eval.soak import camera_faults
    from sim2real.eval.soak.batch import SessionBatch

    mp = pytest.MonkeyPatch()
    mp.setattr(camera_faults, "session_camera_faults", lambda *a, **k: FREEZING)
    mp.setattr(stale, "MAX_RECORDS", 1)
    mp.setattr(cv, "STOP_SAMPLE", 1)
    try:
        config = replace(short_session("arm3", POLICY, hours=14.0 / 3600), seed=3)
        batch = SessionBatch([config], out, progress=False, resume=resume)
        (result,) = batch.run()
    finally:
        mp.undo()
    return result, batch


@pytest.fixture(scope="module")
def frozen_out(tmp_path_factory):
    return tmp_path_factory.mktemp("soak")


@pytest.fixture(scope="module")
def frozen_session(frozen_out):
    """:func:`_frozen_batch` run once."""
    return _frozen_batch(frozen_out)


@needs_gl
def test_a_frozen_camera_stops_the_robot_safely_and_it_runs_again(frozen_session):
    result, _ = frozen_session
    latches = result["runtime"]["latches"]
    assert latches, "a 10-frame freeze at 5 % of the frames must stop the robot in 14 s"
    assert all(x["cause"] == "stale_sensor" for x in latches)
    assert all(x["injected"].startswith("camera: frozen") for x in latches)
    ran = [x for x in latches if x.get("running_again_s") is not None]
    assert ran and all(x["running_again_s"] > x["reset_s"] >= x["t_s"] for x in ran)
    checks = session_checks(result, Thresholds())
    assert checks["no_latched_fault"]["passed"]
    assert (
        f"{len(latches)} more after an injected camera fault stopped it safely"
        in (checks["no_latched_fault"]["message"])
    )
    v = result["camera"]["verdict"]
    assert v["stopped_safely"]["frozen"] == v["stops"]["count"]
    assert v["latched_after_camera"] == {
        "count": len(latches), "ran_again": len(ran), "operator_reset_s": 1.0,
    }  # fmt: skip
    assert "frozen" not in v["survived"]  # it stopped the robot: not survived


@needs_gl
def test_a_latch_without_an_injected_cause_still_fails_the_session(frozen_session):
    result, _ = frozen_session
    bare = copy.deepcopy(result)
    for latch in bare["runtime"]["latches"]:
        latch["injected"] = None
    check = session_checks(bare, Thresholds())["no_latched_fault"]
    assert not check["passed"] and "stale_sensor" in check["message"]


@needs_gl
def test_every_stale_camera_stop_is_counted_and_a_bounded_sample_kept(frozen_session):
    result, batch = frozen_session
    stops = result["runtime"]["by_cause"]["stale_sensor"]
    assert stops >= 2  # else the limits below test nothing
    v = result["camera"]["verdict"]
    assert v["stops"]["count"] == stops and sum(v["stops"]["by_fault"].values()) == stops
    assert len(v["stops"]["sample"]) == 1 and v["stops"]["sample_limit"] == 1
    assert result["camera"]["stale_stops"] == v["stops"]["sample"]
    assert "verdict" in v["stops"]["sample"][0] and "frozen" in v["stops"]["sample"][0]["verdict"]
    rt = batch.rt.stale_stops  # the runtime's own records: bounded, the rest counted
    assert len(rt.records) == 1 and rt.dropped == stops - 1


@needs_gl
def test_the_console_names_what_the_camera_survived_what_stopped_it_and_after_what_it_failed(
    frozen_session,
):
    result, _ = frozen_session
    lines = "\n".join(camera_lines({"id": "seed0003", "camera": result["camera"]}))
    stops = result["camera"]["verdict"]["stops"]["count"]
    assert "camera verdict survived (no stop): " in lines
    assert f"camera verdict stopped it safely: frozen frames {stops} time" in lines
    assert "(stops kept: the first 1, all counted)" in lines
    assert "camera verdict failures by the camera fault before them" in lines


@needs_gl
def test_report_html_shows_the_camera_verdict_report_json_carries(frozen_session):
    """report.json's session carries the verdict as the session wrote it; report.html's
    ``camera verdict`` table shows it (what stopped the robot safely, its stale-camera stops,
    its latches and runs again); a report without a camera has no such section."""
    from sim2real.eval.report.build import build_report
    from sim2real.eval.report.html import report_html

    result, _ = frozen_session
    report = build_report({"robot": "arm3"}, [result])
    (s,) = report["sessions"]
    v = s["camera"]["verdict"]
    assert v == result["camera"]["verdict"]
    page = report_html(report)
    assert "<h2>Camera faults: survived, stopped safely after, failures after them</h2>" in page
    stops, latched = v["stops"]["count"], v["latched_after_camera"]
    row = page[page.index("<h2>Camera faults") : page.index("<h2>Randomization")]
    assert f"<td>{s['id']}</td>" in row
    assert f"<td>frozen frames {stops}</td>" in row  # stopped safely after: all its stops
    assert f"<td>{stops}: frozen {stops}</td>" in row
    assert f"<td>{latched['count']}, {latched['ran_again']} (1 s)</td>" in row
    two = copy.deepcopy(report)  # several cameras: a section each, one verdict
    lone = {k: x for k, x in s["camera"].items() if k not in ("verdict", "stale_stops")}
    wrist = {**lone, "camera": "wrist", "kind": "rgb"}
    two["sessions"][0]["camera"] = {"cameras": {"goal": lone, "wrist": wrist}, "verdict": v}
    assert f"<td>{lone['camera']} (depth) 30 Hz; wrist (rgb) 30 Hz</td>" in report_html(two)
    bare = copy.deepcopy(report)
    del bare["sessions"][0]["camera"]
    assert "Camera faults" not in report_html(bare)


@needs_gl
def test_a_resumed_session_keeps_its_camera_verdict(frozen_session, frozen_out):
    result, _ = frozen_session
    again, _ = _frozen_batch(frozen_out, resume=True)  # from its checkpoint at 12 s
    assert again["camera"]["verdict"] == result["camera"]["verdict"]
    assert again["runtime"]["latches"] == result["runtime"]["latches"]


def test_fault_labels_name_the_per_frame_faults_and_the_session_wide_ones_in_words():
    assert cv.fault_label({"frozen": 3, "dropped": 1, "spiked": 0}) == "frozen+dropped"
    assert cv.fault_label({"frozen": 0, "dropped": 0, "spiked": 2}) == "late"
    assert cv.fault_label({"frozen": 0, "dropped": 0, "spiked": 0}) == "none"
    assert cv.fault_label(None) == "none"
    faults = FREEZING.to_dict() | {"occlusion": 0.05, "extrinsic": (0.0, np.radians(1.5), 0.0)}
    faults["lighting"] = 1.3
    assert cv.throughout(faults, "depth") == ["lens 5.0 % covered", "mount knocked 1.50 deg"]
    assert cv.throughout(faults, "rgb")[-1] == "light x1.30"
    assert cv.throughout(CameraFaults().to_dict(), "rgb") == []


class _Camera:
    """A plant camera's ``recent``: a frozen spell before 5 s, nothing after (our own class's
    one method; no third-party object is stood in for)."""

    def recent(self, env, now, window=1.0):
        frozen = 5 if now - window < 5.0 else 0
        return {"window_s": window, "frozen": frozen, "dropped": 0, "spiked": 0, "last": None}


def _batch():
    rt = SimpleNamespace(
        envs=1,
        counters=SimpleNamespace(safe_stops=np.zeros(1, int)),
        mode=np.full(1, 2, np.int8),
        stale_stops=SimpleNamespace(on_record=None),
    )
    session = SimpleNamespace(
        e=0, latches=[], fault_events=[], config=SimpleNamespace(operator_reset=10.0)
    )
    goals = SimpleNamespace(missed=[[]], missed_dropped=np.zeros(1, int), period=4.0)
    return SimpleNamespace(
        rt=rt,
        camera=_Camera(),
        sessions=[session],
        violations=SimpleNamespace(counts={"hard_limit": np.zeros(1, int)}),
        task=SimpleNamespace(scheduler=goals),
    )


def test_each_failure_is_counted_by_the_camera_fault_before_it():
    b = _batch()
    verdict = cv.CameraVerdict(b)
    assert b.rt.stale_stops.on_record == verdict.stale_stop
    hard, goals, s = b.violations.counts["hard_limit"], b.task.scheduler, b.sessions[0]
    hard[0] = 3
    verdict.step(b.rt, 4.5)  # a hard-limit onset in the frozen spell's second
    hard[0] = 5
    verdict.step(b.rt, 4.6)  # the same violation going on: not a second failure
    goals.missed[0].append({"t_s": 12.0, "issued_s": 8.0})  # a miss long after the spell
    verdict.step(b.rt, 12.0)
    b.rt.counters.safe_stops[0] = 1  # a stop that is no camera's, then its latch
    s.latches.append({"t_s": 13.0, "cause": "hard_limit", "reset_s": None})
    verdict.step(b.rt, 13.0)
    verdict.stale_stop(_camera_stop(14.0, frozen=4))  # a frozen camera stops a goal ...
    goals.missed[0].append({"t_s": 30.0, "issued_s": 13.5})  # ... missed once running again
    verdict.step(b.rt, 30.0)
    counts = verdict.state[0]["failures"]["counts"]
    assert counts["hard_violation"] == {"frozen": 1}
    assert counts["missed_goal"] == {"none": 1, "camera stop after frozen": 1}
    assert counts["latched"] == {"none": 1} and s.latches[0]["injected"] is None
    assert s.latches[0]["camera"] == "none"
    # the soak's own faults: latched in the camera stop's window; held, or met while already
    # stopped, in it; latched long after it
    s.fault_events += [
        {"start_s": 13.8, "duration_s": 0.02, "response": "latched"},
        {"start_s": 13.9, "duration_s": 0.02, "response": "held"},
        {"start_s": 14.1, "duration_s": 0.02, "response": "not_running"},
        {"start_s": 40.0, "duration_s": 0.02, "response": "latched"},
    ]
    verdict.step(b.rt, 45.0)
    assert [ev["camera_stop"] for ev in s.fault_events] == ["camera: frozen", None, None, None]


def _camera_stop(t: float, frozen: int = 0) -> dict:
    """A runtime's stale-stop record of a camera alone stale at ``t`` s (``StaleStops``)."""
    return {
        "env": 0, "t_s": t, "camera_s": 0.3, "joints": {}, "imu_s": None,
        "height_map_s": None, "verdict": "depth camera: silent",
        "other_side": {"camera_faults": {"frozen": frozen, "dropped": 0, "spiked": 0}},
    }  # fmt: skip


def test_a_stale_camera_stop_without_a_camera_fault_before_it_is_a_failure():
    b = _batch()
    verdict = cv.CameraVerdict(b)
    record = _camera_stop(20.0)
    verdict.stale_stop(record)
    b.rt.counters.safe_stops[0] = 1
    b.sessions[0].latches.append({"t_s": 20.05, "cause": "stale_sensor", "reset_s": None})
    verdict.step(b.rt, 20.05)
    assert verdict.state[0]["stops"]["by_fault"] == {"none": 1}
    assert b.sessions[0].latches[0]["injected"] is None
    assert verdict.state[0]["failures"]["counts"]["latched"] == {"none": 1}
    record["joints"] = {"shoulder": 0.1}  # an encoder stale too: no camera's stop
    verdict.stale_stop(record)
    assert verdict.state[0]["stops"]["count"] == 1


def test_the_verdict_state_round_trips_through_a_checkpoint_state():
    b = _batch()
    verdict = cv.CameraVerdict(b)
    verdict.state[0]["stops"]["count"] = 7
    state = verdict.state_dict(0)
    other = cv.CameraVerdict(_batch())
    other.load_state_dict(state, 0)
    assert other.state == verdict.state
