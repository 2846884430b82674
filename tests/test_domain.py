"""A policy's training domain (legged_gym's config read as text, ranges files with pushes and an
added base mass), the pushes the soak applies, the attribution of falls and the robustness
sweep's margins."""

from __future__ import annotations

import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim2real.eval.soak.falls import ORIGINS, attribute_falls, falls_by_origin, stops_while_falling
from sim2real.eval.soak.sweep import (
    FALL_ALLOWANCE,
    QUANTITIES,
    TOLERANCE,
    margin_text,
    margins,
    session_success,
)
from sim2real.eval.world.domain import DomainError, legged_gym_domain, training_domain
from sim2real.eval.world.pushes import DomainPushes, PushRanges, push_velocity
from sim2real.eval.world.ranges_file import RangesError, load_ranges, load_ranges_text

DATA = Path(__file__).parent / "data" / "unitree_rl_gym"


def test_legged_gym_h1_config_becomes_its_training_domain():
    """unitree_rl_gym's own h1_config.py (as published): floor friction 0.1-1.25 averaged with
    the terrain's 1.0 (PhysX), base mass -1..+3 kg, pushes of 1.5 m/s every 5 s, its
    observation noise as sensor sigmas (uniform +-s: s / sqrt(3)), no latency, no bias, no
    link or joint randomization; the text loads as the H1's ranges."""
    from sim2real.robots import load_robot

    text = legged_gym_domain(DATA / "h1" / "h1_config.py")
    ranges = load_ranges_text(text, "h1_config.py", load_robot("h1"))
    assert ranges.floor_friction == pytest.approx((0.55, 1.125))
    assert ranges.added_base_mass == pytest.approx((-1.0, 3.0))
    assert ranges.pushes == PushRanges(interval=5.0, max_velocity=1.5)
    assert ranges.imu.gyro_noise_sigma == pytest.approx((0.0, 0.2 / math.sqrt(3)), rel=1e-4)
    assert ranges.imu.accel_noise_sigma[1] == pytest.approx(9.80665 * 0.05 / math.sqrt(3), 1e-4)
    assert ranges.imu.bias_scale == (0.0, 0.0) and ranges.imu.latency_ticks == (0, 0)
    assert ranges.sensors.noise_sigma[1] == pytest.approx(0.01 / math.sqrt(3), rel=1e-4)
    d = ranges.dynamics
    assert (d.mass, d.friction, d.damping, d.link_length, d.actuator_strength) == (0,) * 5


def test_a_config_without_domain_rand_takes_its_bases_from_its_own_tree(tmp_path):
    """A config class that sets nothing of domain_rand (go2_config.py in unitree_rl_gym) gets
    its own tree's LeggedRobotCfg's (here upstream legged_gym's: friction 0.5-1.25, no base
    mass, pushes of 1 m/s every 15 s), each value naming the base's file and line; without its
    tree the same file is refused in one line naming the class and the module."""
    from tests.legged_gym_trees import write_task

    task = (
        "from legged_gym.envs.base.legged_robot_config import LeggedRobotCfg\n"
        "class GO2RoughCfg(LeggedRobotCfg):\n"
        "    class control(LeggedRobotCfg.control):\n"
        "        stiffness = {'joint': 20.}\n"
    )
    text = legged_gym_domain(write_task(tmp_path / "tree", task, "go2_config.py"))
    assert "floor_friction = [0.75, 1.125]" in text
    assert "added_base_mass" not in text
    assert "interval = 15" in text and "max_velocity = 1" in text
    assert (
        "# from: pushes.interval = 15, mode = set, max_velocity = 1 <- domain_rand.push_interval_s 15 "
        "(legged_gym/envs/base/legged_robot_config.py:47)" in text
    )
    alone = tmp_path / "go2_config.py"
    alone.write_text(task)
    with pytest.raises(DomainError) as refused:
        legged_gym_domain(alone)
    message = str(refused.value)
    assert "\n" not in message and "class GO2RoughCfg" in message
    assert "legged_gym.envs.base.legged_robot_config" in message


def test_bad_domain_sources_name_the_file_and_the_key(tmp_path, arm3):
    from sim2real.robots import load_robot

    bad = tmp_path / "cfg.py"
    bad.write_text(  # a class without bases is read as it stands
        "class Cfg:\n    class terrain:\n        static_friction = 1.0\n"
        "    class domain_rand:\n        randomize_friction = True\n"
        "        friction_range = [1.0]\n"
    )
    with pytest.raises(DomainError, match=r"cfg.py: domain_rand.friction_range: expected"):
        legged_gym_domain(bad)
    none = tmp_path / "none.py"
    none.write_text("x = 1\n")
    with pytest.raises(DomainError, match="no legged_gym config class"):
        legged_gym_domain(none)
    arm = tmp_path / "arm.toml"
    arm.write_text("added_base_mass = [0.0, 1.0]\n[pushes]\ninterval = 2.0\n")
    with pytest.raises(RangesError, match="added_base_mass: robot arm3 has a fixed base"):
        load_ranges(arm, arm3)
    inverted = tmp_path / "inv.toml"
    inverted.write_text("[pushes]\ninterval = 0.0\n")
    with pytest.raises(RangesError, match=r"inv.toml: pushes.interval: expected a number > 0 s"):
        load_ranges(inverted, load_robot("go2"))


