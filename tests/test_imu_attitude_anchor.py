"""The IMU's own attitude as the robot senses it, and the motion-tracking anchor built from it.

- The simulated IMU's quaternion is the true attitude within its modelled roll/pitch error and,
  with ``heading_rate_sigma``, a heading error that drifts as modelled: a turn-on yaw-rate bias
  of that spread, held, plus an angle random walk (``heading_walk``).
- The runtime keeps the base orientation that quaternion gives (``RobotState.
  sensed_orientation``) where robot.toml says the IMU sends one, and a motion-tracking policy's
  anchor (``motion_anchor_ori_b``) and the clip's yaw alignment read it, not the base estimate's
  (rl_sar's G1 loop: ``base_quat = imu_state.quaternion``); without an attitude, the estimate's.

On the shipped go2 (its IMU sends an attitude) with a synthetic clip: no mirror needed.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.attitude import quat_multiply, quaternion_to_matrix, yaw_of
from sim2real.deploy.spec.motion_blocks import (
    anchor_ori_b,
    axis_quat,
    motion_anchor_ori_b,
    torso_quat,
)
from sim2real.robots import load_robot
from sim2real.robots.schema import ImuConfig

#: the go2's joints standing in for a humanoid's waist (yaw, roll, pitch)
WAIST = (0, 1, 2)


def _read_errors(plant, ticks: int) -> tuple[np.ndarray, np.ndarray]:
    """(ticks, envs, 3) the IMU attitude's error from the truth, rad, about the world's x, y
    (small) and z (the heading: any size) axes, holding the home pose; (ticks, envs) the
    model's heading error at each reading."""
    robot = plant.robot
    site = robot.mj_model.site_quat[robot.imu_site_id]
    target = np.tile(robot.home, (plant.envs, 1))
    out, model = [], []
    for _ in range(ticks):
        frame = plant.read()
        model.append(plant.base_sensors.heading_error.copy())
        true = quat_multiply(plant.true_base_state()[:, 3:7], np.tile(site, (plant.envs, 1)))
        rel = quaternion_to_matrix(frame.imu_orientation) @ quaternion_to_matrix(true).transpose(
            0, 2, 1
        )
        out.append(
            np.stack([rel[:, 2, 1], rel[:, 0, 2], np.arctan2(rel[:, 1, 0], rel[:, 0, 0])], axis=1)
        )
        plant.write(target)
        plant.advance()
    return np.array(out), np.array(model)


def _drifting(go2, envs: int, rate_sigma: float, walk: float, seed: int) -> SimBackend:
    plant = SimBackend(go2, "position", envs=envs, seed=seed)
    sensors = plant.base_sensors
    sensors.has_heading = True
    sensors.heading_rate_sigma[:] = rate_sigma
    sensors.heading_walk[:] = walk
    plant.reset()
    return plant


def test_the_imus_heading_drifts_by_its_rate_bias_and_walk(go2):
    """The reported heading errs from the truth by exactly the model's heading error (roll and
    pitch stay within their spread), which grows by the turn-on rate bias (held) times t plus a
    random walk of variance ``walk^2 t``; the rate biases drawn at turn-on spread as
    ``heading_rate_sigma``."""
    envs, ticks = 4, 400
    rate_sigma, walk = 0.02, 0.01  # rad/s, rad/sqrt(s): large enough to see in 8 s
    plant = _drifting(go2, envs, rate_sigma, walk, seed=5)
    sensors = plant.base_sensors
    rate = sensors.heading_rate.copy()
    assert np.all(rate != 0.0)
    err, model = _read_errors(plant, ticks)
    dt = go2.control_period
    sigma = go2.config.sensors.imu.orientation_sigma
    assert np.abs(err[:, :, :2]).max() < 5 * sigma  # roll and pitch: their own spread
    # the heading error the reading carries is the model's (to second order in roll x pitch)
    assert np.abs(err[:, :, 2] - model).max() < 1e-3
    assert np.abs(model[-1]).max() > 0.05  # it drifted
    np.testing.assert_array_equal(sensors.heading_rate, rate)  # held between resets
    t = dt * np.arange(1, ticks + 1)[:, None]
    walked = err[:, :, 2] - rate * t  # the walk alone: increments of variance walk^2 dt
    steps = np.diff(walked, axis=0).ravel()
    assert abs(np.var(steps) / (walk**2 * dt) - 1) < 3 * np.sqrt(2 / steps.size)
    assert abs(np.mean(steps)) < 4 * walk * np.sqrt(dt / steps.size)
    # the turn-on rate biases: N(0, rate_sigma^2), drawn anew at each reset
    draws = []
    for _ in range(250):
        sensors.reset(np.ones(envs, dtype=bool), full=True)
        draws.append(sensors.heading_rate.copy())
    draws = np.concatenate(draws)
    assert abs(draws.std() / rate_sigma - 1) < 0.1 and abs(draws.mean()) < 0.2 * rate_sigma


