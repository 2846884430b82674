"""A motion-tracking session resumes with its plays: the tracking task's play log and judged
figures are in its state dict (the part ``figures`` a soak checkpoint composes), and a tracking
soak's summary claims no velocity tracking for a clip.

The task runs here on the shipped go2 walker with a synthetic 12-joint clip (the task judges any
legged robot against any clip of its joints; the walker ignores the clip): cheap, no mirror.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

from sim2real.deploy.core.stateful import parts_state_dict
from sim2real.deploy.tasks.motion.clip import MotionClip
from sim2real.deploy.tasks.motion.clock import MotionClock

#: the go2's joints standing in for a humanoid's waist (yaw, roll, pitch): any three of the robot
WAIST = (0, 1, 2)


def _rig(go2, go2_onnx, tmp_path):
    """A one-env rig with the ``tracking`` task: a 0.3-s clip around the home pose, 0.2 s to home,
    0.2 s standing, again (an exhibition)."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.rig.rig import Rig

    frames = 15
    pos = np.tile(go2.home, (frames, 1)) + 0.05 * np.sin(np.arange(frames))[:, None]
    root = np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1))
    clip = MotionClip(
        source=tmp_path / "clip.csv", fps=50.0, joint_names=tuple(go2.joint_names),
        joint_pos=pos, joint_vel=np.gradient(pos, axis=0) * 50.0,
        root_pos=np.zeros((frames, 3)), root_quat=root,
    )  # fmt: skip
    names = tuple(go2.joint_names[i] for i in WAIST)
    clock = MotionClock(clip, go2.joint_names, names, 1, "exhibition", go2.home, 0.2, 0.2)
    policy = OnnxPolicy(go2_onnx, go2)
    task = {"period": 1.0, "rng": np.random.default_rng(0), "task": "tracking"}
    backend = SimBackend(go2, "position", envs=1, seed=0)
    rig = Rig(go2, policy, backend, envs=1, task={**task, "motion": (clock, WAIST)})
    rig.start()
    return rig


def _run(rig, ticks: int) -> None:
    for _ in range(ticks):
        rig.runtime.tick()
        rig.monitor(rig.runtime)


def test_the_play_log_and_figures_resume_from_the_tasks_state(go2, go2_onnx, tmp_path):
    """After a few plays, a fresh task loaded with the first's state (as a soak resumes from its
    checkpoint: the parts' state dicts of its env) holds the same play log and figures, and the
    next play closes the same in both (its sums were carried over)."""
    rig = _rig(go2, go2_onnx, tmp_path)
    _run(rig, 300)  # RAMP_IN, then plays of 0.3 + 0.2 + 0.2 s
    task = rig.task
    assert len(task.play_log[0]) >= 2, task.play_log
    state = parts_state_dict(task.parts(), 0)
    assert "figures/play_log" in state  # what Session.capture writes
    fresh = _rig(go2, go2_onnx, tmp_path)
    fresh.runtime.load_state_dict(rig.runtime.state_dict(0), 0)
    fresh.interventions.load_state_dict(rig.interventions.state_dict(0), 0)
    for prefix, part in fresh.task.parts().items():
        part.load_state_dict({k[len(prefix) + 1 :]: v for k, v in state.items()
                              if k.startswith(prefix + "/")}, 0)  # fmt: skip
    assert fresh.task.play_log == task.play_log
    played = task.play_log[0][0]  # each play with the field's figures
    assert played["joint_rms_rad"] > 0.0 and played["mpjpe_mm"] > 0.0
    assert played["anchor_error_deg_mean"] is not None
    a, b = task.summary(), fresh.task.summary()
    for key in ("completed", "ticks", "joint_rms_rad_all", "mpjpe_mm", "anchor_error_deg_mean"):
        assert b[key] == pytest.approx(a[key]), key
    before = len(task.play_log[0])
    while len(task.play_log[0]) == before:
        _run(rig, 1)
        _run(fresh, 1)
    assert len(fresh.task.play_log[0]) == before + 1
    assert fresh.task.play_log[0][-1]["ticks"] == task.play_log[0][-1]["ticks"]