def test_pushes_set_the_base_velocity_from_the_seed_alone(go2):
    """A push sets the base's horizontal velocity (legged_gym's push), drawn from the session
    seed and the push's index only: a resumed session pushes as an uninterrupted one."""
    from sim2real.deploy.backends.sim.plant import SimBackend

    a, b = push_velocity(7, 3, 1.5), push_velocity(7, 3, 1.5)
    assert np.array_equal(a, b) and np.all(np.abs(a) <= 1.5)
    assert not np.array_equal(a, push_velocity(7, 4, 1.5))
    plant = SimBackend(go2, envs=2)
    plant.set_base_velocity(1, np.array([0.7, -0.2]))
    assert plant.datas[1].qvel[:2].tolist() == [0.7, -0.2]
    assert plant.datas[0].qvel[:2].tolist() == [0.0, 0.0]

    class Rt:  # the runtime's fields DomainPushes reads
        ticks, mode = 0, np.array([2, 0], dtype=np.int8)  # env 0 RUNNING, env 1 IDLE

    hidden = PushRanges(interval=1.0, max_velocity=1.5, apply="velocity_hidden_from_imu")
    pushes = DomainPushes([7, 8], hidden, go2.control_period)
    pushes(Rt, plant)
    assert plant.datas[0].qvel[:2] == pytest.approx(push_velocity(7, 0, 1.5))
    assert plant.datas[1].qvel[:2].tolist() == [0.7, -0.2]  # not running: not pushed
    assert pushes.times == [[0.0], []]


def test_every_fall_is_attributed_to_what_began_it():
    faults = [
        {"kind": "stale", "start_s": 10.0, "duration_s": 0.5},
        {"kind": "push", "start_s": 30.0, "duration_s": 0.2},
    ]
    log = [
        {"t_s": 11.0, "cause": "stale_sensor"},  # the runtime's stop during a fault
        {"t_s": 12.0, "cause": "fall"},  # 1.5 s after the stale frames ended
        {"t_s": 31.5, "cause": "fall"},  # after a push fault
        {"t_s": 50.5, "cause": "fall"},  # after a domain push at 50 s
        {"t_s": 80.0, "cause": "fall"},  # nothing before it, not replayed
        {"t_s": 90.0, "cause": "hard_limit", "joint": "left_hip_roll_joint", "past_rad": 0.2},
        # hard-limit stops the soak replayed without the stop: the replay stood / fell anyway
        {"t_s": 100.5, "cause": "hard_limit", "past_rad": 0.15, "would_fall": False},
        {"t_s": 101.0, "cause": "hard_limit", "past_rad": 0.15, "would_fall": True},  # push at 100
    ]
    falls = attribute_falls(log, faults, push_times=[50.0, 100.0])
    assert [f["origin"] for f in falls] == [
        "runtime_stop",
        "fault",
        "push",
        "push",
        "undecided",  # before: "policy", which no replay had shown
        "runtime_stop",
        "runtime_stop",
        "push",
    ]
    assert falls[0]["during"] == "stale" and falls[3]["during"] == "domain push"
    assert falls[5]["joint"] == "left_hip_roll_joint"
    assert [f["stopped_while_falling"] for f in falls[5:]] == [False, False, True]
    assert falls_by_origin(falls) == dict(zip(ORIGINS, (3, 3, 1, 0, 0, 0, 1), strict=True))
    assert stops_while_falling(falls) == 1


