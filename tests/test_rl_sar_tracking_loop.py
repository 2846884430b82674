"""The bare rl_sar tracking loop (sim2real.stacks.loops.rl_sar_tracking), the reference deploy-run is held to on a
dance: its observation on the first control tick and its clip clock, against hand computations
from rl_sar's own dance_102 folder (fan-ziqi/rl_sar e384912, read from its checkout under ``SIM2REAL_STACKS``; skipped
without it). The anchor is computed here with scipy rotation matrices, not the loop's quaternions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sim2real.stacks.loops.rl_sar_motion import RlSarMotion, rl_sar_params
from sim2real.stacks.loops.rl_sar_tracking import observation

DANCE = "policy/g1/whole_body_tracking/dance_102"


@pytest.fixture(scope="module")
def dance(stacks, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("rl_sar")
    stacks.copy("rl_sar", [f"{DANCE}/config.yaml", f"{DANCE}/G1_Take_102.bvh_60hz.csv"], root)
    stacks.copy("rl_sar", ["policy/g1/base.yaml"], root)
    return root / DANCE


def csv_rows(folder: Path) -> np.ndarray:
    lines = (folder / "G1_Take_102.bvh_60hz.csv").read_text().split()
    return np.array([[float(v) for v in line.split(",")] for line in lines])


def torso(rotation: Rotation, waist) -> Rotation:
    """The G1 torso: pelvis, then waist yaw (z), roll (x), pitch (y) (g1_29dof.xml's axes)."""
    return rotation * Rotation.from_euler("ZXY", waist)


def test_first_tick_observation_is_rl_sars_from_the_csv(dance):
    """rl_sar's 154 entries on the tick the dance starts: the clip's frame 0 joints and forward
    difference at 50 Hz by ``joint_mapping``, the clip torso turned to the robot's heading seen
    from the robot torso (first two matrix columns, row-major), gyro, joints less the default."""
    _, params = rl_sar_params(dance)
    rows = csv_rows(dance)
    mapping = np.asarray(params["joint_mapping"])
    rng = np.random.default_rng(3)
    base = Rotation.from_euler("ZYX", [0.7, 0.05, -0.03])  # the robot turned 40 deg, tilted
    q = np.asarray(params["default_dof_pos"]) + rng.normal(0, 0.05, 29)  # policy order
    dq, gyro, last = rng.normal(0, 0.3, 29), rng.normal(0, 0.2, 3), rng.normal(0, 0.5, 29)
    waist = [q[list(mapping).index(i)] for i in (12, 13, 14)]
    x, y, z, w = base.as_quat()
    motion = RlSarMotion(dance / params["motion_file"], 50.0)
    motion.reset([w, x, y, z], waist)
    motion.update(0.0)
    obs = observation(params, motion, [w, x, y, z], gyro, q, dq, last)

    assert obs.shape == (154,) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[:29], rows[0, 7:][mapping], atol=1e-6)
    np.testing.assert_allclose(obs[29:58], (rows[1, 7:] - rows[0, 7:])[mapping] * 50.0, atol=1e-4)
    robot = torso(base, waist).as_matrix()
    clip = torso(Rotation.from_quat(rows[0, 3:7]), rows[0, 7 + 12 : 7 + 15]).as_matrix()
    heading = np.arctan2(robot[1, 0], robot[0, 0]) - np.arctan2(clip[1, 0], clip[0, 0])
    reference = Rotation.from_euler("z", heading).as_matrix() @ clip
    expected = (robot.T @ reference)[:, :2].reshape(-1)
    np.testing.assert_allclose(obs[58:64], expected, atol=1e-5)
    np.testing.assert_allclose(obs[64:67], gyro, atol=1e-6)
    np.testing.assert_allclose(obs[67:96], q - params["default_dof_pos"], atol=1e-6)
    np.testing.assert_allclose(obs[96:125], dq, atol=1e-6)
    np.testing.assert_allclose(obs[125:154], last, atol=1e-6)


def test_the_clip_clock_is_rl_sars_one_frame_per_tick_ending_at_frames_times_dt(dance):
    """rl_sar plays the clip at the control rate (50 Hz), its duration ``frames * dt``: tick k
    reads frame ``k (T - 1) / T``, interpolated, and the last frame at tick T."""
    _, params = rl_sar_params(dance)
    rows = csv_rows(dance)
    frames = len(rows)
    motion = RlSarMotion(dance / params["motion_file"], 50.0)
    assert frames == 1749 and motion.duration == pytest.approx(frames * 0.02)
    k = 1000
    motion.update(k * 0.02)
    at = k * (frames - 1) / frames
    i, blend = int(at), at - int(at)
    expected = rows[i, 7:] * (1 - blend) + rows[i + 1, 7:] * blend
    np.testing.assert_allclose(motion.joint_pos(), expected, atol=1e-9)
    motion.update(frames * 0.02)
    np.testing.assert_allclose(motion.joint_pos(), rows[-1, 7:], atol=1e-12)


@pytest.mark.nightly
def test_dance_102_plays_whole_in_the_bare_loop_on_unitree_mujocos_g1(stacks, dance, tmp_path):
    """The reference itself: rl_sar's dance_102 whole on unitree_mujoco's g1_29dof.xml, no fall."""
    pytest.importorskip("torch")
    from sim2real.stacks.loops.rl_sar_tracking import run

    stacks.copy("rl_sar", [f"{DANCE}/policy.pt"], dance.parents[3])
    stacks.copy("unitree_mujoco", ["unitree_robots/g1"], tmp_path)
    scene = tmp_path
    r = run(dance, scene / "unitree_robots/g1/scene_29dof.xml")
    assert not r["fell"] and r["share"] == 1.0
    assert r["rms"]["all"] < 0.15 and r["anchor_mean_deg"] < 6.0 and r["mpjpe_mm"] < 50.0
