"""An exhibition soak's hard-limit ticks and interventions judged against the policy's own loop on
the same clip (:mod:`sim2real.eval.soak.own_loop_limits`): the stack is blamed only for ticks past
what the own loop has, joint by joint, and a policy with no own loop is judged as before."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from sim2real.eval.report.schema import Thresholds
from sim2real.eval.soak.own_loop_limits import (
    MARGIN,
    SIGMAS,
    GuardReplay,
    allowance,
    judge_hard_limits,
    judge_interventions,
    judge_run,
    own_loop_reference,
)
from sim2real.eval.soak.session import SessionConfig
from sim2real.stacks.loops.rl_sar_pushed import rl_sar_folder

OWN = {
    "compared": True,
    "plays": 3,
    "falls": 0,
    "clip_s": 100.0,  # s of clip played in the own loop
    "ticks": 5000,
    "hard_limit_ticks": 120,
    "hard_limit_joints": {"right_ankle_roll_joint": 100, "left_ankle_roll_joint": 20},
    "guard_checks": {"pd_barrier": 50, "target_clamp": 400},
    "guard_patterns": [[[], 4550], [["pd_barrier"], 50], [["target_clamp"], 400]],
    "guard_ticks": 450,
}


def _session(joints: dict, down: int = 0, stops: int = 0, share: float = 0.001) -> dict:
    """A session result with 1,000 s of clip played (50,000 judged ticks at 50 Hz)."""
    return {
        "simulated_s": 1200.0,
        "ticks": 60000,
        "exhibition": {"clips": [{"ticks": 25000}, {"ticks": 25000}], "clip_s": 35.0},
        "violations": {
            "total": {"hard_limit": sum(joints.values())},
            "hard_limit_joints": joints,
            "while_down": {"hard_limit": down},
        },
        "runtime": {"by_cause": {"hard_limit": stops} if stops else {}},
        "interventions": {
            "any": {"fraction": share},
            "safety": {"fraction": share},
            "by_design": ["target_clamp"],
            "checks": {},
        },
    }


def test_the_allowance_is_the_own_loops_rate_plus_ten_percent_and_three_sigma():
    """1 tick/s over 100 s: 100 expected, 110 + 3 x 10 = 140 allowed; none expected: none."""
    assert allowance(1.0, 100.0) == pytest.approx((1 + MARGIN) * 100 + SIGMAS * 10)
    assert allowance(1.0, 100.0) == pytest.approx(140.0)
    assert allowance(0.0, 1000.0) == 0.0


def test_only_the_ticks_past_the_own_loops_are_the_stacks():
    """The own loop's right ankle roll crosses 1 tick/s: 1,000 expected in 1,000 s of clip, and
    1,194.9 allowed; 1,150 pass. Its left ankle roll 0.2/s: 200 expected, 262.4 allowed, 300
    are 38 too many. A knee the own loop never crosses: every tick is the stack's."""
    ok, message, fig = judge_hard_limits(
        _session({"right_ankle_roll_joint": 1150, "left_ankle_roll_joint": 100}), OWN
    )
    assert ok, message
    assert fig["joints"]["right_ankle_roll_joint"]["allowed"] == pytest.approx(
        1.1 * 1000 + 3 * math.sqrt(1000), abs=0.1
    )
    assert fig["clip_s"] == pytest.approx(1000.0)
    assert "the stack's (past the allowance): 0" in message
    ok, message, fig = judge_hard_limits(
        _session({"left_ankle_roll_joint": 300, "left_knee_joint": 2}), OWN
    )
    assert not ok
    assert fig["joints"]["left_ankle_roll_joint"]["stack"] == 38
    assert fig["joints"]["left_knee_joint"] == {"ours": 2, "own": 0, "allowed": 0.0, "stack": 2}
    assert fig["stack_ticks"] == 40
    assert "left_knee_joint 2 (own 0, allowed 0)" in message


