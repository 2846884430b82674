"""The soak's legged mode: go2 follows seeded velocity commands
(:class:`sim2real.deploy.tasks.commands.CommandSchedule`), its tracking, falls and distance are measured
(:class:`sim2real.deploy.tasks.locomotion.CommandTracker`) and reported, and a kill -9 + resume equals an
uninterrupted run."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from sim2real.deploy.tasks.commands import CommandSchedule
from sim2real.deploy.tasks.locomotion import CommandTracker
from sim2real.eval.report.build import build_report
from sim2real.eval.soak import checkpoint as ckpt
from sim2real.eval.soak.batch import SessionBatch
from sim2real.eval.soak.campaign import run_campaign
from sim2real.eval.soak.session import session_dir
from sim2real.eval.world.fault_schedule import fault_ranges
from sim2real.eval.world.session_draw import sample_session
from sim2real.eval.world.session_ranges import SessionRanges, session_ranges
from tests.soak_fixtures import kill_after_first_checkpoint, short_session

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def config(go2_onnx, go2):
    """36 s of go2 with faults every ~10 s (pushes on the base among them), checkpoints every
    12 s, on legged_gym's heading commands (a heading's yaw rate computed every tick from the
    estimate: the checkpoint must carry the schedule's headings)."""
    from sim2real.deploy.tasks.commands import CommandRanges

    ranges = replace(session_ranges(go2, 10.0), commands=CommandRanges(heading_command=True))
    return short_session("go2", go2_onnx, 0.01, checkpoint_minutes=0.2, ranges=ranges)


def seeded(result: dict) -> dict:
    return {k: v for k, v in result.items() if k != "wall"}


def test_a_legged_session_draws_imu_floor_friction_and_no_cable(go2):
    draw = sample_session(go2, 3, 3600.0, SessionRanges(faults=fault_ranges(go2, 30.0)))
    assert draw.imu is not None and 0.5 <= draw.floor_friction <= 1.25
    kinds = {f.kind for f in draw.faults}
    assert "cable" not in kinds and "push" in kinds
    pushes = [f.magnitude for f in draw.faults if f.kind == "push"]
    assert all(6.4 <= p <= 32.0 for p in pushes)  # go2's [soak] push_force
    doc = draw.to_dict()
    assert type(draw).from_dict(doc) == draw and "imu" in doc and "floor_friction" in doc


def test_command_schedule_and_tracker_state_round_trip():
    class Rt:
        def __init__(self):
            self.mode = np.array([2, 2])
            self.time, self.ticks = 0.0, 0
            self.velocity_command = np.zeros((2, 3))
            self.counters = type("C", (), {"faults": {"fall": np.zeros(2, dtype=np.int64)}})

    class Backend:
        def __init__(self):
            self.rng = np.random.default_rng(1)

        def true_base_state(self):
            s = np.zeros((2, 13))
            s[:, 3] = 1.0
            s[:, 7:9] = 0.3 + 0.05 * self.rng.standard_normal((2, 2))
            return s

    def run(schedule, tracker, rt, ticks):
        for _ in range(ticks):
            rt.ticks += 1
            rt.time = rt.ticks * 0.02
            schedule(rt)
            tracker(rt)

    def make():
        streams = [np.random.default_rng([s, 5]) for s in (0, 1)]
        return CommandSchedule(2, 1.0, streams), CommandTracker(2, 0.02, Backend(), window=2.0)

    a_s, a_t = make()
    rt_a = Rt()
    run(a_s, a_t, rt_a, 300)
    b_s, b_t = make()
    rt_b = Rt()
    run(b_s, b_t, rt_b, 130)
    c_s, c_t = make()
    c_t.truth = b_t.truth  # the same plant
    for e in (0, 1):  # one env at a time, as a session's checkpoint
        c_s.load_state_dict(b_s.state_dict(e), e)
        c_t.load_state_dict(b_t.state_dict(e), e)
    rt_c = Rt()
    rt_c.ticks, rt_c.time = rt_b.ticks, rt_b.time
    rt_c.velocity_command[:] = rt_b.velocity_command
    run(c_s, c_t, rt_c, 170)
    assert a_s.issued.tolist() == c_s.issued.tolist() and (a_s.issued >= 5).all()
    np.testing.assert_array_equal(a_s.command, c_s.command)
    np.testing.assert_array_equal(a_t.tracked_time, c_t.tracked_time)
    np.testing.assert_array_equal(a_t.distance, c_t.distance)
    assert a_t.windows(0, rt_a.time) == c_t.windows(0, rt_c.time)
    assert len(a_t.windows(0, rt_a.time)) == 3


