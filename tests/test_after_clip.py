"""What follows a clip is a decision the user sees, and the base's travel judges a clip run.

On CI's shipped go2: a made-up tracking policy that walks (the go2 walker behind a graph that
reads a clip and always commands 0.6 m/s forward, :mod:`tests.walking_dancer`) plays a 2-s clip
whose root walks 0.45 m/s forward. Held after the clip it walks on, off its spot: the run
fails (exit 5); handed over to the go2's standing policy at the clip's end, it stops there.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sim2real.deploy.tasks.motion.clip import MotionClip
from sim2real.deploy.tasks.motion.clock import MotionClock
from sim2real.deploy.tasks.motion.travel import OFF_PATH_M, ClipTravel
from tests.walking_dancer import clip_npz, walking_dancer_onnx

# Every test reads the module fixture: on one pytest-xdist worker (make test's --dist
# loadgroup), which builds it once, not once per worker.
pytestmark = pytest.mark.xdist_group("walking_dancer")


@pytest.fixture(scope="module")
def dancer(go2, go2_policies, tmp_path_factory):
    """(the walking dancer's ONNX, the go2 standing policy's, a 2-s clip walking 0.45 m/s)."""
    from pathlib import Path

    folder = tmp_path_factory.mktemp("dancer")
    onnx_path = walking_dancer_onnx(Path(go2_policies["walk"]), folder / "dancer.onnx", 0.6)
    clip = clip_npz(folder / "walk.npz", go2, 2.0, 0.45)
    return onnx_path, go2_policies["stand"], clip


def _run(argv, tmp_path, capsys) -> tuple[int, dict, str]:
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    report = tmp_path / "r.json"
    code = deploy_run_main(
        ["--backend", "sim", "--robot", "go2", "--duration", "5", "--report", str(report), *argv]
    )
    out = capsys.readouterr()
    return code, (json.loads(report.read_text()) if report.exists() else {}), out.out + out.err


def test_a_policy_walking_away_after_its_clip_fails_the_run(dancer, tmp_path, capsys):
    """Held after its clip (the default: to home, then home) the policy walks on: the summary
    says what followed the clip, where the base went during and after it against the clip's
    root path, prints no velocity-task line, and the run exits 5, not 0."""
    policy, _, clip = dancer
    code, r, out = _run(["--policy", str(policy), "--motion", str(clip)], tmp_path, capsys)
    assert code == 5
    t = r["tracking"]
    assert t["after_clip"]["follows"] == "stand"
    (f,) = t["travel"]["envs"]
    assert t["travel"]["off_path"] == [0]
    assert f["after_clip_travel_m"] > 2 * OFF_PATH_M and f["end_offset_m"] > OFF_PATH_M
    assert f["clip_root_travel_m"] == pytest.approx(0.9, abs=0.02)  # 2.02 s at 0.45 m/s
    assert "LEFT ITS SPOT" in out and "exit code 5" in out
    assert "a hold judged" in out and "guard interventions" in out
    assert "walked " not in out and "  heading " not in out  # no velocity task in a clip run


def test_a_second_policy_takes_the_robot_at_the_clips_end(dancer, tmp_path, capsys):
    """Given a second --policy, the run hands over to it at the clip's end (rl_sar's fsm): the
    standing policy stops the walk within the bound, and the run is clean."""
    policy, stand, clip = dancer
    argv = ["--policy", f"dance={policy}", "--policy", f"stand={stand}", "--motion", str(clip)]
    code, r, out = _run(argv, tmp_path, capsys)
    t = r["tracking"]
    assert code == 0, out
    after = t["after_clip"]
    assert after["follows"] == "handover" and after["policy"] == "stand"
    # RAMP_IN, then the 2.02-s clip: handed over once it ended, not before
    assert after["at_s"] is not None and after["at_s"] > t["length_s"]
    (f,) = t["travel"]["envs"]
    assert f["after_clip_max_m"] < OFF_PATH_M and t["travel"]["off_path"] == []
    assert t["plays"] == 1  # the clip does not start again under the standing policy
    assert "handed over to 'stand'" in out


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--after-clip", "walk"], "--after-clip walk: expected the NAME of a --policy"),
        (["--envs", "2"], "--envs must be 1"),
        (["--motion-playback", "loop"], "--motion-playback loop and a hand-over"),
        (["--after-clip-blend=-1"], "--after-clip-blend -1.0: expected s >= 0"),
    ],
)
def test_a_hand_over_that_cannot_be_is_refused_in_one_line(dancer, tmp_path, capsys, extra, match):
    policy, stand, clip = dancer
    argv = ["--policy", f"dance={policy}", "--policy", f"stand={stand}", "--motion", str(clip)]
    code, _, out = _run([*argv, *extra], tmp_path, capsys)
    lines = [x for x in out.splitlines() if x.startswith("deploy-run: error:")]
    assert code == 3 and len(lines) == 1 and match in lines[0]
    assert not (tmp_path / "r.json").exists()


def test_the_policy_off_and_home_held_keeps_the_dancer_on_its_spot(dancer, tmp_path, capsys):
    """--after-clip default-pose, no second policy: at the clip's end the dancer's policy is off
    and the PD loop holds home, ramped to over 2 s (unitree_rl_gym's move_to_default_pos): the
    walker stops on its spot, the run is clean and says what followed the clip."""
    policy, _, clip = dancer
    argv = ["--policy", str(policy), "--motion", str(clip), "--after-clip", "default-pose"]
    code, r, out = _run(argv, tmp_path, capsys)
    t = r["tracking"]
    assert code == 0, out
    after = t["after_clip"]
    assert after["follows"] == "default_pose" and after["blend_s"] == 2.0
    assert after["at_s"] is not None and after["at_s"] > t["length_s"]
    (f,) = t["travel"]["envs"]
    assert f["after_clip_max_m"] < OFF_PATH_M and t["travel"]["off_path"] == []
    assert t["plays"] == 1 and r["locomotion"]["falls"] == 0
    assert "the policy off at the clip's end" in out and "over 2 s" in out


def test_with_the_policy_off_the_dancer_is_not_called_after_its_clip(dancer, go2, monkeypatch):
    """The hold is the PD loop's, not the policy's: once the clip has ended the dancer's ONNX is
    not run again, and the joints' targets reach home after the ramp."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.rig.after_clip import AfterClipHook

    calls, seen = [], {}
    real_call, real_tick = OnnxPolicy.__call__, AfterClipHook.after_tick

    def counted(self, obs):
        calls.append(seen.get("runtime") and seen["runtime"].time)
        return real_call(self, obs)

    def watched(self, runtime):
        seen["runtime"], seen["hook"] = runtime, self
        real_tick(self, runtime)

    monkeypatch.setattr(OnnxPolicy, "__call__", counted)
    monkeypatch.setattr(AfterClipHook, "after_tick", watched)
    policy, _, clip = dancer
    argv = ["--backend", "sim", "--robot", "go2", "--duration", "5", "--policy", str(policy),
            "--motion", str(clip), "--after-clip", "default-pose", "--after-clip-blend", "1"]  # fmt: skip
    assert deploy_run_main(argv) == 0
    at = seen["hook"].at_s
    assert at is not None and calls and max(c or 0.0 for c in calls) <= at + 1e-9
    np.testing.assert_allclose(seen["runtime"].target[0], go2.home, atol=1e-6)


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        (["--motion-playback", "hold"], "--after-clip default-pose and --motion-playback hold"),
        (["SECOND"], "--after-clip default-pose and a second --policy"),
        (["--envs", "2"], "--envs must be 1"),
        (["--after-clip-blend=-1"], "--after-clip-blend -1.0: expected s >= 0"),
    ],
)
def test_a_default_pose_hold_that_cannot_be_is_refused_in_one_line(
    dancer, tmp_path, capsys, extra, match
):
    policy, stand, clip = dancer
    if extra == ["SECOND"]:  # the go2's standing policy as a second --policy
        extra = ["--policy", f"stand={stand}"]
    argv = ["--policy", f"dance={policy}", "--motion", str(clip), "--after-clip", "default-pose"]
    code, _, out = _run([*argv, *extra], tmp_path, capsys)
    lines = [x for x in out.splitlines() if x.startswith("deploy-run: error:")]
    assert code == 3 and len(lines) == 1 and match in lines[0], out
    assert not (tmp_path / "r.json").exists()


