"""mjlab's velocity-task domain as a ranges file (sim2real/eval/world/mjlab_velocity_ranges.toml): its
inline tables ``[pushes] velocity``, ``angular_velocity`` and ``[dynamics] com_offset``, their
one-line errors, a fixed-base robot's encoder bias and centre-of-mass offset, the world twist a
push adds, and files without the new keys drawing exactly what they drew before them."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from sim2real.eval.world.dynamics import DynamicsRanges
from sim2real.eval.world.pushes import DomainPushes
from sim2real.eval.world.ranges_file import (
    RangesError,
    load_ranges,
    load_ranges_text,
    read_overrides,
)
from sim2real.eval.world.session_draw import sample_session
from sim2real.eval.world.session_ranges import session_ranges
from sim2real.robots import load_robot

MJLAB_RANGES = (
    Path(__file__).parents[1] / "sim2real" / "eval" / "world" / "mjlab_velocity_ranges.toml"
)


def _rounded(x):
    if isinstance(x, float):
        return float(f"{x:.10g}")
    if isinstance(x, dict):
        return {k: _rounded(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_rounded(v) for v in x]
    return x


def _digest(obj) -> str:
    text = json.dumps(_rounded(obj), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


#: The active lines of sim2real/eval/world/example_ranges.toml when the new keys came (an arm's file).
EXAMPLE = """
[dynamics]
mass = 0.3
friction = 0.6
[sensors]
noise_sigma = [0.004, 0.04]
latency_ticks = [0, 3]
dropout = [0.0, 0.002]
[drift]
friction_rate = [0.02, 0.08]
[faults]
mean_interval = 90.0
push_force = [5.0, 20.0]
kinds = ["dropout", "stale", "nan-action", "latency", "push", "cable"]
weights = [1.0, 1.0, 1.0, 1.0, 2.0, 1.0]
"""
#: A legged_gym training domain (policy-export --domain writes such a text).
LEGGED_GYM = (
    "floor_friction = [0.6, 1.0]\nadded_base_mass = [-1.0, 3.0]\n"
    "[pushes]\ninterval = 2.0\nmax_velocity = 0.5\n"
)


def test_files_without_the_new_keys_draw_exactly_what_they_drew_before():
    """The sessions (dynamics, sensors, drift, faults, IMU, floor, base mass) and legged_gym's
    pushes of files without the new keys equal those of the code before them (commit b4b6e62:
    the digests were computed by it, floats to 10 significant digits; go2's since the stale
    limit became at least 8 control periods, ``Robot.stale_limit``: its 50-Hz sensor faults'
    durations, magnitudes and starts only, each a whole number of the longer gap)."""
    from sim2real.deploy.core.modes import RUNNING

    drawn = {}
    for label, name, text in [
        ("arm3 example", "arm3", EXAMPLE),
        ("go2 legged_gym", "go2", LEGGED_GYM),
        ("go2 defaults", "go2", ""),
    ]:
        robot = load_robot(name)
        ranges = load_ranges_text(text, "nightly.toml", robot)
        sessions = [sample_session(robot, s, 600.0, ranges).to_dict() for s in (0, 7, 123)]
        drawn[label] = _digest(sessions)
    assert drawn == {
        "arm3 example": "4a13d06fe5218ba7",
        "go2 legged_gym": "c600050c753c3c5d",
        "go2 defaults": "34355f2c408b656e",
    }

    go2 = load_robot("go2")
    calls = []

    class Rt:
        ticks, mode = 0, np.full(3, RUNNING)

    class Backend:
        def set_base_velocity(self, e, v):
            calls.append((Rt.ticks, e, [float(a) for a in v]))

    ranges = load_ranges_text(LEGGED_GYM, "nightly.toml", go2).pushes
    ranges = dataclasses.replace(ranges, apply="velocity_hidden_from_imu")  # the velocity set
    pushes = DomainPushes([0, 7, 123], ranges, go2.control_period)
    for t in range(int(30 / go2.control_period)):
        Rt.ticks = t
        pushes(Rt, Backend())
    assert len(calls) == 45 and _digest(calls) == "dc0d78bbe16a81f2"


def test_the_mjlab_velocity_file_parses_and_loads_for_a_robot_with_its_body():
    """The shipped file: every key parses; the go2 (no torso_link) refuses it naming the file,
    the key and its bodies; with a body the robot has (the H1's pelvis here: sim2real/robots/ ships no
    G1) it loads as mjlab's G1 domain, the other ranges the robot kind's defaults."""
    overrides = read_overrides(MJLAB_RANGES)
    assert overrides["com_offset"] == {
        "body": "torso_link",
        "x": (-0.05, 0.05),
        "y": (-0.05, 0.05),
        "z": (-0.05, 0.05),
    }
    go2 = load_robot("go2")
    with pytest.raises(RangesError) as exc:
        load_ranges(MJLAB_RANGES, go2)
    message = str(exc.value)
    assert message.startswith(f"{MJLAB_RANGES}: dynamics.com_offset.body: 'torso_link' is no body")
    assert "'base'" in message and "'FL_calf'" in message and "\n" not in message

    h1 = load_robot("h1")
    text = MJLAB_RANGES.read_text().replace('body = "torso_link"', 'body = "pelvis"')
    ranges = load_ranges_text(text, "mjlab.toml", h1)
    p = ranges.pushes
    assert (p.interval, p.mode, p.max_velocity) == ((1.0, 3.0), "add", None)
    np.testing.assert_allclose(
        p.ranges(),
        [[-0.5, 0.5], [-0.5, 0.5], [-0.25, 0.25], [-0.52, 0.52], [-0.52, 0.52], [-0.78, 0.78]],
    )
    default = session_ranges(h1)
    assert ranges.sensors.encoder_bias == (-0.015, 0.015)
    assert ranges.sensors.noise_sigma == default.sensors.noise_sigma
    # mjlab randomizes no mass, friction, damping or gains, and its IMU has no latency
    assert ranges.dynamics == DynamicsRanges.none()
    assert ranges.imu == dataclasses.replace(default.imu, latency_ticks=(0, 0))
    assert ranges.floor_friction == (0.3, 1.2)
    draw = sample_session(h1, 4, 60.0, ranges)
    assert len(draw.encoder_bias) == h1.n_joints
    assert draw.com_offset[0] == "pelvis" and max(map(abs, draw.com_offset[1])) <= 0.05
    report = draw.to_dict()  # what the soak report and the checkpoint carry
    assert report["com_offset"]["body"] == "pelvis" and len(report["encoder_bias"]) == h1.n_joints


@pytest.mark.parametrize(
    "text, key, expected",
    [
        ("[pushes]\nvelocity = [-0.5, 0.5]", "pushes.velocity", "an inline table {x, y, z}"),
        ("[pushes]\nvelocity = {w = [0, 1]}", "pushes.velocity.w", "one of x, y, z"),
        ('[pushes]\nvelocity = {x = "fast"}', "pushes.velocity.x", "a range [low, high]"),
        (
            '[pushes]\nmode = "add"\nvelocity = {x = [0.5, -0.5]}',
            "pushes.velocity.x",
            "low <= high",
        ),
        (
            "[pushes]\nangular_velocity = {roll = [0, 1], x = [0, 1]}",
            "pushes.angular_velocity.x",
            "one of roll, pitch, yaw",
        ),
        (
            "[pushes]\nmax_velocity = 1.0\nangular_velocity = {yaw = [-1, 1]}",
            "pushes.angular_velocity",
            "not both",
        ),
        ("[pushes]\nx = [-0.5, 0.5]", "pushes.x", "velocity, angular_velocity"),
        ("[pushes]\ninterval = -2.0", "pushes.interval", "a number > 0 s or a range"),
        ("[pushes]\ninterval = [-1.0, 3.0]", "pushes.interval", "0 < low <= high"),
        ("[pushes]\ninterval = [1.0, 2.0, 3.0]", "pushes.interval", "a number or a range"),
        ('[pushes]\nmode = "push"', "pushes.mode", "one of ['set', 'add']"),
        ("[sensors]\nencoder_bias = 0.015", "sensors.encoder_bias", "a range [low, high]"),
        ("[sensors]\nencoder_bias = [0.015, -0.015]", "sensors.encoder_bias", "low <= high"),
        ("[dynamics]\ncom_offset = 0.05", "dynamics.com_offset", "an inline table {body, x"),
        ("[dynamics]\ncom_offset = {body = 3}", "dynamics.com_offset.body", "a string"),
        ("[dynamics]\ncom_offset = {x = [0.05, -0.05]}", "dynamics.com_offset.x", "low <= high"),
        ("[dynamics]\ncom_offset = {mass = 1.0}", "dynamics.com_offset.mass", "one of body, x"),
        ("[com_offset]\nx = [0, 0.01]", "unknown key 'com_offset'", "[dynamics]"),
    ],
)
def test_a_bad_value_is_one_line_naming_the_file_key_and_expected_value(text, key, expected):
    go2 = load_robot("go2")
    with pytest.raises(RangesError) as exc:
        load_ranges_text(text, "domain.toml", go2)
    message = str(exc.value)
    assert message.startswith(f"domain.toml: {key}")
    assert expected in message and "\n" not in message


def test_a_fixed_base_arm_draws_an_encoder_bias_and_a_com_offset():
    """Neither needs a floating base: the arm's named link's ``body_ipos`` moves by the drawn
    offset (its default body is its base), its encoders read q + bias; pushes stay refused."""
    from sim2real.eval.world.dynamics import shift_com

    arm = load_robot("arm3")
    link = arm.mj_model.body(arm.mj_model.nbody - 1).name
    text = (
        "[sensors]\nencoder_bias = [-0.01, 0.01]\n"
        f'[dynamics]\nmass = 0.3\ncom_offset = {{body = "{link}", z = [0.01, 0.02]}}\n'
    )
    ranges = load_ranges_text(text, "arm.toml", arm)
    assert ranges.dynamics.mass == 0.3 and ranges.com_offset.body == link
    draw = sample_session(arm, 2, 60.0, ranges)
    body, offset = draw.com_offset
    assert body == link and offset[:2] == (0.0, 0.0) and 0.01 <= offset[2] <= 0.02
    assert len(draw.encoder_bias) == arm.n_joints
    model = arm.plant_model()
    before = model.body_ipos[model.body(link).id].copy()
    shift_com(model, body, offset)
    np.testing.assert_allclose(model.body_ipos[model.body(link).id] - before, offset)
    with pytest.raises(RangesError, match="arm.toml: pushes: robot arm3 has a fixed base"):
        load_ranges_text("[pushes]\ninterval = [1.0, 3.0]", "arm.toml", arm)


def test_an_added_push_is_the_world_twist_at_the_base_frame_whatever_its_attitude():
    """``push_base(add=True)``: MuJoCo's own velocity of the base frame (mj_objectVelocity, world
    orientation) changes by the twist, linear and angular, at a rolled, pitched, yawed base;
    ``add=False`` sets the horizontal velocity only and refuses the other axes."""
    from sim2real.deploy.backends.sim.plant import SimBackend

    go2 = load_robot("go2")
    plant = SimBackend(go2, envs=1)
    m, d = plant.models[0], plant.datas[0]
    quat = np.empty(4)
    mujoco.mju_euler2Quat(quat, np.array([0.4, -0.3, 1.1]), "xyz")
    d.qpos[3:7] = quat
    d.qvel[:6] = [0.3, -0.2, 0.1, 0.5, 0.2, -0.4]
    body = m.body(go2.base_body).id

    def world_twist():
        mujoco.mj_forward(m, d)
        out = np.empty(6)
        mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_XBODY, body, out, 0)
        return np.concatenate([out[3:], out[:3]])  # (linear, angular), world

    before = world_twist()
    twist = np.array([0.4, -0.5, 0.2, 0.52, -0.3, 0.78])
    plant.push_base(0, twist, add=True)
    np.testing.assert_allclose(world_twist() - before, twist, atol=1e-12)
    plant.push_base(0, np.array([0.1, 0.2, 0, 0, 0, 0]), add=False)
    np.testing.assert_allclose(d.qvel[:2], [0.1, 0.2])
    with pytest.raises(ValueError, match="use add"):
        plant.push_base(0, twist, add=False)


def test_a_go2_soak_in_mjlabs_domain_reports_its_draws_and_resumes_exactly(go2_onnx, tmp_path):
    """A soak session with mjlab's domain (pushes adding a twist after 1-3 s, an encoder bias, a
    centre-of-mass offset on the base): the report lists the bias and the offset with the other
    drawn values, and a kill -9 after the first checkpoint + resume equals the whole run (the
    next push of the random interval is in the checkpoint)."""
    import shutil
    from dataclasses import replace

    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.soak.campaign import run_campaign
    from sim2real.eval.soak.session import session_dir
    from tests.soak_fixtures import kill_after_first_checkpoint, short_session

    go2 = load_robot("go2")
    text = MJLAB_RANGES.read_text().replace('body = "torso_link"', 'body = "base"')
    ranges = load_ranges_text(text, "mjlab.toml", go2)
    config = short_session(
        "go2", go2_onnx, 0.006, checkpoint_minutes=0.15, faults=False, ranges=ranges
    )
    whole = SessionBatch([config], tmp_path / "whole", progress=False).run()[0]
    drawn = whole["randomization"]
    assert len(drawn["encoder_bias"]) == go2.n_joints and drawn["com_offset"]["body"] == "base"
    assert 0.3 <= drawn["floor_friction"] <= 1.2
    assert whole["locomotion"]["domain_pushes"] >= 5
    from sim2real.eval.report.html import randomization_table

    table = randomization_table([whole])  # report.html's table
    row = dict(zip(table["header"], table["rows"][0], strict=True))
    assert row["centre of mass offset (m)"].startswith("base: ")
    assert row["encoder bias, largest |b| (rad)"] == max(map(abs, drawn["encoder_bias"]))

    out = tmp_path / "campaign"
    kill_after_first_checkpoint(config, out)
    assert not (session_dir(out, 0) / "result.json").exists()
    resumed = run_campaign(replace(config, seed=0), 1, out, resume=True, progress=False)[0]
    strip = {"wall"}
    assert {k: v for k, v in resumed.items() if k not in strip} == {
        k: v for k, v in whole.items() if k not in strip
    }
    shutil.rmtree(out)


def test_pybullet_takes_the_added_twist_too():
    """The pybullet plant's base gets the same twist: its own base velocity read back (linear at
    the base frame, angular body frame) is the MuJoCo mirror's after ``push_base(add=True)``."""
    from sim2real.deploy.backends.sim.bullet.plant import BulletBackend

    go2 = load_robot("go2")
    plant = BulletBackend(go2)
    plant.reset()
    d = plant.datas[0]
    quat = np.empty(4)
    mujoco.mju_euler2Quat(quat, np.array([0.2, 0.3, -0.9]), "xyz")
    d.qpos[3:7] = quat
    plant.push_base(0, np.zeros(6), add=True)  # the pose to pybullet
    plant.push_base(0, np.array([0.4, -0.5, 0.2, 0.52, -0.3, 0.78]), add=True)
    state = np.empty(13)
    plant._base_state(plant._worlds[0], state)
    np.testing.assert_allclose(state[7:13], d.qvel[:6], atol=1e-9)
    np.testing.assert_allclose(np.abs(state[3:7] @ d.qpos[3:7]), 1.0, atol=1e-9)