def test_a_fall_with_nothing_before_it_is_named_by_its_replays_and_the_summary_says_so():
    """No push, fault or stop before these falls: the policy's own loop falling in most of its
    replays names the policy; the own loop standing and the runtime with other noise falling
    names the runtime; both standing, the session's rare draw; the own loop standing with no
    runtime replay, or no replay, is undecided. The summary says what the replays showed."""
    from sim2real.eval.report.summary import REPLAY_MEANING, replay_lines

    def replays(own, redraw=None):
        out = {"own_loop": {"from_s": [1.0] * len(own), "fall_s": own}}
        if redraw is not None:
            out["redraw"] = {"from_s": 3.0, "fall_s": redraw}
        return out

    stood, fell = None, 9.0
    log = [
        {"t_s": 10.0, "cause": "fall", **replays([fell, fell, fell, stood, stood], [stood] * 5)},
        {"t_s": 20.0, "cause": "fall", **replays([stood] * 5, [fell, fell, fell, stood, fell])},
        {"t_s": 30.0, "cause": "fall", **replays([stood] * 5, [stood, fell, stood, stood, stood])},
        {"t_s": 40.0, "cause": "fall", **replays([stood, stood])},  # the runtime's not run
        {"t_s": 50.0, "cause": "fall"},  # past MAX_FALLS: not replayed
    ]
    falls = attribute_falls(log, [], push_times=[])
    assert [f["origin"] for f in falls] == [
        "policy",
        "runtime",
        "rare_draw",
        "undecided",
        "undecided",
    ]
    by = falls_by_origin(falls)
    assert by == {
        **dict.fromkeys(ORIGINS, 0),
        "policy": 1,
        "runtime": 1,
        "rare_draw": 1,
        "undecided": 2,
    }
    (line,) = replay_lines(by)
    for origin in ("policy", "runtime", "rare_draw", "undecided"):
        assert REPLAY_MEANING[origin] in line
    assert "undecided 2:" in line and replay_lines({"push": 3, "policy": 0}) == []


def test_sweep_margin_is_the_last_level_held_in_a_row():
    q = next(x for x in QUANTITIES if x.name == "link_mass")
    ok = {"success": 0.9, "falls": 0}
    results = {("reference", 0.0): ok}
    results.update({("link_mass", lv): ok for lv in q.levels[:2]})
    results[("link_mass", q.levels[2])] = {"success": 0.9 - TOLERANCE - 0.01, "falls": 0}
    results[("link_mass", q.levels[3])] = ok  # holds again: the margin stays at level 2
    results[("link_mass", q.levels[4])] = {"success": 0.9, "falls": FALL_ALLOWANCE + 1}
    out = margins(results, [q], {"link_mass": True})
    row = out["quantities"][0]
    assert out["reference"]["holds"]
    assert row["margin"] == q.levels[1] and row["failed_at"] == q.levels[2]
    assert margin_text(row) == f"+-{100 * q.levels[1]:.0f} %"
    assert [lv["holds"] for lv in row["levels"]] == [True, True, False, True, False]
    fell = {("reference", 0.0): {"success": 0.9, "falls": FALL_ALLOWANCE + 1}}
    fell.update({("link_mass", lv): ok for lv in q.levels})
    row = margins(fell, [q], {"link_mass": True})["quantities"][0]
    assert row["margin"] is None and "does not hold in the reference world" in margin_text(row)
    assert margin_text({**row, "applies": False}) == "n/a (not in the robot's model)"


def _ranges(domain: str) -> list[str]:
    """A training domain's TOML without its comment lines."""
    return [line for line in domain.splitlines() if not line.startswith("#")]


def test_soak_runs_the_training_domain_the_policy_carries(tmp_path, capsys, go2_onnx):
    """An ONNX policy with a training domain (``policy-export --domain``; here its metadata set
    directly): soak-test runs it (pushes every 2 s, a payload on the base) unless --no-domain,
    and the report says so; the console says which pushes and how they act (a file without
    ``apply``: forces spread over the bodies, not the training's velocity set)."""
    import onnx

    from sim2real.eval.cli import main as soak_main

    domain = (
        "floor_friction = [0.9, 1.0]\nadded_base_mass = [0.5, 1.0]\n"
        "[pushes]\ninterval = 2.0\nmax_velocity = 0.3\n"
    )
    shipped = DATA / "h1" / "h1.onnx"  # the shipped H1 carries its own (policy-export --domain)
    # the same ranges (its comment lines name the reader's module as it was when it was exported)
    assert _ranges(training_domain(shipped)) == _ranges(
        legged_gym_domain(DATA / "h1" / "h1_config.py")
    )
    model = onnx.load(str(go2_onnx))  # sim2real/policies/go2.pt exported
    prop = model.metadata_props.add()
    prop.key, prop.value = "training_domain", domain
    policy = tmp_path / "go2_domain.onnx"
    onnx.save(model, str(policy))
    assert training_domain(policy) == domain
    common = ["--robot", "go2", "--policy", str(policy), "--no-progress"]
    common += ["--no-film", "--no-faults", "--checkpoint-minutes", "0"]
    soak_main([*common, "--hours", "0.01", "--out", str(tmp_path / "with")])
    said = capsys.readouterr().out
    assert "soak-test: pushes: every 2 s, the horizontal velocity set to up to 0.3 m/s, as " in said
    assert "forces over 0.1 s spread over the robot's bodies" in said
    report = json.loads((tmp_path / "with" / "report.json").read_text())
    s = report["sessions"][0]
    assert report["campaign"]["training_domain"] == domain
    assert 0.5 <= s["randomization"]["added_base_mass"] <= 1.0
    assert s["locomotion"]["domain_pushes"] >= 10
    # 10.8 s: the domain's pushes (every 2 s) would have come several times
    soak_main([*common, "--hours", "0.003", "--no-domain", "--out", str(tmp_path / "without")])
    assert "soak-test: pushes:" not in capsys.readouterr().out
    report = json.loads((tmp_path / "without" / "report.json").read_text())
    assert report["campaign"]["training_domain"] is None
    assert report["sessions"][0]["locomotion"]["domain_pushes"] == 0