def test_the_running_ramp_holds_home_until_the_env_leaves_running():
    """RampIn with ``running`` (the policy-off hold): the RUNNING envs' targets go along the line
    to home and stay there past the ramp's end; an env that stops (a fall) is let go."""
    from sim2real.deploy.core.modes import RUNNING, SAFE_STOP
    from sim2real.deploy.runtime.handover import RampIn

    start, home = np.array([[1.0, -1.0], [1.0, -1.0]]), np.zeros(2)
    ramp = RampIn(start, home, np.array([True, True]), ticks=2, running=True)
    mode = np.full(2, RUNNING, dtype=np.int8)
    target = np.full((2, 2), 9.0)
    assert not ramp.shape(target, mode)
    np.testing.assert_allclose(target, 0.5 * start)
    for _ in range(5):  # past its 2 ticks: home, held
        target[:] = 9.0
        assert not ramp.shape(target, mode)
        np.testing.assert_allclose(target, 0.0)
    mode[:] = SAFE_STOP
    target[:] = 9.0
    assert ramp.shape(target, mode) and (target == 9.0).all()


def _clip(tmp_path, root_xy: np.ndarray, yaw: float = 0.0) -> MotionClip:
    frames = len(root_xy)
    half = 0.5 * yaw
    return MotionClip(
        source=tmp_path / "c.csv", fps=10.0, joint_names=("a", "b", "c"),
        joint_pos=np.zeros((frames, 3)), joint_vel=np.zeros((frames, 3)),
        root_pos=np.hstack([root_xy, np.full((frames, 1), 0.8)]),
        root_quat=np.tile([math.cos(half), 0.0, 0.0, math.sin(half)], (frames, 1)),
    )  # fmt: skip