def test_without_a_heading_drift_the_imus_heading_is_the_truths(go2_true_heading):
    """robot.toml without ``heading_rate_sigma``: the attitude's heading is the true one."""
    plant = SimBackend(go2_true_heading, "position", envs=2, seed=3)
    plant.reset()
    assert not plant.base_sensors.has_heading
    err, _ = _read_errors(plant, 100)
    assert np.abs(err[:, :, 2]).max() < 1e-3


def test_a_heading_drift_without_an_attitude_is_refused():
    with pytest.raises(ValueError, match="heading_rate_sigma needs orientation_sigma"):
        ImuConfig(gyro_noise_sigma=0.01, accel_noise_sigma=0.1, rate=50.0, heading_rate_sigma=1e-4)


def _state(base, sensed, waist, reference):
    n = 4
    motion = np.zeros((1, 2 * n + 4))
    motion[0, 2 * n :] = reference
    q = np.zeros((1, n))
    q[0, :3] = waist
    return SimpleNamespace(
        q=q, motion=motion, base=SimpleNamespace(orientation=base[None]),
        sensed_orientation=None if sensed is None else sensed[None],
    )  # fmt: skip


def test_the_anchor_block_reads_the_sensed_orientation_where_there_is_one():
    """``motion_anchor_ori_b`` builds the torso from the IMU's attitude when the state has one
    (it fails if the estimate is read), and from the estimate when it has none."""
    block = SimpleNamespace(joints=np.array([0, 1, 2]), kind=SimpleNamespace(name="anchor"))
    estimate = axis_quat(2, 0.0)
    sensed = quat_multiply(axis_quat(2, 0.7), axis_quat(0, 0.05))
    waist = np.array([0.1, -0.05, 0.2])
    reference = axis_quat(2, 0.3)
    for source, other in ((sensed, estimate), (None, estimate)):
        state = _state(estimate, source, waist, reference)
        raw = np.zeros((1, 6))
        motion_anchor_ori_b(state, None, raw, block, None, None)
        base = estimate if source is None else source
        want = anchor_ori_b(torso_quat(base[None], waist[None]), reference[None])
        np.testing.assert_allclose(raw, want, atol=1e-12)
        if source is not None:
            wrong = anchor_ori_b(torso_quat(other[None], waist[None]), reference[None])
            assert np.abs(raw - wrong).max() > 0.1


def test_a_robot_without_an_attitude_has_no_sensed_orientation(go2, tmp_path):
    from sim2real.deploy.kinds.legged import LEGGED

    assert LEGGED.state(go2, 2).sensed_orientation is not None
    text = (go2.directory / "robot.toml").read_text()
    # without the attitude, none of its heading's drift either (robot.toml refuses one alone)
    lines = [ln for ln in text.splitlines() if not ln.startswith(("orientation_", "heading_"))]
    folder = tmp_path / "go2"
    folder.mkdir()
    for f in go2.directory.iterdir():
        if f.is_file() and f.name != "robot.toml":
            (folder / f.name).write_bytes(f.read_bytes())
    (folder / "robot.toml").write_text("\n".join(lines) + "\n")
    bare = load_robot(folder)
    assert bare.config.sensors.imu.orientation_sigma is None
    assert LEGGED.state(bare, 2).sensed_orientation is None