def test_ticks_lying_down_and_hard_limit_stops_still_fail():
    """Within the allowance on every joint, a tick lying down after a stop or a hard-limit safe
    stop still fails the check (the own loop is not asked about them)."""
    assert not judge_hard_limits(_session({"right_ankle_roll_joint": 10}, down=1), OWN)[0]
    assert not judge_hard_limits(_session({"right_ankle_roll_joint": 10}, stops=1), OWN)[0]
    assert judge_hard_limits(_session({"right_ankle_roll_joint": 10}), OWN)[0]


def test_interventions_against_the_guard_replayed_on_the_own_loop():
    """The own loop's replayed guard changes 1 % of its ticks by a check the session judges
    (pd_barrier; target_clamp is the policy's style): the session may have 1.1 %."""
    ok, message, fig = judge_interventions(_session({}, share=0.0105), OWN, 0.005)
    assert ok, message
    assert fig["own"] == pytest.approx(0.01)
    assert fig["allowed"] == pytest.approx(0.011)
    assert not judge_interventions(_session({}, share=0.0115), OWN, 0.005)[0]
    assert judge_interventions(_session({}, share=0.0115), OWN, 0.02)[0]  # the threshold


def test_the_report_judges_a_clip_session_against_the_own_loop():
    """A session's no_hard_violation fails on 900 right ankle roll ticks alone, and passes
    judged against an own loop that has them too (build_report's ``own_loop_checks``)."""
    result = _session({"right_ankle_roll_joint": 900})
    result.update(
        id="seed0000",
        seed=0,
        status="complete",
        diverged=False,
        thermal={"joints": ["j"], "peak_c": {"j": 40.0}, "max_winding_c": {"j": 120.0}},
        goals={"success_rate": 1.0, "min_window_success_rate": 1.0, "reached": 1, "issued": 1,
               "windows": [], "window_s": 600.0},
    )  # fmt: skip
    result["runtime"].update(latched_faults=0, latches=[])
    from sim2real.eval.report import build

    checks = build.session_checks(dict(result), Thresholds())
    assert not checks["no_hard_violation"]["passed"]
    r = dict(result)
    r["checks"] = checks
    figures = build.own_loop_checks(r, OWN, Thresholds())
    assert r["checks"]["no_hard_violation"]["passed"], r["checks"]["no_hard_violation"]
    assert figures["hard_limits"]["joints"]["right_ankle_roll_joint"]["own"] == 100


def test_a_policy_with_no_own_loop_is_not_compared(tmp_path):
    """An ONNX outside an rl_sar whole_body_tracking folder, another clip (--motion) or 0 plays:
    not compared, and the reason says which."""
    onnx = tmp_path / "dance.onnx"
    onnx.write_bytes(b"")
    t = SessionConfig(robot="go2", policy=str(onnx), seed=0, hours=0.1)
    own = own_loop_reference(t, 3)
    assert not own["compared"] and "no stack's own tracking loop plays it" in own["why"]
    assert "another clip" in own_loop_reference(SessionConfig(
        robot="go2", policy=str(onnx), seed=0, hours=0.1, motion="x.csv"), 3)["why"]  # fmt: skip
    assert own_loop_reference(t, 0)["why"] == "--own-loop-plays 0"


def test_an_rl_sar_tracking_folder_is_found_beside_its_onnx(tmp_path):
    """policy/g1/whole_body_tracking/<name>/policy.onnx with config.yaml, policy.pt and
    base.yaml two levels up, as rl_sar lays it; a folder missing one is not."""
    folder = tmp_path / "policy" / "g1" / "whole_body_tracking" / "dance"
    folder.mkdir(parents=True)
    for name in ("config.yaml", "policy.pt", "policy.onnx"):
        (folder / name).write_text("")
    assert rl_sar_folder(folder / "policy.onnx") is None  # no base.yaml
    (tmp_path / "policy" / "g1" / "base.yaml").write_text("")
    assert rl_sar_folder(folder / "policy.onnx") == folder.resolve()
    (folder / "policy.pt").unlink()
    assert rl_sar_folder(folder / "policy.onnx") is None


