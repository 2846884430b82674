"""A LeRobot export as the runtime's policy (sim2real/deploy/policy/lerobot_policy.py): the
policy's rate beside the servo loop, one network call per chunk, LeRobot's SO-101 units, refusals
in one line, and the thin wrapper sim2real/eval/lerobot/action_chunks.py over deploy-run."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy
from sim2real.deploy.spec.foreign import lerobot as lr
from sim2real.robots import load_robot
from tests.lerobot_folder import write_chunk_onnx


@pytest.fixture(scope="module")
def so101():
    return load_robot("so101")


def _obs(policy, q):
    """The spec's observation of the joints ``q`` (rad): ``(q - offset) / scale``."""
    b = policy.spec.observation_blocks[0]
    return ((np.asarray(q) - np.asarray(b.offset)) / np.asarray(b.scale)).astype(np.float32)[None]


def test_policy_rate_and_one_call_per_chunk(tmp_path, so101):
    path = write_chunk_onnx(tmp_path / "ramp.onnx", chunk_size=4, n_action_steps=2, fps=25.0)
    policy = LeRobotChunkPolicy(path, so101)
    obs = _obs(policy, np.zeros(6))
    a = policy.spec.action
    targets, boundaries = [], []
    for k in range(40):  # 0.4 s of the 100 Hz servo loop beside a 25 Hz policy
        action = policy(obs)[0].astype(float)
        targets.append(np.asarray(a.offset) + np.asarray(a.scale) * action)
        if policy.new_chunk[0]:
            boundaries.append(k)
    assert policy.policy_ticks[0] == 10
    assert policy.calls[0] == 5  # n_action_steps 2: a call every other policy tick
    assert boundaries == [0, 8, 16, 24, 32]  # servo ticks: every 2 policy ticks of 4
    # held for 4 servo ticks, then the next action of the chunk: +2 deg on the arm joints
    np.testing.assert_allclose(targets[0], targets[3])
    np.testing.assert_allclose(targets[4][:5] - targets[0][:5], np.deg2rad(2.0), atol=1e-6)


def test_reset_takes_a_new_chunk_at_once(tmp_path, so101):
    policy = LeRobotChunkPolicy(write_chunk_onnx(tmp_path / "r.onnx", fps=25.0), so101)
    obs = _obs(policy, np.zeros(6))
    policy(obs), policy(obs)
    policy.reset(np.array([True]))
    policy(obs)
    assert policy.new_chunk[0] and policy.calls[0] == 2


def test_so101_units_round_trip(tmp_path, so101):
    policy = LeRobotChunkPolicy(write_chunk_onnx(tmp_path / "r.onnx"), so101)
    q = np.array([0.1, -0.2, 0.3, 0.0, 1.0, so101.position_lower[5]])
    lerobot = policy.to_lerobot(q)
    np.testing.assert_allclose(lerobot[:5], np.rad2deg(q[:5]), rtol=1e-6)
    assert lerobot[5] == pytest.approx(0.0)  # the gripper's lower limit is 0 %
    np.testing.assert_allclose(policy.to_joints(lerobot), q, atol=1e-6)


def test_the_camera_key_is_an_rgb_block(tmp_path, so101):
    policy = LeRobotChunkPolicy(
        write_chunk_onnx(tmp_path / "r.onnx", image_shape=(3, 6, 10)), so101
    )
    (block,) = policy.spec.images
    assert (block.input, block.camera, block.kind) == ("observation.images.front", "front", "rgb")
    assert block.shape == block.resize == (6, 10) and block.layout == "CHW"
    assert block.normalisation == "unit" and block.rate == 30.0
    assert policy.images["observation.images.front"].shape == (1, 1, 3, 6, 10)


def test_robot_without_lerobot_units_is_refused(tmp_path):
    with pytest.raises(lr.LeRobotFormatError, match=r"robot 'arm3' has no LeRobot joint units"):
        LeRobotChunkPolicy(write_chunk_onnx(tmp_path / "r.onnx"), load_robot("arm3"))


def test_onnx_policy_points_a_lerobot_export_to_its_loader(tmp_path, so101):
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.onnx_checks import PolicyLoadError

    path = write_chunk_onnx(tmp_path / "act.onnx")
    with pytest.raises(PolicyLoadError, match=r"a LeRobot export .* LeRobotChunkPolicy") as info:
        OnnxPolicy(path, so101)
    assert "\n" not in str(info.value)


def test_the_wrapper_runs_the_rig(tmp_path, capsys):
    from sim2real.eval.lerobot.action_chunks import main

    path = write_chunk_onnx(tmp_path / "act.onnx", image_shape=None, fps=25.0, n_action_steps=3)
    assert main([str(path), "--goals", "1"]) == 0
    out = capsys.readouterr().out
    assert "goals: 1 of 1 reached" in out or "goals: 0 of 1 reached" in out
    assert "policy at 25 Hz beside 100 Hz" in out and "policy ticks per chunk [3]" in out
    assert "command, smoothed" in out


def test_inspect_shows_the_lerobot_contract(tmp_path, capsys):
    from sim2real.deploy.cli.policy_export import EXIT_OK, main

    path = write_chunk_onnx(tmp_path / "act.onnx", chunk_size=6, n_action_steps=4, fps=30.0)
    assert main([str(path), "--inspect"]) == EXIT_OK
    out = capsys.readouterr().out
    assert "LeRobot ACT policy" in out
    assert "action queue (4 of 6 actions per call)" in out and "rate: 30.0 Hz" in out
    assert "camera observation.images.front: 3x8x8 float32 [0, 1] RGB CHW" in out
    assert "deploy-run --robot so101 --policy FILE" in out
