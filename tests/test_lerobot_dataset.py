"""A LeRobot dataset written from our simulation (sim2real/eval/lerobot/dataset.py): the shipped
SO-101 reach policy as the demonstrator, recorded at 25 Hz in LeRobot's units; written and read
back with lerobot's own LeRobotDataset (skips, naming the extra, without it)."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.eval.lerobot.dataset import record_demonstrations, write_dataset


@pytest.fixture(scope="module")
def demonstrations(tmp_path_factory):
    pytest.importorskip("torch")
    from tests.runtime_fixtures import shipped_onnx

    out = shipped_onnx("so101", tmp_path_factory.mktemp("so101"))
    return record_demonstrations(out, "so101", seconds=12.0, fps=25.0, seed=0)


def test_demonstrations_are_episodes_per_goal_in_lerobots_units(demonstrations):
    episodes, goals = demonstrations
    assert goals["issued"] >= 2 and len(episodes) >= 2
    ep = episodes[1]  # a whole goal: 4 s at 25 Hz
    assert len(ep.state) == len(ep.action) == len(ep.goal) == 100
    assert all(np.array_equal(g, ep.goal[0]) for g in ep.goal)
    state = np.asarray(ep.state)
    # degrees: the arm's joints move by more than a radian's worth of numbers would allow
    assert np.abs(state[:, :5]).max() > 3.2
    assert (state[:, 5] >= -1).all() and (state[:, 5] <= 101).all()  # gripper percent


def test_dataset_written_and_read_by_lerobot(demonstrations, tmp_path):
    pytest.importorskip(
        "lerobot", reason="the extra 'lerobot' (lerobot's own classes) is not installed"
    )
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    episodes, _ = demonstrations
    write_dataset(episodes, tmp_path / "ds", fps=25.0)
    ds = LeRobotDataset("sim2real/so101_reach", root=tmp_path / "ds")
    assert ds.meta.fps == 25 and ds.meta.total_episodes == len(episodes)
    assert ds.meta.total_frames == sum(len(e.state) for e in episodes)
    item = ds[0]
    np.testing.assert_allclose(item["observation.state"].numpy(), episodes[0].state[0])
    assert ds.meta.features["observation.state"]["names"][0] == "shoulder_pan.pos"