def test_a_robot_that_follows_each_command_step_at_once_tracks_all_of_its_running_time():
    """The tracked velocity is averaged over TRACKING_WINDOW; so is the command it is judged
    against, so the window's own lag after a command step is not counted as the robot's error."""

    class Rt:
        def __init__(self):
            self.mode = np.array([2, 2])  # RUNNING
            self.time, self.ticks = 0.0, 0
            self.velocity_command = np.zeros((2, 3))

    rt = Rt()

    class Follower:  # the true base moves at the command of this very tick (base frame)
        def true_base_state(self):
            s = np.zeros((2, 13))
            s[:, 3] = 1.0
            s[:, 7:9] = rt.velocity_command[:, :2]
            return s

    streams = [np.random.default_rng([s, 9]) for s in (0, 1)]
    schedule, tracker = CommandSchedule(2, 1.0, streams), CommandTracker(2, 0.02, Follower())
    largest_step = np.zeros(2)
    for _ in range(1000):  # 20 s, a new command every second
        rt.ticks += 1
        rt.time = rt.ticks * 0.02
        before = rt.velocity_command[:, :2].copy()
        schedule(rt)
        step = np.linalg.norm(rt.velocity_command[:, :2] - before, axis=1)
        largest_step = np.maximum(largest_step, step)
        tracker(rt)
    assert (schedule.issued >= 15).all()
    assert (largest_step > 0.3).all()  # steps beyond the tolerance: a lagging judge fails them
    settled = tracker.running_time - (tracker.window - 1) * 0.02  # the first window fills
    np.testing.assert_allclose(tracker.tracked_time, settled, atol=1e-9)


def test_a_short_go2_soak_reports_falls_tracking_and_distance(go2_onnx, tmp_path, capsys):
    from sim2real.eval.cli import main

    out = tmp_path / "soak"
    code = main(
        [
            "--robot",
            "go2",
            "--policy",
            str(go2_onnx),
            "--hours",
            "0.02",
            "--sessions",
            "1",
            "--seed",
            "0",
            "--out",
            str(out),
            "--no-progress",
            "--no-film",
            "--fault-interval",
            "20",
        ]
    )
    text = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    assert report["exit_code"] == code
    s = report["sessions"][0]
    loco = s["locomotion"]
    assert s["goals"] is None and s["simulated_s"] == pytest.approx(72.0)
    for key in ("falls", "falls_per_hour", "tracking_success", "distance_m"):
        assert key in loco
    assert loco["running_s"] > 0 and loco["distance_m"] > 0 and loco["commands_issued"] > 1
    assert 0.0 <= loco["tracking_success"] <= 1.0
    assert loco["falls_per_hour"] == pytest.approx(loco["falls"] / 0.02)
    assert set(loco["peak_winding_c"]) == {"hip", "thigh", "calf"}
    assert "floor_friction" in s["randomization"] and "imu" in s["randomization"]
    assert all(e["kind"] != "cable" for e in s["faults"]["events"])
    assert "falls" in s["checks"] and "falls" in report["checks"]
    assert report["totals"]["locomotion"]["falls"] == loco["falls"]
    # the base estimate against the plant's truth, per session and in the totals
    est = s["base_estimate"]
    assert est["ticks"] > 0.9 * loco["running_s"] / 0.02  # every RUNNING tick (50 Hz)
    assert est["attitude_error_deg"]["mean"] < 2.0 and est["velocity_rms_m_s"] < 0.2, est
    assert abs(est["vertical_velocity_m_s"]["bias"]) < 0.1, est
    assert report["totals"]["base_estimate"]["ticks"] == est["ticks"]
    assert "base estimate vs truth" in text
    assert "locomotion   falls" in text
    assert "Locomotion" in (out / "report.html").read_text()