def test_a_session_ending_mid_clip_logs_that_clip_unfinished(go2, go2_onnx, tmp_path):
    """A soak session whose end falls inside a clip: its exhibition's clips end with that play,
    ``unfinished``, the share of the clip reached and its ticks judged (it was not logged at
    all); the heat report counts it neither completed nor a fall; asking changes no state. In
    the rest between clips the open play is the clip whose rest it is, whole, its rest cut
    short (a play is logged with its rest, at the next clip's start)."""
    from types import SimpleNamespace

    from sim2real.eval.soak.exhibition import heat_report
    from sim2real.eval.soak.result import exhibition_result

    rig = _rig(go2, go2_onnx, tmp_path)
    task, clock = rig.task, rig.task.motion
    _run(rig, 150)  # RAMP_IN, then plays of 0.3 + 0.2 + 0.2 s
    while not (task.play_log[0] and 0.1 < clock.time[0] < 0.2):  # a later play, mid-clip
        _run(rig, 1)
    session = SimpleNamespace(task=task, e=0, batch=SimpleNamespace(
        violations=SimpleNamespace(reference_ticks=np.zeros(1, np.int64))))  # fmt: skip
    logged = copy.deepcopy(task.play_log[0])
    clips = exhibition_result(session)["clips"]
    assert clips[:-1] == logged and task.play_log[0] == logged  # nothing changed by asking
    last = clips[-1]
    assert last["unfinished"] and not last["stopped"], last
    assert last["completed"] == pytest.approx(clock.time[0] / clock.length)
    assert 0.3 < last["completed"] < 0.7 and last["ticks"] > 0 and last["joint_rms_rad"] > 0
    h = heat_report(clips)
    assert (h["clips"], h["completed"], h["falls"], h["unfinished"]) == (
        len(logged) + 1,
        len(logged),
        0,
        1,
    )
    from sim2real.eval.report.summary import exhibition_lines

    line = exhibition_lines({"id": "seed0000", "exhibition": exhibition_result(session)})[0]
    assert f"completed {len(logged)}, falls 0, the last cut short by the session's end" in line
    while not clock.time[0] > clock.total:  # the rest after the clip and its transition
        _run(rig, 1)
    rest = task.open_play(0)
    assert rest["rest_cut_short"] and rest["completed"] == 1.0 and "unfinished" not in rest
    assert task.plays(0) == [*task.play_log[0], rest]
    assert heat_report(task.plays(0))["completed"] == len(task.play_log[0]) + 1


# The tests reading the module fixture legged_result: on one pytest-xdist worker (make test's
# --dist loadgroup), which builds it once, not once per worker.
ON_ONE_WORKER = pytest.mark.xdist_group("legged_result")


@pytest.fixture(scope="module")
def legged_result(go2_onnx, tmp_path_factory) -> dict:
    """A 7.2-s go2 soak session's result (a velocity-commanded one, to be dressed as a clip's)."""
    from sim2real.eval.soak.batch import SessionBatch
    from tests.soak_fixtures import short_session

    config = short_session("go2", go2_onnx, 0.002)
    return SessionBatch([config], tmp_path_factory.mktemp("legged"), progress=False).run()[0]


