"""A LeRobot dataset written from our simulation (sim2real/eval/lerobot/dataset.py): the shipped
SO-101 reach policy as the demonstrator, recorded at 25 Hz in LeRobot's units with the task
scene's front and wrist cameras; written and read back with lerobot's own LeRobotDataset (skips,
naming the extra, without it); the cameras' videos."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.eval.lerobot.cameras import CAMERAS
from sim2real.eval.lerobot.dataset import record_demonstrations, write_dataset, write_videos

SHAPE = (24, 32)


@pytest.fixture(scope="module")
def demonstrations(tmp_path_factory):
    pytest.importorskip("torch")
    from tests.runtime_fixtures import shipped_onnx

    out = shipped_onnx("so101", tmp_path_factory.mktemp("so101"))
    return record_demonstrations(
        out, "so101", seconds=12.0, fps=25.0, seed=0, cameras=CAMERAS, shape=SHAPE
    )


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
    for name in CAMERAS:  # one frame per recorded tick, the camera's shape, not all alike
        frames = np.asarray(ep.images[name])
        assert frames.shape == (100, *SHAPE, 3) and frames.dtype == np.uint8
        assert np.abs(frames[-1].astype(int) - frames[0]).mean() > 1.0, name


def test_videos_of_an_episode(demonstrations, tmp_path):
    import cv2

    episodes, _ = demonstrations
    paths = write_videos(episodes[1], tmp_path, fps=25.0)
    assert sorted(p.name for p in paths) == sorted(f"{n}.mp4" for n in CAMERAS)
    for path in paths:
        cap = cv2.VideoCapture(str(path))
        frames = []
        while (ok_frame := cap.read())[0]:
            frames.append(ok_frame[1])
        cap.release()
        assert len(frames) == 100 and frames[0].shape == (*SHAPE, 3)
    with pytest.raises(ValueError, match="no camera frames"):
        write_videos(type(episodes[1])(), tmp_path, fps=25.0)


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
    for name in CAMERAS:  # lerobot's image feature, read back as (3, H, W) in [0, 1]
        key = f"observation.images.{name}"
        assert ds.meta.features[key]["dtype"] == "image"
        assert tuple(ds.meta.features[key]["shape"]) == (*SHAPE, 3)
        image = item[key].numpy()
        assert image.shape == (3, *SHAPE)
        np.testing.assert_allclose(
            image * 255, np.moveaxis(episodes[0].images[name][0], -1, 0), atol=0.51
        )