def test_a_soak_refused_for_its_clip_writes_nothing_and_removes_no_earlier_session(
    go2_onnx, tmp_path, capsys
):
    """A clip the policy cannot play (here: the walker reads none) is refused in one line, exit
    3, before the campaign writes: a fresh --out gets no empty ``sessions/`` folder, and an
    earlier campaign's session in another --out is not removed (it was, before the refusal)."""
    from sim2real.eval.cli import main

    clip = tmp_path / "clip.csv"
    clip.write_text("0,0,0\n")
    earlier = tmp_path / "earlier" / "sessions" / "seed0000" / "result.json"
    earlier.parent.mkdir(parents=True)
    earlier.write_text("{}")
    for out in (tmp_path / "fresh", tmp_path / "earlier"):
        argv = ["--robot", "go2", "--policy", str(go2_onnx), "--hours", "0.001", "--sessions"]
        argv += ["1", "--out", str(out), "--no-progress", "--no-film", "--no-domain"]
        assert main([*argv, "--motion", str(clip)]) == 3
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [
            f"soak-test: error: {clip}: --motion: the policy's observation reads no clip"
        ]
    assert not (tmp_path / "fresh").exists()
    assert earlier.read_text() == "{}"


# The tests reading the module fixture go2_uninterrupted: on one pytest-xdist worker (make test's
# --dist loadgroup), which builds it once, not once per worker.
ON_ONE_WORKER = pytest.mark.xdist_group("go2_uninterrupted")


@pytest.fixture(scope="module")
def uninterrupted(config, tmp_path_factory):
    out = tmp_path_factory.mktemp("legged_whole")
    return SessionBatch([config], out, progress=False).run()[0]


@ON_ONE_WORKER
def test_kill_and_resume_of_a_go2_session_equals_an_uninterrupted_run(
    config, uninterrupted, tmp_path
):
    out = tmp_path / "campaign"
    kill_after_first_checkpoint(config, out)
    assert not (session_dir(out, 0) / "result.json").exists()
    arrays, meta = ckpt.read_checkpoint(session_dir(out, 0))
    assert 0 < meta["tick"] < 1800
    assert "commands/rng" in arrays and arrays["tracker/ring"].shape == (1, 40, 2)
    assert "commands/heading" in arrays and arrays["tracker/yaw_ring"].shape == (1, 40)
    assert not any(k.startswith("goals/") for k in arrays)
    resumed = run_campaign(replace(config, seed=0), 1, out, resume=True, progress=False)[0]
    assert seeded(resumed) == seeded(uninterrupted)
    assert resumed["locomotion"]["commands_issued"] > 1
    assert resumed["locomotion"]["heading"]["heading_commands_ended"] >= 1
    assert resumed["locomotion"]["yaw_tracking_success"] is not None
    a = build_report({"robot": "go2"}, [resumed])
    b = build_report({"robot": "go2"}, [uninterrupted])
    assert a["totals"] | {"tick_cost_us": None} == b["totals"] | {"tick_cost_us": None}
    shutil.rmtree(out)


def test_robot_import_writes_go2s_soak_table(tmp_path):
    """Regenerating go2 with the command in its robot.toml header gives the shipped file, its
    ``[soak]`` pushes included (the table is the importer's, not a hand edit it would drop)."""
    import shlex

    from sim2real.deploy.cli.robot_import import main

    shipped = (REPO / "sim2real" / "robots" / "go2" / "robot.toml").read_text()
    command = shlex.split(shipped.splitlines()[2].removeprefix("#   "))
    out = tmp_path / "go2"
    command[command.index("--out") + 1] = str(out)
    assert main(command[1:]) == 0
    written = (out / "robot.toml").read_text()
    assert "[soak]\n" in written and "push_force = [6.4, 32.0]  # N" in written
    assert written.replace(str(out), "robots/go2") == shipped


@ON_ONE_WORKER
def test_a_legged_sessions_tracking_is_judged_only_when_the_user_asks(uninterrupted):
    """How closely a policy follows every command is its own quality: reported, not judged,
    unless a threshold is given (soak-test --min-success); falls and violations are judged."""
    import copy

    from sim2real.eval.report.build import session_checks
    from sim2real.eval.report.schema import Thresholds

    result = copy.deepcopy(uninterrupted)
    loco = result["locomotion"]
    loco["tracking_success"] = loco["min_window_success_rate"] = 0.5
    reported = session_checks(result, Thresholds())
    assert reported["success_rate"]["passed"] and reported["window_success"]["passed"]
    assert "0.500 (not judged" in reported["success_rate"]["message"]
    judged = session_checks(result, Thresholds(judge_tracking=True))
    assert not judged["success_rate"]["passed"] and not judged["window_success"]["passed"]
    assert "threshold 0.950" in judged["success_rate"]["message"]
    loco["falls"], loco["falls_per_hour"] = 1, 50.0
    assert not session_checks(result, Thresholds())["falls"]["passed"]