@ON_ONE_WORKER
def test_a_clip_sessions_summary_claims_no_velocity_tracking(legged_result):
    """A legged session a clip commands (``commanded_by: clip``): the console summary prints its
    falls and its clips' tracking (joint error, anchor error, MPJPE per clip), no velocity
    tracking, distance or forward speed; its success checks pass, not judged, saying why."""
    from sim2real.eval.report.build import build_report, session_checks
    from sim2real.eval.report.schema import Thresholds
    from sim2real.eval.report.summary import summary_text
    from sim2real.eval.soak.exhibition import heat_report

    result = copy.deepcopy(legged_result)
    result["locomotion"]["commanded_by"] = "clip"
    play = {"completed": 1.0, "stopped": False, "joint_rms_rad": 0.09, "ticks": 1749,
            "anchor_error_deg_mean": 2.7, "mpjpe_mm": 27.1, "interventions": 3,
            "safety_interventions": 0, "end_s": 40.0, "hottest": "left_knee_joint",
            "hottest_c": 61.0, "derating": []}  # fmt: skip
    result["exhibition"] = {
        "clip": "dance.csv", "clip_s": 34.98, "stand_s": 2.0, "rest_s": 10.0,
        "clips": [play, {**play, "joint_rms_rad": 0.1, "mpjpe_mm": 30.0}],
        "reference_contacts": {"frames_touching": 0}, "reference_contact_ticks": 0,
        "heat": heat_report([play, play]),
    }  # fmt: skip
    source = "CommandRanges' default (our choice)"
    schedule = {"period_s": 4.0, "zero_fraction": 0.2, "vx": [0.0, 0.5], "vy": [0.0, 0.0],
                "yaw_rate": [-0.5, 0.5], "sources": dict.fromkeys(
                    ("vx", "vy", "yaw_rate", "zero_fraction", "period"), source)}  # fmt: skip
    campaign = {"robot": "g1", "commands": schedule}
    report = build_report(campaign, [result], Thresholds(judge_tracking=True))
    text = summary_text(report)
    assert "within 0.2 m/s" not in text and "forward speed" not in text
    assert "lowest tracking success" not in text and "  commands " not in text
    assert "a motion clip commands the policy, not a velocity" in text
    assert "joint error 0.090-0.100 rad RMS, anchor error 2.7-2.7 deg mean, MPJPE 27.1-30.0 mm" in (
        text
    )
    checks = session_checks(result, Thresholds(judge_tracking=True))
    assert checks["success_rate"]["passed"] and checks["window_success"]["passed"]
    assert checks["success_rate"]["message"].startswith("not judged: a motion clip")
    assert report["totals"]["locomotion"]["clip_sessions"] == 1
    assert report["totals"]["locomotion"]["tracking_success"] is None
    assert report["totals"]["locomotion"]["yaw_tracking_success"] is None
    from sim2real.eval.report.html import report_html

    # the sessions' and locomotion tables (the latter's yaw-rate column too)
    assert report_html(report).count("n/a (a clip)") == 6


def test_the_anchor_is_judged_against_the_true_heading_not_the_estimates(go2, go2_onnx, tmp_path):
    """The clip is aligned to the robot's estimated heading (rl_sar's ``Reset`` on its IMU);
    judged on the truth, an estimate 0.5 rad off in yaw when the clip was aligned is not the
    policy's anchor error: the same figure as with an estimate on the true heading (the go2
    walker ignores the clip, so both robots move alike; the figure itself is large: the go2's
    hips stand in for a waist)."""
    from sim2real.deploy.spec.motion_blocks import axis_quat, quat_mul

    def anchor(turn: float) -> float:
        rig = _rig(go2, go2_onnx, tmp_path)
        orientation = rig.runtime.state.base.orientation
        for _ in range(150):
            rig.runtime.tick()
            seen = orientation.copy()  # the task reads an estimate turned by ``turn``
            orientation[:] = quat_mul(axis_quat(2, np.full(1, turn)), seen)
            rig.monitor(rig.runtime)
            orientation[:] = seen  # the policy and the estimator keep theirs
        return rig.task.summary()["anchor_error_deg_mean"]

    straight, turned = anchor(0.0), anchor(0.5)
    assert turned == pytest.approx(straight, abs=1.0), (straight, turned)


@ON_ONE_WORKER
def test_a_clip_campaign_is_not_judged_on_a_baselines_velocity_tracking(legged_result):
    """A clip campaign against a velocity-commanded baseline of the same robot (or the other way
    round): no velocity tracking to compare, so no regression of it (the clip side's None was
    read as 0, 'tracking success fell from 0.9 to 0.000'); two velocity campaigns still compare."""
    from sim2real.eval.report.baseline import compare_with_baseline
    from sim2real.eval.report.build import build_report
    from sim2real.eval.report.schema import Thresholds

    clip = copy.deepcopy(legged_result)
    clip["locomotion"]["commanded_by"] = "clip"
    walk = copy.deepcopy(legged_result)
    walk["locomotion"]["tracked_s"] = 0.9 * walk["locomotion"]["running_s"]  # a good baseline
    t = Thresholds()
    clips, walks = (
        build_report({"robot": "go2"}, [clip], t),
        build_report({"robot": "go2"}, [walk], t),
    )
    assert walks["totals"]["locomotion"]["tracking_success"] == pytest.approx(0.9)
    for new, old in ((clips, walks), (walks, clips)):
        compared = compare_with_baseline(new, old, t)
        assert not any(m.startswith("locomotion.") for m in compared["compared"]), compared
    worse = build_report({"robot": "go2"}, [copy.deepcopy(legged_result)], t)
    worse["totals"]["locomotion"]["tracking_success"] = 0.5
    metrics = {r["metric"] for r in compare_with_baseline(worse, walks, t)["regressions"]}
    assert "locomotion.tracking_success" in metrics
