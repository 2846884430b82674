"""A LeRobot export run beside the servo loop (sim2real/deploy/policy/lerobot_policy.py,
sim2real/eval/lerobot/action_chunks.py): the policy's rate, one network call per chunk, LeRobot's SO-101
units, and the smoother's bound on the jerk at chunk boundaries, on the MuJoCo SO-101."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy
from sim2real.deploy.spec.foreign import lerobot as lr
from sim2real.eval.lerobot.action_chunks import boundary_jerk, jerk, run_chunks
from sim2real.robots import load_robot
from tests.lerobot_folder import write_chunk_onnx


@pytest.fixture(scope="module")
def so101():
    return load_robot("so101")


def test_policy_rate_and_one_call_per_chunk(tmp_path, so101):
    path = write_chunk_onnx(tmp_path / "ramp.onnx", chunk_size=4, n_action_steps=2, fps=25.0)
    policy = LeRobotChunkPolicy(path, so101)
    frames = {"observation.images.front": np.zeros((3, 8, 8), np.float32)}
    q = np.zeros(6)
    dt = so101.control_period  # 100 Hz servo loop beside a 25 Hz policy
    targets = [policy.step(k * dt, q, frames).copy() for k in range(40)]
    assert policy.policy_ticks == 10  # 0.4 s at 25 Hz
    assert policy.chunks.calls == 5  # n_action_steps 2: a call every other policy tick
    assert policy.boundaries == [0, 2, 4, 6, 8]
    # held for 4 servo ticks, then the next action of the chunk: +2 deg on the arm joints
    np.testing.assert_array_equal(targets[0], targets[3])
    np.testing.assert_allclose(targets[4][:5] - targets[0][:5], np.deg2rad(2.0))


def test_so101_units_round_trip(tmp_path, so101):
    policy = LeRobotChunkPolicy(write_chunk_onnx(tmp_path / "r.onnx"), so101)
    q = np.array([0.1, -0.2, 0.3, 0.0, 1.0, so101.position_lower[5]])
    lerobot = policy.to_lerobot(q)
    np.testing.assert_allclose(lerobot[:5], np.rad2deg(q[:5]), rtol=1e-6)
    assert lerobot[5] == pytest.approx(0.0)  # the gripper's lower limit is 0 %
    np.testing.assert_allclose(policy.to_joints(lerobot), q, atol=1e-6)


def test_wrong_frame_shape_is_refused(tmp_path, so101):
    policy = LeRobotChunkPolicy(write_chunk_onnx(tmp_path / "r.onnx"), so101)
    with pytest.raises(
        ValueError,
        match=r"camera observation.images.front: frame of shape \(3, 4, 4\), expected \(3, 8, 8\)",
    ):
        policy.step(0.0, np.zeros(6), {"observation.images.front": np.zeros((3, 4, 4))})


def test_robot_without_lerobot_units_is_refused(tmp_path):
    with pytest.raises(lr.LeRobotFormatError, match=r"robot 'arm3' has no LeRobot joint units"):
        LeRobotChunkPolicy(write_chunk_onnx(tmp_path / "r.onnx"), load_robot("arm3"))


def test_the_smoother_bounds_the_jerk_of_a_chunk_boundary(tmp_path, so101):
    """A chunk is a ramp and the next one starts again from the state: written straight to the
    servos the arm jerks at every boundary; through Ruckig the command's jerk stays within the
    robot's jerk limit."""
    path = write_chunk_onnx(tmp_path / "ramp.onnx", chunk_size=6, n_action_steps=4, step_deg=1.5)
    raw = run_chunks(path, "so101", seconds=1.5, smoothing=False, seed=0)
    smooth = run_chunks(path, "so101", seconds=1.5, smoothing=True, seed=0)
    assert raw.calls == smooth.calls == int(np.ceil(raw.policy_ticks / 4))
    limit = float(np.max(so101.jerk_limit))
    assert np.abs(jerk(smooth.command, smooth.dt)).max() <= limit * 1.01
    f_raw, f_smooth = boundary_jerk(raw, "command"), boundary_jerk(smooth, "command")
    assert f_raw["boundary_median"] > 5 * f_smooth["boundary_median"]


def test_deploy_run_refuses_a_lerobot_export_in_one_line(tmp_path, so101):
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.onnx_checks import PolicyLoadError

    path = write_chunk_onnx(tmp_path / "act.onnx")
    with pytest.raises(
        PolicyLoadError,
        match=r"a LeRobot export .* `python -m sim2real.eval.lerobot.action_chunks ",
    ) as info:
        OnnxPolicy(path, so101)
    assert "\n" not in str(info.value)


def test_inspect_shows_the_lerobot_contract(tmp_path, capsys):
    from sim2real.deploy.cli.policy_export import EXIT_OK, main

    path = write_chunk_onnx(tmp_path / "act.onnx", chunk_size=6, n_action_steps=4, fps=30.0)
    assert main([str(path), "--inspect"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "LeRobot ACT policy" in out
    assert "action queue (4 of 6 actions per call)" in out and "rate: 30.0 Hz" in out
    assert "camera observation.images.front: 3x8x8 float32 [0, 1] RGB CHW" in out