MJLAB_RANGES = (
    Path(__file__).parents[1] / "sim2real" / "eval" / "world" / "mjlab_velocity_ranges.toml"
)


def test_mjlab_pushes_add_a_twist_after_random_intervals_and_resume_exactly(go2):
    """mjlab's push_robot: after U(1, 3) s, U(range) is ADDED to the root's world velocity, linear
    and angular; each interval and twist is a pure function of the seed and the push's index,
    and a push schedule restored from its state continues as the uninterrupted one."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.eval.world.pushes import AXES, push_twist
    from sim2real.eval.world.ranges_file import read_overrides

    overrides = read_overrides(MJLAB_RANGES)  # the shipped file: every key parses
    assert overrides["com_offset"]["body"] == "torso_link"  # the G1's: a go2 refuses it
    with pytest.raises(RangesError, match="'torso_link' is no body of robot go2"):
        load_ranges(MJLAB_RANGES, go2)
    # the velocity added at once (the training stack's way, hidden from the IMU)
    assert overrides["pushes"]["apply"] == "force" and overrides["pushes"]["window"] == 0.1
    ranges = PushRanges(**{**overrides["pushes"], "apply": "velocity_hidden_from_imu"})
    assert ranges.mode == "add" and ranges.interval == (1.0, 3.0) and not ranges.legacy
    dt = go2.control_period

    class Rt:
        ticks, mode = 0, np.array([2], dtype=np.int8)

    def run(pushes, plant, start, stop):
        for t in range(start, stop):
            Rt.ticks = t
            pushes(Rt, plant)

    plant = SimBackend(go2, envs=1)
    d = plant.datas[0]
    d.qpos[3:7] = [np.cos(0.3), 0.0, 0.0, np.sin(0.3)]  # the base turned 0.6 rad about z
    d.qvel[:] = 0.0
    d.qvel[:3] = [0.2, 0.1, 0.0]
    pushes = DomainPushes([5], ranges, dt)
    run(pushes, plant, 0, int(60 / dt))
    gaps = np.diff([0.0, *pushes.times[0]])
    assert len(gaps) > 20 and np.all(gaps >= 1.0 - dt) and np.all(gaps <= 3.0 + dt)
    twists = np.array([push_twist(5, k, ranges.ranges()) for k in range(1, len(gaps) + 1)])
    for a, name in enumerate(AXES):  # every axis moves within its range
        lo, hi = getattr(ranges, name)
        assert np.all((twists[:, a] >= lo) & (twists[:, a] <= hi)) and np.ptp(twists[:, a]) > 0
    np.testing.assert_allclose(d.qvel[:3], [0.2, 0.1, 0.0] + twists[:, :3].sum(0), atol=1e-12)
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, d.qpos[3:7])
    np.testing.assert_allclose(rot.reshape(3, 3) @ d.qvel[3:6], twists[:, 3:].sum(0), atol=1e-12)

    whole = DomainPushes([5], ranges, dt)
    run(whole, plant, 0, int(40 / dt))
    resumed = DomainPushes([5], ranges, dt)
    run(resumed, plant, 0, int(17 / dt))
    state = resumed.state_dict(0)
    resumed = DomainPushes([5], ranges, dt)
    resumed.load_state_dict(state, 0)
    run(resumed, plant, int(17 / dt), int(40 / dt))
    assert resumed.times == whole.times


def test_random_interval_pushes_wait_after_each_reset_and_legged_gyms_keep_their_grid(go2):
    """A robot down 1.5-6 s at a time (stopped, lying, stood up) over 5 minutes: pushes at
    random intervals (Isaac Lab's ``is_global_time=False``, holosoma's) wait at least the
    interval's low end after each return to RUNNING, the env's reset (before, a push came 0.02 s
    after one); legged_gym's global ``common_step_counter % push_interval`` stays on its grid
    whatever the robot did, as it trained."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.core.modes import Mode

    dt = go2.control_period
    rng = np.random.default_rng(0)
    mode = np.full(int(300 / dt), int(Mode.RUNNING), dtype=np.int8)
    onsets, t = [0], 4.0
    while t < 290.0:
        down = rng.uniform(1.5, 6.0)
        mode[int(t / dt) : int((t + down) / dt)] = int(Mode.FAULTED)
        onsets.append(int((t + down) / dt))
        t += down + rng.uniform(2.0, 8.0)

    class Rt:
        ticks, mode = 0, np.zeros(1, dtype=np.int8)

    plant = SimBackend(go2, envs=1)
    randomly = DomainPushes([3], PushRanges(interval=(1.0, 3.0), mode="add", x=(-0.1, 0.1)), dt)
    grid = DomainPushes([3], PushRanges(interval=2.0, max_velocity=0.1), dt)
    for tick, m in enumerate(mode):
        Rt.ticks, Rt.mode[0] = tick, m
        randomly(Rt, plant)
        grid(Rt, plant)
    pushed = np.round(np.array(randomly.times[0]) / dt).astype(int)
    assert len(onsets) > 20 and len(pushed) > 50
    since = pushed - np.array([max(o for o in onsets if o <= p) for p in pushed])
    assert since.min() * dt >= 1.0 - 1e-9, since.min() * dt
    on_grid = np.round(np.array(grid.times[0]) / dt).astype(int)
    assert np.all(on_grid % round(2.0 / dt) == 0) and np.all(mode[on_grid] == int(Mode.RUNNING))