def test_the_replayed_guard_counts_a_joint_past_its_limit_and_its_change():
    """On the Go2's plant, a calf 0.05 rad past its lower limit and the policy asking 0.1 rad
    farther: the tick counts for that joint alone, and the guard would have changed the target
    (the target is not applied: the replay only watches)."""
    from sim2real.robots import load_robot

    robot = load_robot("go2")
    replay = GuardReplay(robot)
    m = robot.plant_model("torque")
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_offset :] = robot.home
    d.qpos[2] = 0.3
    mujoco.mj_forward(m, d)
    target = np.array(robot.home, dtype=float)
    replay(d, target)  # at home: nothing
    assert replay.ticks == 1 and replay.past_ticks == 0 and not replay.checks
    j = robot.joint_names.index("FR_calf_joint")
    d.qpos[robot.qpos_offset + j] = robot.position_lower[j] - 0.05
    mujoco.mj_forward(m, d)
    target[j] = robot.position_lower[j] - 0.15
    before = target.copy()
    replay(d, target)
    assert replay.past_ticks == 1 and replay.joint_ticks[j] == 1 and replay.joint_ticks.sum() == 1
    assert sum(replay.checks.values()) >= 1
    np.testing.assert_array_equal(target, before)


def test_soak_test_refuses_a_negative_own_loop_play_count_in_one_line(go2_onnx, tmp_path, capsys):
    """--own-loop-plays -1: exit 3, one line naming the flag, nothing written."""
    from sim2real.eval.cli import main as soak_main

    out = tmp_path / "soak"
    argv = ["--robot", "go2", "--policy", str(go2_onnx), "--hours", "0.01", "--out", str(out)]
    assert soak_main([*argv, "--own-loop-plays", "-1"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["soak-test: error: --own-loop-plays: expected a number >= 0, got -1"]
    assert not out.exists()


def test_the_replayed_watch_counts_a_self_collision_tick_and_its_pairs():
    """On the Go2's plant, the front left leg folded back into the rear left thigh (thigh 2.11,
    calf -1.107 rad): the watch counts one self-collision tick, on the pairs the violation
    monitor's collision model names; at home none."""
    from sim2real.robots import load_robot

    robot = load_robot("go2")
    replay = GuardReplay(robot)
    m = robot.plant_model("torque")
    d = mujoco.MjData(m)
    d.qpos[robot.qpos_offset :] = robot.home
    d.qpos[2] = 0.3
    target = np.array(robot.home, dtype=float)
    replay(d, target)
    assert replay.collision_ticks == 0 and not replay.pair_ticks.any()
    j = robot.joint_names.index("FL_thigh_joint")
    d.qpos[robot.qpos_offset + j : robot.qpos_offset + j + 2] = (2.11, -1.107)
    replay(d, target)
    touching = {replay.pair_names[k] for k in np.flatnonzero(replay.pair_ticks)}
    assert replay.collision_ticks == 1 and touching == {"FL_calf|RL_thigh", "FL_foot|RL_thigh"}


OWN_RUN = {
    "compared": True,
    "clip_s": 18.0,
    "plays": 1,
    "falls": 0,
    "hard_limit_ticks": 0,
    "hard_limit_joints": {},
    "self_collision_ticks": 140,
    "self_collision_pairs": {"torso_link_0|left_elbow_link": 90},
}


def _violations(collided: int, joints: dict) -> dict:
    """A deploy-run report's ``violations`` (true state, while up)."""
    return {
        "by_type": {"hard_limit": max(joints.values(), default=0), "self_collision": collided},
        "hard_limit_joints": {j: {"ticks": n, "depth_rad": 0.001} for j, n in joints.items()},
        "while_down": {},
    }


def test_a_tracking_runs_self_collision_is_judged_against_its_own_loops():
    """The own loop touches on 140 ticks in 18 s: a run of the same 18 s may touch on
    1.1 x 140 + 3 sqrt(140) = 189.5 ticks; 126 pass, 200 are 11 the stack's. A hard-limit tick on
    a joint the own loop never crosses is the stack's (allowed 0)."""
    v = judge_run(_violations(126, {}), OWN_RUN, 18.0)
    sc = v["self_collision"]
    assert sc["passed"] and sc["ours"] == 126 and sc["own"] == 140
    assert sc["allowed"] == pytest.approx(1.1 * 140 + 3 * math.sqrt(140), abs=0.1)
    assert v["hard_limit"]["passed"] and v["hard_limit"]["ours"] == 0
    v = judge_run(_violations(200, {"right_ankle_roll_joint": 1}), OWN_RUN, 18.0)
    assert not v["self_collision"]["passed"] and v["self_collision"]["stack"] == 11
    assert not v["hard_limit"]["passed"] and v["hard_limit"]["stack"] == 1
    half = judge_run(_violations(126, {}), OWN_RUN, 9.0)  # half the motion: half the allowance
    assert not half["self_collision"]["passed"]


def test_deploy_runs_exit_code_fails_only_on_ticks_past_the_own_loops():
    """exit_code: self-collision ticks within the own loop's allowance do not fail the run (they
    are listed as within it); past it, or lying down after a stop, they do (exit 1)."""
    from types import SimpleNamespace

    from sim2real.deploy.cli.run_verdict import EXIT_CLEAN, EXIT_HARD_VIOLATION, exit_code

    rig = SimpleNamespace(true_falls=lambda: 0)

    def report(collided, down=0):
        v = _violations(collided, {})
        v["any"], v["while_down"] = collided, {"self_collision": down} if down else {}
        verdict = judge_run(v, OWN_RUN, 18.0)
        return {
            "violations": v,
            "diverged": None,
            "faults": {"by_cause": {"hard_limit": 0}},
            "final_state": ["RUNNING"],
            "final_cause": [None],
            "own_loop": {"compared": True, "verdict": verdict},
        }

    r = report(126)
    assert exit_code(r, rig) == EXIT_CLEAN
    assert r["within_own_loop"] == {"self_collision": 126} and r["hard_violations"] == {}
    r = report(200)
    assert exit_code(r, rig) == EXIT_HARD_VIOLATION and r["hard_violations"] == {
        "self_collision": 200
    }
    assert exit_code(report(126, down=3), rig) == EXIT_HARD_VIOLATION


def test_the_tracking_loop_is_the_stack_registrys_face(tmp_path):
    """An rl_sar whole_body_tracking folder is rl_sar's loop, an rl_sar robomimic folder
    (config.yaml, its module, base.yaml two up) RoboMimic_Deploy's Dance; a file elsewhere has
    none."""
    from sim2real.eval.soak.own_loop_limits import own_tracking_loop
    from tests.robomimic_files import write_robomimic_folder

    folder = tmp_path / "policy" / "g1" / "whole_body_tracking" / "dance"
    folder.mkdir(parents=True)
    for name in ("config.yaml", "policy.pt"):
        (folder / name).write_text("")
    (tmp_path / "policy" / "g1" / "base.yaml").write_text("")
    stack, loop, found = own_tracking_loop(folder / "policy.onnx")
    assert (stack, found) == ("rl_sar", folder.resolve()) and "whole_body_tracking" in loop.what
    dance = write_robomimic_folder(tmp_path / "rm")
    stack, loop, found = own_tracking_loop(dance / "dance.onnx")
    assert (stack, found) == ("robomimic", dance.resolve()) and "Dance" in loop.what
    assert own_tracking_loop(tmp_path / "elsewhere.onnx") is None


def test_robomimics_dance_config_is_read_from_the_rl_sar_folder(tmp_path):
    """folder_dance: the gains, default angles and scales of config.yaml, T from rl_sar's fsm
    (18 s for charleston's key), RoboMimic's 23 joints; the inner network answers 380 -> 23."""
    from sim2real.stacks.loops.robomimic_dance import folder_dance
    from tests.robomimic_files import write_robomimic_folder

    cfg, joints, net = folder_dance(write_robomimic_folder(tmp_path))
    assert cfg["motion_length"] == 18.0 and len(cfg["kps"]) == 29 and len(joints) == 29
    assert cfg["dof23_index"] == list(range(19)) + [22, 23, 24, 25]
    assert net(np.zeros((1, 380), np.float32)).shape == (1, 23)


def test_deploy_run_refuses_a_negative_own_loop_play_count_in_one_line(capsys):
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    assert deploy_run_main(["--robot", "go2", "--own-loop-plays", "-1"]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--own-loop-plays" in err[0] and "expected an integer >= 0" in err[0]


def test_without_pushes_the_own_loops_plays_go_back_to_back(monkeypatch):
    """No pushes: the own loop is deterministic from its rest, so its N plays are one call of N
    plays back to back (the clip again where the last left the robot); with pushes, N plays from
    rest, seeds seed .. seed + N - 1."""
    from types import SimpleNamespace

    from sim2real.deploy.core.stacks import TrackingLoop
    from sim2real.eval.soak import own_loop_limits
    from sim2real.robots import load_robot
    from sim2real.stacks.loops.bare import Run

    calls = []

    def play(robot, folder, seed, seconds, pushes, watch, repeat=1):
        calls.append((seed, repeat))
        return Run(walked=35.0 * repeat)

    loop = TrackingLoop("a made-up loop", lambda p: p, play)
    monkeypatch.setattr(own_loop_limits, "own_tracking_loop", lambda p: ("made_up", loop, "f"))
    robot = load_robot("go2")
    own = own_loop_limits.play_reference(robot, "x.onnx", 3, seed=7)
    assert calls == [(7, 3)] and own["clip_s"] == 105.0 and own["plays"] == 3
    calls.clear()
    pushes = SimpleNamespace(describe=lambda: "pushes")
    own = own_loop_limits.play_reference(robot, "x.onnx", 3, seed=7, pushes=pushes)
    assert calls == [(7, 1), (8, 1), (9, 1)] and own["clip_s"] == 105.0


def test_deploy_run_asks_its_own_loop_only_for_ticks_to_judge_and_as_many_plays(monkeypatch):
    """own_loop_verdict: no hard-limit or self-collision tick, or --own-loop-plays 0: nothing
    played; --motion another clip: not compared, said why; a clip played 5 times by 1 env: 5 plays
    back to back in the own loop, judged over the run's s of clip."""
    from types import SimpleNamespace

    from sim2real.deploy.cli import own_loop_check
    from sim2real.eval.soak import own_loop_limits

    asked = []

    def reference(robot, policy, plays):
        asked.append(plays)
        scaled = {"clip_s": 18.0 * plays, "self_collision_ticks": 140 * plays}
        return {**OWN_RUN, "stack": "made_up", "loop": "a loop", **scaled}

    monkeypatch.setattr(own_loop_limits, "play_reference", reference)
    rig = SimpleNamespace(robot=SimpleNamespace(control_period=0.02))
    args = SimpleNamespace(own_loop_plays=1, motion=None, policies={"p": "p.onnx"})

    def report(collided, plays=1):
        v = _violations(collided, {})
        return {"violations": v, "policy": "p.onnx", "envs": 1,
                "tracking": {"ticks": 900 * plays, "plays": plays}}  # fmt: skip

    assert own_loop_check.own_loop_verdict(args, rig, report(0)) is None and not asked
    off = SimpleNamespace(**{**vars(args), "own_loop_plays": 0})
    assert own_loop_check.own_loop_verdict(off, rig, report(10)) is None and not asked
    other = SimpleNamespace(**{**vars(args), "motion": "x.csv"})
    assert "another clip" in own_loop_check.own_loop_verdict(other, rig, report(10))["why"]
    judged = own_loop_check.own_loop_verdict(args, rig, report(600, plays=5))
    assert asked == [5] and judged["clip_s"] == pytest.approx(90.0)
    assert judged["verdict"]["self_collision"]["passed"]  # 600 in 90 s against 700 in 90 s
    lines = own_loop_check.own_loop_lines(judged)
    assert lines[2].startswith("  own loop self_collision  ticks ours 600 over 90.0 s")