def test_the_clip_root_path_is_laid_from_where_and_how_the_base_starts(tmp_path):
    """A clip whose root walks 1 m along its x, started by a base at (1, 2) facing +y: its path
    ends at (1, 3); a base that went there is on it, one that stayed 1 m off; what the base did
    after the clip's end is the after-clip travel."""
    clip = _clip(tmp_path, np.stack([np.linspace(0, 1, 11), np.zeros(11)], axis=1), yaw=0.3)
    clock = MotionClock(clip, ("a", "b", "c"), ("a", "b", "c"), 2, "once")
    travel = ClipTravel(clock, 2)
    travel.update(np.array([[1.0, 2.0], [1.0, 2.0]]), np.full(2, 0.3 + math.pi / 2), 0.1)
    travel.begin(np.array([True, True]))
    np.testing.assert_allclose(travel.expected(0, clock.length), [1.0, 3.0], atol=1e-9)
    travel.update(np.array([[1.0, 3.0], [1.0, 2.0]]), np.full(2, 0.3 + math.pi / 2), 0.1)
    travel.reach(np.full(2, clock.length), np.array([True, True]))
    on, off = travel.figures(0), travel.figures(1)
    assert on["clip_end_offset_m"] == pytest.approx(0.0, abs=1e-9) and not on["off_path"]
    assert off["end_offset_m"] == pytest.approx(1.0) and off["off_path"]
    assert on["clip_root_travel_m"] == pytest.approx(1.0) and on["base_travel_m"] == 1.0
    # after the clip: env 0 walks 0.6 m on and turns a full circle in steps (unwrapped)
    for k in range(1, 9):
        travel.update(
            np.array([[1.0, 3.0 + 0.075 * k], [1.0, 2.0]]),
            np.full(2, 0.3 + math.pi / 2 + k * math.pi / 4), 0.1,
        )  # fmt: skip
    after = travel.figures(0)
    assert after["after_clip_travel_m"] == pytest.approx(0.6)
    assert after["after_clip_turn_deg"] == pytest.approx(360.0)
    assert after["after_clip_s"] == pytest.approx(0.8) and after["off_path"]


def _play(clip_m: float, end_offset: float, rest_m: float | None, iv: int, rest_iv: int) -> dict:
    rest = rest_m is not None
    return {
        "stopped": False, "interventions": iv, "rest_interventions": rest_iv,
        "travel": {
            "base_travel_m": clip_m, "clip_end_offset_m": end_offset,
            "after_clip_s": 12.0 if rest else None,
            "after_clip_travel_m": rest_m, "after_clip_max_m": rest_m,
            "end_offset_m": end_offset + (rest_m or 0.0),
            "off_path": end_offset + (rest_m or 0.0) > OFF_PATH_M or (rest and rest_m > 0.5),
        },
    }  # fmt: skip


