"""LeRobot's policy folder read without lerobot (sim2real/deploy/spec/foreign/lerobot.py), on
folders written in tmp_path the way lerobot 0.4.4 writes them, and the action chunks the runtime
executes (sim2real/deploy/policy/action_chunks.py) against ACT's two schemes written out."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim2real.deploy.policy.action_chunks import ActionChunks
from sim2real.deploy.spec.foreign import lerobot as lr
from tests.lerobot_folder import write_act_folder


def test_reads_cameras_statistics_and_chunking(tmp_path):
    folder = write_act_folder(tmp_path / "pretrained_model", chunk_size=10, n_action_steps=5)
    assert lr.detect(folder)
    c = lr.read(folder, fps=30)
    assert c.policy_type == "act" and c.state_dim == 6 and c.action_dim == 6
    assert c.cameras == (
        ("observation.images.front", (3, 48, 64)),
        ("observation.images.wrist", (3, 48, 64)),
    )
    assert (c.chunk_size, c.n_action_steps, c.temporal_ensemble_coeff, c.fps) == (10, 5, None, 30)
    assert c.normalization["observation.images.front"].stats["mean"].shape == (3, 1, 1)
    np.testing.assert_allclose(c.normalization["action"].stats["std"], np.linspace(5, 20, 6))
    # the contract survives the trip through the ONNX metadata's JSON
    back = lr.LeRobotContract.from_json(c.to_json(), "x.onnx")
    assert back.cameras == c.cameras and back.fps == 30 and back.chunk_size == 10
    np.testing.assert_array_equal(
        back.normalization["observation.state"].stats["mean"],
        c.normalization["observation.state"].stats["mean"],
    )


def test_normalisation_is_lerobots(tmp_path):
    """MEAN_STD (x - mean) / (std + eps); MIN_MAX to [-1, 1]; each inverted exactly."""
    folder = write_act_folder(
        tmp_path / "m",
        norm_map={"VISUAL": "MEAN_STD", "STATE": "MIN_MAX", "ACTION": "MEAN_STD"},
    )
    c = lr.read(folder, fps=30)
    state = c.normalization["observation.state"]
    assert state.mode == "MIN_MAX"
    np.testing.assert_allclose(state.apply(np.full(6, 90.0, np.float32)), 1.0)
    np.testing.assert_allclose(state.apply(np.full(6, -90.0, np.float32)), -1.0)
    act = c.normalization["action"]
    y = np.arange(6, dtype=np.float32)
    np.testing.assert_allclose(act.invert(act.apply(y)), y, rtol=1e-5)
    np.testing.assert_allclose(act.apply(act.stats["mean"]), 0.0, atol=1e-6)


def test_fps_from_train_config_and_disagreement(tmp_path):
    folder = write_act_folder(tmp_path / "f", train_env_fps=50)
    assert lr.read(folder).fps == 50
    with pytest.raises(lr.LeRobotFormatError, match=r"train_config.json: env.fps 50.0 disagrees"):
        lr.read(folder, fps=30)
    assert lr.read(write_act_folder(tmp_path / "g")).fps is None


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"config_edits": {"type": "pi0"}}, r"config.json: type 'pi0' is not read"),
        ({"n_action_steps": 11}, r"config.json: n_action_steps 11 exceeds chunk_size 10"),
        (
            {"temporal_ensemble_coeff": 0.01, "n_action_steps": 5},
            r"config.json: temporal_ensemble_coeff needs n_action_steps 1, got 5",
        ),
        (
            {
                "config_edits": {
                    "input_features": {
                        "observation.images.top": {"type": "VISUAL", "shape": [48, 64]}
                    }
                }
            },
            r"input_features.observation.images.top: a VISUAL feature must be .* got \[48, 64\]",
        ),
        (
            {"pre_steps": [{"registry_name": "image_crop_processor", "config": {}}]},
            r"policy_preprocessor.json: steps\[0\].registry_name 'image_crop_processor' is not read",
        ),
        (
            {"drop_stats": ("observation.state.std",)},
            r"normalizer_processor.safetensors: observation.state.std missing \(MEAN_STD needs mean and std\)",
        ),
        (
            {"norm_map": {"VISUAL": "MEAN_STD", "STATE": "QUANTILES", "ACTION": "MEAN_STD"}},
            r"norm_map.STATE 'QUANTILES' is not read",
        ),
    ],
)
def test_refusals_name_file_and_field(tmp_path, kwargs, message):
    folder = write_act_folder(tmp_path / "bad", **kwargs)
    with pytest.raises(lr.LeRobotFormatError, match=message) as info:
        lr.read(folder, fps=30)
    assert "\n" not in str(info.value)


def test_not_a_folder_is_not_detected(tmp_path):
    assert not lr.detect(tmp_path)
    (tmp_path / "config.json").write_text(json.dumps({"type": "act"}))
    assert not lr.detect(tmp_path)


def test_queue_calls_once_per_n_action_steps():
    chunks = ActionChunks(chunk_size=10, n_action_steps=4)
    calls = []

    def predict():
        calls.append(len(calls))
        return np.arange(10, dtype=np.float32)[:, None] + 100 * len(calls)

    got = [float(chunks.step(predict)[0]) for _ in range(12)]
    # first 4 of each chunk, a new chunk every 4 ticks
    assert got == [100, 101, 102, 103, 200, 201, 202, 203, 300, 301, 302, 303]
    assert chunks.calls == 3


def test_temporal_ensembling_is_the_weighted_average_of_every_prediction():
    """The action at tick t is sum_i w_i a_i(t) / sum_i w_i over the chunks that predicted t,
    w_i = exp(-coeff i), w_0 the oldest (Algorithm 2 of the ACT paper, offline)."""
    k, coeff, ticks = 6, 0.3, 9
    rng = np.random.default_rng(0)
    preds = rng.standard_normal((ticks, k, 2)).astype(np.float32)  # chunk made at tick s
    chunks = ActionChunks(k, 1, coeff)
    it = iter(preds)
    for t in range(ticks):
        got = chunks.step(lambda: next(it))
        made = [s for s in range(ticks) if s <= t < s + k]
        w = np.exp(-coeff * np.arange(len(made)))
        want = sum(wi * preds[s][t - s] for wi, s in zip(w, made, strict=True)) / w.sum()
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
    assert chunks.calls == ticks


def test_chunks_state_round_trip():
    a = ActionChunks(5, 3)
    a.step(lambda: np.ones((5, 2)))
    b = ActionChunks(5, 3)
    b.load_state_dict(a.state_dict())
    assert not b.needs_call() and b.calls == 1
    with pytest.raises(ValueError, match=r"n_action_steps must be in \[1, chunk_size=5\]"):
        ActionChunks(5, 6)