@pytest.mark.parametrize(
    "text, message",
    [
        ("[pushes]\nmax_velocity = 1.0\nvelocity = {x = [-1, 1]}", "pushes.velocity: .*not both"),
        ("[pushes]\nvelocity = {z = [-0.2, 0.2]}", 'pushes.velocity.z: .*expect mode = "add"'),
        ("[pushes]\ninterval = [3.0, 1.0]", "pushes.interval: expected a number > 0"),
        ('[pushes]\nmode = "shove"', "pushes.mode: expected one of"),
        ("[sensors]\nencoder_bias = [0.02, -0.02]", "sensors.encoder_bias"),
        ('[dynamics]\ncom_offset = {body = "no_such_body"}', "'no_such_body' is no body"),
        ('[pushes]\ninterval = "often"', "a number or a range"),
    ],
)
def test_bad_mjlab_domain_keys_are_refused_naming_the_key(go2, text, message):
    with pytest.raises(RangesError, match=message):
        load_ranges_text(text, "domain.toml", go2)


def test_encoder_bias_and_com_offset_are_drawn_per_session_and_applied(go2):
    """An encoder bias offsets what each encoder reads (never the true state), drawn per joint
    from its own stream; a centre-of-mass offset moves the body's ``body_ipos``; ranges without
    them draw exactly what they drew before (the other streams untouched)."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.eval.world.dynamics import shift_com
    from sim2real.eval.world.session_draw import sample_session
    from sim2real.eval.world.session_ranges import session_ranges

    base = session_ranges(go2)
    plain = sample_session(go2, 3, 60.0, base)
    text = (
        "[sensors]\nencoder_bias = [-0.015, 0.015]\n[dynamics]\ncom_offset = {x = [-0.05, 0.05]}\n"
    )
    ranges = load_ranges_text(text, "domain.toml", go2)
    drawn = sample_session(go2, 3, 60.0, ranges)
    assert "encoder_bias" not in plain.to_dict() and plain.encoder_bias is None
    same = {k: v for k, v in drawn.to_dict().items() if k not in ("encoder_bias", "com_offset")}
    assert same == plain.to_dict()
    bias = np.array(drawn.encoder_bias)
    assert bias.shape == (go2.n_joints,) and np.all(np.abs(bias) <= 0.015) and np.ptp(bias) > 0
    body, offset = drawn.com_offset
    assert body == go2.base_body and abs(offset[0]) <= 0.05 and offset[1:] == (0.0, 0.0)
    back = type(drawn).from_dict(json.loads(json.dumps(drawn.to_dict())))
    assert back == drawn

    plant = SimBackend(go2, envs=2)
    plant.encoder_bias[1] = bias
    plant.reset()
    for _ in range(10):
        plant.advance()
    frame = plant.read()
    q = plant.true_position()
    np.testing.assert_allclose(frame.position[1] - q[1], bias, atol=5e-3)  # noise, quantum
    np.testing.assert_allclose(frame.position[0] - q[0], 0.0, atol=5e-3)
    model = go2.plant_model()
    before = model.body_ipos[model.body(body).id].copy()
    shift_com(model, body, offset)
    np.testing.assert_allclose(model.body_ipos[model.body(body).id] - before, offset)


@pytest.mark.parametrize("apply", ["force", "velocity_hidden_from_imu"])
def test_a_push_is_a_force_the_imu_feels_unless_asked_to_hide_it(apply):
    """A domain push: by default the wrench that gives the robot legged_gym's
    velocity change over ``window`` s (F = m dv / window), so the plant's accelerometer reads
    it (about dv / window along the push, world frame) and the base gains about dv; the force
    is gone after the window. Setting the velocity instead (``apply =
    "velocity_hidden_from_imu"``) moves the base at once and the accelerometer never sees it
    (it reads the floor's friction slowing the robot down, against the push)."""
    from sim2real.deploy.backends.sim.legged_sensors import sensor_address
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.robots import load_robot

    go2 = load_robot("go2")
    plant = SimBackend(go2, envs=1)
    plant.reset()
    for _ in range(25):  # settle on its feet
        plant.advance()
    m, d = plant.models[0], plant.datas[0]
    accel = sensor_address(m, mujoco.mjtSensor.mjSENS_ACCELEROMETER, go2.imu_site_id)
    ranges = PushRanges(interval=1.0, max_velocity=1.0, apply=apply, window=0.1)
    pushes = DomainPushes([7], ranges, go2.control_period)
    dv = push_velocity(7, 0, 1.0)

    class Rt:
        ticks, mode = 0, np.array([2], dtype=np.int8)

    v0 = d.qvel[:2].copy()
    pushes(Rt, plant)  # tick 0: the push
    assert pushes.times == [[0.0]] and pushes.last_tick.tolist() == [0]
    felt = []
    for t in range(1, 6):  # the window: 0.1 s, five ticks at 50 Hz
        plant.advance()
        world = d.site_xmat[go2.imu_site_id].reshape(3, 3) @ d.sensordata[accel : accel + 3]
        felt.append(world[:2] @ dv / np.linalg.norm(dv))  # m/s^2 along the push
        Rt.ticks = t
        pushes(Rt, plant)
    gained = (d.qvel[:2] - v0) @ dv / np.linalg.norm(dv)
    base = m.body(go2.base_body).id
    if apply == "force":
        expected = np.linalg.norm(dv) / 0.1  # m/s^2 over the window
        assert 0.5 * expected < np.mean(felt) < 1.5 * expected, (felt, expected)
        assert 0.6 * np.linalg.norm(dv) < gained < 1.1 * np.linalg.norm(dv)
        assert not d.xfrc_applied[base].any() and pushes.until.tolist() == [0]
    else:
        assert np.mean(felt) < 0.0, felt


@pytest.mark.parametrize("twist", [[0.8, -0.6, 0, 0, 0, 0], [0.3, 0.2, 0.1, 0.4, -0.3, 0.6]])
def test_a_push_moves_the_whole_robot_as_the_training_push_does(twist):
    """A force push spread over the robot's bodies (``set_push_wrench``) changes the whole
    robot's velocity as a training push does (legged_gym sets the root's velocity, mjlab adds
    a twist; the joints' speeds are left alone): after the 0.1-s window, in the air without
    gravity, the base has the push's velocity change and the joints barely move, where the
    same wrench on the base alone swings the legs about their joints."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.robots import load_robot

    go2 = load_robot("go2")
    twist = np.array(twist)
    add = bool(np.any(twist[2:]))
    joints = {}
    for how in ("spread", "base"):
        plant = SimBackend(go2, envs=1)
        plant.reset()
        m, d = plant.models[0], plant.datas[0]
        m.opt.gravity[:] = 0.0
        d.qpos[2] += 1.0  # in the air
        mujoco.mj_forward(m, d)
        v0 = d.qvel[:6].copy()
        wrench = plant.push_wrench(0, twist, add, 0.1)
        if how == "spread":
            plant.set_push_wrench(0, wrench)
        else:
            plant.set_base_wrench(0, wrench)
        swing = 0.0
        for _ in range(5):  # 0.1 s at 50 Hz
            plant.advance()
            swing = max(swing, np.abs(d.qvel[6:]).max())
        rot = d.xmat[m.body(go2.base_body).id].reshape(3, 3)
        gained = np.concatenate([d.qvel[:3] - v0[:3], rot @ d.qvel[3:6] - rot @ v0[3:6]])
        joints[how] = swing  # rad/s, the fastest joint in the window
        if how == "spread":
            wanted = twist if add else np.array([*twist[:2], 0, 0, 0, 0])
            np.testing.assert_allclose(gained, wanted, atol=0.05 * np.abs(wanted).max())
    assert joints["spread"] < 0.03 and joints["base"] > 0.15, joints  # measured 0.012, 0.38


def test_false_fall_stops_are_fall_check_stops_of_a_robot_the_truth_has_upright():
    """``false_fall_stops``: the holosoma G1's stop (0.4 deg, base 0.67 m of its
    0.757 m) counts; a tilted or low base, another cause, a record without the truth or one
    whose replay fell anyway does not."""
    from sim2real.eval.soak.falls import false_fall_stops

    falls = [
        {"cause": "fall", "true_tilt_deg": 0.4, "true_height_m": 0.67},  # upright: false
        {"cause": "fall", "true_tilt_deg": 70.0, "true_height_m": 0.5},  # tilted past half
        {"cause": "fall", "true_tilt_deg": 3.0, "true_height_m": 0.2},  # the base down
        {"cause": "hard_limit", "true_tilt_deg": 1.0, "true_height_m": 0.7},  # not the check's
        {"cause": "fall", "tilt_deg": 1.0},  # hardware: no truth
        {"cause": "fall", "true_tilt_deg": 1.0, "true_height_m": 0.7, "would_fall": True},
    ]
    assert false_fall_stops(falls, 0.757, 1.0) == 1


def test_a_stop_of_a_base_collapsing_vertically_is_a_true_fall():
    """A level base going down (knees buckling: the fall check's upright sinking signal, 0.3 s
    at 1 m/s, leaves a humanoid's base well above 0.4 of its standing height) is a fall, not a
    false stop; a level base standing still or swaying as a walk does is a false stop. Before,
    every level base above the height line counted as a false stop."""
    from sim2real.eval.soak.falls import false_fall_stops

    collapse = {"cause": "fall", "true_tilt_deg": 1.5, "true_height_m": 0.7, "true_vz_m_s": -1.2}
    still = {"cause": "fall", "true_tilt_deg": 1.5, "true_height_m": 0.7, "true_vz_m_s": -0.05}
    walk = {"cause": "fall", "true_tilt_deg": 1.5, "true_height_m": 0.7, "true_vz_m_s": 0.3}
    assert false_fall_stops([collapse], 1.034, 1.0) == 0
    assert false_fall_stops([still, walk, collapse], 1.034, 1.0) == 2


def test_the_estimate_after_a_push_is_judged_against_the_truth_its_frame_sampled():
    """A tick's estimate comes from the frame the plant sampled at the end of the tick before;
    the tick's own physics then moves the base on. A base accelerating at 10 m/s^2 (a push) is
    0.2 m/s faster one 50-Hz tick later: an estimate equal to the truth of its frame is judged
    0 m/s off, not 0.2 m/s (the truth after the tick's physics)."""
    from sim2real.eval.soak.push_response import PushResponse

    class Pushes:
        seeds = [1]
        last_tick = np.array([-1], dtype=np.int64)

    class Base:
        linear_velocity = np.zeros((1, 3))

    class Rt:
        ticks, mode = 0, np.array([2])
        state = type("S", (), {"base": Base})

    class Plant:
        speed = 0.0

        def true_base_state(self, out=None):
            s = np.zeros((1, 13))
            s[0, 3] = 1.0  # upright, base frame = world frame
            s[0, 7] = self.speed
            return s

    plant, response = Plant(), PushResponse(Pushes, 0.02)
    for t in range(60):
        Rt.ticks = t
        Base.linear_velocity[0, 0] = plant.speed  # the estimate: the truth its frame sampled
        plant.speed = 0.2 * t  # the tick's physics: 10 m/s^2
        response(Rt, plant)  # after the tick, before its push
        if t == 5:
            Pushes.last_tick[0] = t
    summary = response.summary()
    assert summary["ticks"] == 50 and summary["worst_m_s"] == pytest.approx(0.0)


def test_the_estimate_is_judged_in_the_second_after_each_push():
    """PushResponse: the planar velocity error of the RUNNING ticks 1..50 after a push (50 Hz),
    its mean, RMS, worst tick and worst push; a new push closes the previous one's second."""
    from sim2real.eval.soak.push_response import PushResponse

    class Pushes:
        seeds = [1, 2]
        last_tick = np.array([-1, -1], dtype=np.int64)

    class Base:
        linear_velocity = np.zeros((2, 3))

    class Rt:
        ticks, mode = 0, np.array([2, 2])
        state = type("S", (), {"base": Base})

    class Plant:
        def true_base_state(self, out=None):
            s = np.zeros((2, 13))
            s[:, 3] = 1.0  # upright, base frame = world frame
            s[:, 7] = [0.3, 0.1]  # the estimate says 0: errors 0.3 and 0.1 m/s
            return s

    response = PushResponse(Pushes, 0.02)
    for t in range(200):
        Rt.ticks = t
        if t in (10, 100, 130):  # env 0 pushed at 10 and 100, env 1 at 130 (not 1 s on)
            Pushes.last_tick[0 if t < 130 else 1] = t
        if t == 110:
            Pushes.last_tick[0] = t  # a push 0.2 s after the last: its second ends there
        response(Rt, Plant())
    zero, one = response.summary(0), response.summary(1)
    assert zero["pushes"] == 3 and zero["ticks"] == 50 + 9 + 50  # 101..109: 110 is a push
    assert zero["mean_m_s"] == pytest.approx(0.3) and zero["worst_m_s"] == pytest.approx(0.3)
    assert one["pushes"] == 1 and one["ticks"] == 50 and one["rms_m_s"] == pytest.approx(0.1)
    assert response.summary()["worst_push_mean_m_s"] == pytest.approx(0.3)
    state = response.state_dict(0)
    again = PushResponse(Pushes, 0.02)
    again.load_state_dict(state, 0)
    assert again.summary(0) == zero


def test_robot_labs_go2w_domain_loads_on_the_go2w_and_refuses_a_robot_without_its_base(go2):
    """The shipped ranges file of robot_lab's Go2-W task (its EventCfg, commands and noise):
    every key parses onto the go2w, whose base body it names; the go2's base is another body."""
    from sim2real.robots import load_robot

    path = MJLAB_RANGES.parent / "robot_lab_go2w_velocity_ranges.toml"
    ranges = load_ranges(path, load_robot("go2w"))
    assert ranges.floor_friction == (0.3, 1.0) and ranges.added_base_mass == (-1.0, 3.0)
    assert (ranges.dynamics.mass, ranges.dynamics.kp, ranges.dynamics.kd) == (0.3, 0.3, 0.3)
    assert ranges.pushes.interval == (10.0, 15.0) and ranges.pushes.mode == "add"
    assert ranges.commands.vx == ranges.commands.vy == ranges.commands.yaw_rate == (-1.0, 1.0)
    with pytest.raises(RangesError, match="'base_link' is no body of robot go2"):
        load_ranges(path, go2)


def test_robot_labs_command_period_is_read_not_the_soaks_default(tmp_path):
    """robot_lab's velocity task draws a new command every 10 s (CommandsCfg.base_velocity
    ``resampling_time_range=(10.0, 10.0)``, fan-ziqi/robot_lab velocity_env_cfg.py): the shipped
    ranges file says so and the soak's schedule takes it from there (before: no ``period``, so
    soak-test's 4-s default); the env.yaml reader turns the same command term into the same
    period."""
    from sim2real.eval.world.command_schedule import command_schedule
    from sim2real.eval.world.env_yaml_domain import env_yaml_domain
    from sim2real.robots import load_robot

    path = MJLAB_RANGES.parent / "robot_lab_go2w_velocity_ranges.toml"
    ranges = load_ranges(path, load_robot("go2w"))
    assert ranges.commands.period == (10.0, 10.0)
    given = {"vx": 0, "vy": 0, "yaw_rate": 0, "zero_fraction": 0, "period": 0}
    commands, account = command_schedule(ranges.commands, given, path.name, (None, None), None)
    assert commands.period == (10.0, 10.0) and account["period_s"] == 10.0
    assert account["sources"]["period"] == f"{path.name} [commands] period"

    env = tmp_path / "env.yaml"  # the command term as Isaac Lab dumps robot_lab's CommandsCfg
    env.write_text(
        "events: {}\ncommands:\n  base_velocity:\n    resampling_time_range: [10.0, 10.0]\n"
        "    rel_standing_envs: 0.02\n    ranges:\n      lin_vel_x: [-1.0, 1.0]\n"
        "      lin_vel_y: [-1.0, 1.0]\n      ang_vel_z: [-1.0, 1.0]\n"
    )
    read = load_ranges_text(env_yaml_domain(env), "env.yaml", load_robot("go2w"))
    assert read.commands.period == ranges.commands.period
    assert read.commands.zero_fraction == ranges.commands.zero_fraction


def test_a_clip_sessions_sweep_success_is_its_clips_not_a_zero_command_tracking():
    """A sweep level's success of a session a motion clip commands: the share of its clips no
    stop ended (the one cut short by the session's end counted as not stopped), not the velocity
    tracker's zero-command tracking (which it read: 0.95 here for a dance that fell in 1 of 2)."""
    play = {"stopped": False, "completed": 1.0}
    loco = {"commanded_by": "clip", "tracking_success": 0.95}
    clips = [play, {**play, "stopped": True, "completed": 0.4}]
    result = {"locomotion": loco, "exhibition": {"clips": clips}}
    assert session_success(result) == pytest.approx(0.5)
    cut = [play, {**play, "unfinished": True, "completed": 0.3}]
    assert session_success({**result, "exhibition": {"clips": cut}}) == pytest.approx(1.0)
    assert session_success({**result, "exhibition": {"clips": []}}) is None
    walk = {"locomotion": {**loco, "commanded_by": "velocity"}}
    assert session_success(walk) == pytest.approx(0.95)
    assert session_success({"locomotion": None, "goals": {"success_rate": 0.8}}) == 0.8