def test_an_exhibitions_rests_are_judged_apart_from_its_clips():
    """A session whose clips stay on their spot but whose rests carry the robot away: the
    rests' travel and guard ticks are counted apart from the clips', the plays that left their
    spot are named, and the soak's ``on_spot`` check fails with exit code 10."""
    from sim2real.eval.cli import EXIT_LEFT_SPOT, exit_code
    from sim2real.eval.report.build import on_spot_check
    from sim2real.eval.soak.exhibition import clips_and_rests

    plays = [
        _play(0.1, 0.05, 15.0, 20, 300),
        _play(0.2, 0.1, 14.0, 25, 310),
        _play(0.1, 0.1, None, 5, 0),
    ]
    x = clips_and_rests(plays)
    assert x["clips"] == {"travel_m": pytest.approx(0.4), "worst_end_offset_m": 0.1,
                          "interventions": 50, "hard_limit_ticks": 0, "violation_ticks": 0}  # fmt: skip
    assert x["rests"]["count"] == 2 and x["rests"]["travel_m"] == pytest.approx(29.0)
    assert x["rests"]["worst_travel_m"] == 15.0 and x["rests"]["interventions"] == 610
    assert x["left_spot"] == [1, 2]
    passed, message = on_spot_check({"exhibition": {"clips_and_rests": x}})
    assert not passed and "plays [1, 2]" in message and "rests: 2, travel 29.00 m" in message
    report = {"checks": {"on_spot": {"passed": False, "failed_sessions": ["seed0000"]}}}
    assert exit_code(report) == EXIT_LEFT_SPOT
    still = clips_and_rests([_play(0.1, 0.05, 0.1, 20, 3), _play(0.1, 0.05, 0.05, 20, 3)])
    assert still["left_spot"] == [] and on_spot_check({"exhibition": {"clips_and_rests": still}})[0]
    assert on_spot_check({"exhibition": None}) == (True, "no motion clip: not judged")


def test_an_exhibition_on_the_rig_logs_each_plays_travel_and_rest(go2, go2_onnx, tmp_path):
    """The tracking task's exhibition on the go2 (clip 0.3 s, 0.2 s to home, 0.2 s standing):
    each play logged carries its travel, its rest's (from where its clip ended) and the rest's
    guard ticks apart; the walker standing at a zero command stays on its spot."""
    from sim2real.eval.soak.exhibition import clips_and_rests
    from tests.test_tracking_resume import _rig, _run

    rig = _rig(go2, go2_onnx, tmp_path)
    _run(rig, 300)
    plays = rig.task.plays(0)
    assert len(plays) >= 3
    for p in plays[:-1]:
        assert {"hard_limit_ticks", "violation_ticks", "rest_hard_limit_ticks"} <= set(p)
        f = p["travel"]
        assert f["after_clip_s"] == pytest.approx(0.4, abs=0.03)  # 0.2 s to home + 0.2 s rest
        assert f["after_clip_travel_m"] is not None and "rest_interventions" in p
    x = clips_and_rests(plays)
    assert x["rests"]["count"] >= 2 and x["left_spot"] == []
    total = rig.violations.any[0]  # every tick with a violation is a clip's, a rest's or before
    assert x["clips"]["violation_ticks"] + x["rests"]["violation_ticks"] <= total
    assert x["rests"]["travel_m"] < 0.5 and x["clips"]["travel_m"] < 0.5


def test_a_fall_in_a_rest_is_counted_apart_from_a_fall_in_a_clip():
    """A clip played to its end whose robot fell in the rest after it is a completed clip and
    a rest fall; a fall during a clip is neither; the exhibition line says how many fell in
    the rests."""
    from sim2real.eval.report.summary import exhibition_lines
    from sim2real.eval.soak.exhibition import clips_and_rests, heat_report

    def play(stopped, in_rest, completed):
        return {**_play(0.1, 0.05, 0.2 if in_rest else None, 10, 5), "stopped": stopped,
                "stopped_in_rest": in_rest, "completed": completed, "joint_rms_rad": 0.09}  # fmt: skip

    plays = [play(False, False, 1.0), play(True, True, 1.0), play(True, False, 0.4)]
    h = heat_report(plays)
    assert (h["completed"], h["falls"], h["rest_falls"]) == (2, 2, 1)
    x = {"clip_s": 38.8, "stand_s": 2.0, "rest_s": 10.0, "clips": plays, "heat": h,
         "reference_contacts": {"frames_touching": 0}, "clips_and_rests": clips_and_rests(plays)}  # fmt: skip
    lines = exhibition_lines({"id": "seed0000", "exhibition": x})
    assert "completed 2, falls 2 (1 in the rests after their clips)" in lines[0]
    assert any(line.startswith("  clips/rests  clips: base travel 0.30 m") for line in lines)