def test_a_stand_up_anchors_the_estimate_where_the_encoders_read(config, tmp_path):
    """The operator's stand-up restarts the runtime at rest where the encoders read the joints
    (the only pose an operator's restart on hardware knows): with an encoder bias, the joint
    estimate starts at home + bias, not at the nominal home (anchored there, a biased G1 fell
    3.3 s after every stand-up)."""
    import dataclasses

    from sim2real.eval.world.sensors import SensorRanges

    ranges = dataclasses.replace(
        config.ranges, sensors=dataclasses.replace(config.ranges.sensors, encoder_bias=(0.01, 0.02))
    )
    biased = replace(config, ranges=ranges, hours=0.002)
    batch = SessionBatch([biased], tmp_path / "soak", progress=False)
    bias = batch.backend.encoder_bias[0].copy()
    assert isinstance(ranges.sensors, SensorRanges) and np.all((bias >= 0.01) & (bias <= 0.02))
    for _ in range(50):
        batch.rt.tick()
    batch.stand_up(np.array([True]))
    np.testing.assert_allclose(batch.rt.state.q[0], batch.robot.home + bias, atol=2e-3)


def test_a_stop_holds_the_command_clock_and_does_not_restart_it():
    """The schedule's clock counts RUNNING time only and is held, not restarted, by a stop
    : a robot that runs 0.8 s between 3-s stops gets a new command every 1.0 s of
    running, not its first draw forever (the clock set to the stop's end made every period
    start again after each stop)."""

    class Rt:
        def __init__(self):
            self.mode = np.array([2])
            self.time, self.ticks = 0.0, 0
            self.velocity_command = np.zeros((1, 3))

    rt = Rt()
    schedule = CommandSchedule(1, 1.0, [np.random.default_rng(3)])
    running = 0.0
    for _ in range(10):  # 0.8 s RUNNING, then 3 s stopped (a fall, a stand-up)
        for mode, seconds in ((2, 0.8), (4, 3.0)):
            for _ in range(round(seconds / 0.02)):
                rt.ticks += 1
                rt.time = rt.ticks * 0.02
                rt.mode[0] = mode
                schedule(rt)
                running += 0.02 * (mode == 2)
    # the first draw at the first RUNNING tick, then one per 1.0 s of RUNNING time (8 s)
    assert schedule.issued[0] == 8, (schedule.issued, running)
    state = schedule.state_dict(0)
    again = CommandSchedule(1, 1.0, [np.random.default_rng(3)])
    again.load_state_dict(state, 0)
    np.testing.assert_array_equal(again.t_seen, schedule.t_seen)
    del state["t_seen"]  # a checkpoint of the code before: loads, nothing moved on at first
    again.load_state_dict(state, 0)
    assert np.isnan(again.t_seen).all()


def test_a_go2w_soak_states_its_wheels_speeds_and_never_their_angle(tmp_path, capsys):
    """The Go2-W (continuous wheels) soaked with a policy of rl_sar's folder layout rolling on
    5 rad/s wheel speed targets: its wheels turn many times over, none is a position violation
    or a hard-limit joint, and the report states each wheel's true peak speed against its
    velocity limit."""
    pytest.importorskip("torch")
    from sim2real.eval.cli import main
    from tests.test_rl_sar_contract import write

    policy = write(tmp_path, bias=[0.0] * 12 + [1.0] * 4)
    out = tmp_path / "soak"
    args = ["--robot", "go2w", "--policy", str(policy), "--hours", "0.004", "--sessions", "1"]
    args += ["--seed", "0", "--out", str(out), "--no-progress", "--no-film"]
    main(args)
    text = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    wheels = report["totals"]["wheels"]
    names = ["FL_wheel_joint", "FR_wheel_joint", "RL_wheel_joint", "RR_wheel_joint"]
    assert wheels["joints"] == names
    peak, limit = wheels["peak_speed_rad_s"], wheels["velocity_limit_rad_s"]
    assert all(2.0 < peak[j] < limit[j] for j in names), wheels  # rolling, within the limit
    assert report["sessions"][0]["wheels"] == wheels
    violations = report["totals"]["violations"]
    # (a leg may pass its stop under the domain's pushes: this policy holds its legs blindly)
    assert not set(violations["hard_limit_joints"]) & set(names), violations
    assert "wheel speeds (true peak of the velocity limit" in text
    assert "FL_wheel_joint" in text.split("wheel speeds", 1)[1].splitlines()[0]
    assert "FL_wheel_joint peak / limit (rad/s)" in (out / "report.html").read_text()