def _rig(go2, go2_onnx, tmp_path, heading: float):
    """A one-env go2 rig with the ``tracking`` task on a 0.8-s synthetic clip played in a loop
    (each play aligned anew), whose IMU heading is off the truth by ``heading`` rad (held: no
    drift, no walk) from its second reading on."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.rig.rig import Rig
    from sim2real.deploy.tasks.motion.clip import MotionClip
    from sim2real.deploy.tasks.motion.clock import MotionClock

    frames = 40
    pos = np.tile(go2.home, (frames, 1)) + 0.05 * np.sin(np.arange(frames))[:, None]
    root = np.array([axis_quat(2, 0.01 * k) for k in range(frames)])
    clip = MotionClip(
        source=tmp_path / "clip.csv", fps=50.0, joint_names=tuple(go2.joint_names),
        joint_pos=pos, joint_vel=np.gradient(pos, axis=0) * 50.0,
        root_pos=np.zeros((frames, 3)), root_quat=root,
    )  # fmt: skip
    names = tuple(go2.joint_names[i] for i in WAIST)
    clock = MotionClock(clip, go2.joint_names, names, 1, "loop", go2.home, 0.2, 0.2)
    backend = _drifting(go2, 1, 0.0, 0.0, seed=0)
    task = {"period": 1.0, "rng": np.random.default_rng(0), "task": "tracking"}
    rig = Rig(
        go2, OnnxPolicy(go2_onnx, go2), backend, envs=1, task={**task, "motion": (clock, WAIST)}
    )
    backend.base_sensors.heading_error[:] = heading
    rig.start()
    return rig


def test_the_clip_is_aligned_to_and_judged_against_the_sensed_heading(go2, go2_onnx, tmp_path):
    """With the IMU's heading 1 rad off the truth (the estimator's is not: it reads only the
    attitude's tilt; the go2 walker reads no heading, so both runs move alike), the runtime's
    sensed orientation carries that heading, the clip's next play is yaw-aligned to the torso
    it gives (its anchor 1 rad turned from a run whose IMU heading is the truth's; the same
    anchor if the estimate were read), and the judged anchor error (the true torso against the
    clip turned by the sensed heading's error at the alignment) is that run's."""
    anchors, judged = {}, {}
    n = go2.n_joints
    for heading in (0.0, 1.0):
        rig = _rig(go2, go2_onnx, tmp_path, heading)
        rt = rig.runtime
        for _ in range(5):
            rt.tick()
            rig.monitor(rt)
        state = rt.state
        true_yaw = yaw_of(rig.backend.true_base_state()[:, 3:7])
        turn = yaw_of(state.sensed_orientation) - true_yaw - heading
        assert abs(np.angle(np.exp(1j * turn)))[0] < 0.02
        assert abs(yaw_of(state.base.orientation) - true_yaw)[0] < 0.02
        for _ in range(95):  # the first play (aligned to the first reading), then the next
            rt.tick()
            rig.monitor(rt)
        assert rig.task.motion.time[0] < 0.8 and len(rig.task.play_log[0]) >= 2
        anchors[heading] = state.motion[0, 2 * n : 2 * n + 4].copy()
        summary = rig.task.summary()
        assert summary["ticks"] > 0
        judged[heading] = summary["anchor_error_deg_mean"]
    turned = quat_multiply(axis_quat(2, 1.0), anchors[0.0])
    assert min(np.abs(turned - anchors[1.0]).max(), np.abs(turned + anchors[1.0]).max()) < 0.02
    assert judged[1.0] == pytest.approx(judged[0.0], abs=0.5), judged


def test_the_heading_drift_resumes_from_the_plants_state_dict(go2):
    """The heading's rate bias and error are the plant's state: a plant of another seed loaded
    with the first's state dict reports the same attitudes after (a soak's resume)."""
    first = _drifting(go2, 2, 0.02, 0.01, seed=1)
    _read_errors(first, 20)
    saved = first.state_dict()
    assert "imu/heading_error" in saved and "imu/heading_rate" in saved
    again = _drifting(go2, 2, 0.03, 0.02, seed=9)
    again.load_state_dict(saved)
    np.testing.assert_array_equal(again.base_sensors.heading_rate, first.base_sensors.heading_rate)
    a, _ = _read_errors(first, 30)
    b, _ = _read_errors(again, 30)
    np.testing.assert_array_equal(a, b)
