"""policy-export of a LeRobot ACT folder (sim2real/deploy/export/lerobot_act.py): folders written
in tmp_path by lerobot's own classes, exported and checked against lerobot's own select_action
(skips, naming the extra 'lerobot', without it); the refusals that need no lerobot run always."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from sim2real.deploy.cli.policy_export import EXIT_BAD_INPUT, EXIT_OK, main
from sim2real.deploy.spec.foreign import lerobot as lr
from tests.lerobot_folder import write_act_folder

HAS_LEROBOT = importlib.util.find_spec("lerobot") is not None


def lerobot_act_folder(
    folder, *, chunk_size=8, n_action_steps=3, coeff=None, seed=0, cameras=True, env_state=False
):
    """A small ACT policy saved by lerobot's ACTPolicy and processors (random weights; a
    ResNet-18 backbone without pretrained weights, as ACTConfig requires a ResNet); ``cameras``
    True: a front and a wrist camera, ``"front"``: the front one, False: none."""
    pytest.importorskip(
        "lerobot", reason="the extra 'lerobot' (lerobot's own classes) is not installed"
    )
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    from tests.lerobot_folder import stats

    torch.manual_seed(seed)
    shape = (3, 32, 40)
    cams = {"observation.images.front": shape, "observation.images.wrist": shape} if cameras else {}
    if cameras == "front":  # one camera
        cams = {"observation.images.front": shape}
    inputs = {"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(6,))}
    if env_state:
        inputs["observation.environment_state"] = PolicyFeature(type=FeatureType.ENV, shape=(3,))
    inputs.update({k: PolicyFeature(type=FeatureType.VISUAL, shape=s) for k, s in cams.items()})
    cfg = ACTConfig(
        input_features=inputs,
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(6,))},
        chunk_size=chunk_size,
        n_action_steps=n_action_steps,
        temporal_ensemble_coeff=coeff,
        dim_model=32,
        n_heads=2,
        dim_feedforward=64,
        n_encoder_layers=1,
        n_decoder_layers=1,
        latent_dim=8,
        pretrained_backbone_weights=None,
        device="cpu",
    )
    policy = ACTPolicy(cfg)
    flat = stats(cameras=cams)
    grouped: dict = {}
    for name, v in flat.items():
        key, _, stat = name.rpartition(".")
        grouped.setdefault(key, {})[stat] = torch.from_numpy(v)
    pre, post = make_pre_post_processors(cfg, dataset_stats=grouped)
    policy.save_pretrained(folder)
    pre.save_pretrained(folder)
    post.save_pretrained(folder)
    return folder


@pytest.mark.parametrize(
    ("n_action_steps", "coeff"), [(3, None), (1, 0.01)], ids=["queue", "temporal_ensembling"]
)
def test_act_folder_exports_with_parity_against_select_action(
    tmp_path, capsys, n_action_steps, coeff
):
    folder = lerobot_act_folder(
        tmp_path / "pretrained_model", n_action_steps=n_action_steps, coeff=coeff
    )
    out = tmp_path / "act.onnx"
    argv = [str(folder), "--robot", "so101", "--fps", "30", "--out", str(out)]
    assert main(argv) == EXIT_OK
    text = capsys.readouterr().out
    # 24 ticks: the queue calls the network every n_action_steps ticks, ensembling every tick
    calls = 24 // n_action_steps
    assert "parity vs lerobot's select_action: max |onnx - lerobot|" in text
    assert f"of the action's scale, over 24 ticks and {calls} network calls" in text
    c = lr.read_onnx(out)
    assert c.camera_keys == ("observation.images.front", "observation.images.wrist")
    assert (c.chunk_size, c.n_action_steps, c.temporal_ensemble_coeff, c.fps) == (
        8,
        n_action_steps,
        coeff,
        30.0,
    )
    np.testing.assert_allclose(c.normalization["action"].stats["std"], np.linspace(5, 20, 6))
    import onnxruntime as ort

    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == ["observation.state", *c.camera_keys]
    assert sess.get_outputs()[0].shape == [1, 8, 6]


def test_goal_conditioned_act_without_cameras(tmp_path):
    """observation.environment_state (a goal) instead of cameras: ACT's other input."""
    from sim2real.deploy.export.lerobot_act import PARITY_RTOL, export_lerobot_act

    folder = lerobot_act_folder(tmp_path / "pm", cameras=False, env_state=True, n_action_steps=4)
    result = export_lerobot_act(folder, tmp_path / "g.onnx", fps=25)
    assert result.max_rel_error <= PARITY_RTOL and result.calls == 6
    c = lr.read_onnx(result.path)
    assert c.env_state_dim == 3 and c.cameras == ()
    assert c.normalization["observation.environment_state"].mode == "IDENTITY"  # ENV: unmapped


def test_folder_without_fps_is_refused_in_one_line(tmp_path, capsys):
    folder = write_act_folder(tmp_path / "pretrained_model")
    assert main([str(folder), "--robot", "so101"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    assert "train_config.json has no env.fps" in err and "--fps" in err


def test_folder_of_the_wrong_robot_is_refused(tmp_path, capsys):
    folder = write_act_folder(tmp_path / "pretrained_model")
    assert main([str(folder), "--robot", "arm3", "--fps", "30"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip()
    assert "config.json: observation.state has 6 and action 6 entries, robot arm3 has" in err


@pytest.mark.skipif(HAS_LEROBOT, reason="lerobot is installed: the refusal is for its absence")
def test_without_lerobot_the_export_names_the_extra(tmp_path, capsys):
    folder = write_act_folder(tmp_path / "pretrained_model")
    assert main([str(folder), "--fps", "30"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip()
    assert "pip install 'sim2real-deploy[lerobot]'" in err and "\n" not in err


def test_an_exported_act_with_a_camera_runs_in_deploy_run_on_a_recorded_video(tmp_path, capsys):
    """lerobot's ACT with one camera, exported, through deploy-run on the plant with its camera
    from a video written by cv2.VideoWriter: a chunk every n_action_steps policy ticks, the
    video's frames taken; the same ACT with two cameras runs on the plant, which renders both of
    the SO-101 scene's cameras into it."""
    cv2 = pytest.importorskip("cv2", reason="OpenCV (the extra 'camera') is not installed")
    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.cli.run_verdict import EXIT_CLEAN, EXIT_FAULT

    folder = lerobot_act_folder(tmp_path / "pm", cameras="front", n_action_steps=3)
    out = tmp_path / "act.onnx"
    assert main([str(folder), "--robot", "so101", "--fps", "30", "--out", str(out)]) == EXIT_OK
    video = tmp_path / "front.mkv"
    w = cv2.VideoWriter(str(video), cv2.CAP_FFMPEG, cv2.VideoWriter_fourcc(*"FFV1"), 30, (40, 32))
    rng = np.random.default_rng(0)
    for _ in range(30):
        w.write(rng.integers(0, 255, (32, 40, 3), dtype=np.uint8))
    w.release()
    report = tmp_path / "r.json"
    argv = ["--backend", "sim", "--realtime", "--robot", "so101", "--policy", str(out),
            "--duration", "3", "--camera-source", f"front=opencv:{video},loop",
            "--overrun-limit", "1", "--report", str(report)]  # fmt: skip
    code = deploy_run_main(argv)
    import json

    r = json.loads(report.read_text())
    # a loaded machine may starve the video's decoder: a stale stop is the runtime's answer
    stale = r["faults"]["by_cause"]["stale_sensor"]
    assert code == EXIT_CLEAN or (code == EXIT_FAULT and r["faults"]["safe_stops"] == stale >= 1)
    assert r["chunks"]["policy_ticks_per_chunk"] == [3] and r["camera"]["frames_taken"][0] >= 15
    two = lerobot_act_folder(tmp_path / "pm2", cameras=True)
    out2 = tmp_path / "act2.onnx"
    assert main([str(two), "--robot", "so101", "--fps", "30", "--out", str(out2)]) == EXIT_OK
    report2 = tmp_path / "r2.json"
    argv = ["--backend", "sim", "--robot", "so101", "--policy", str(out2), "--duration", "1",
            "--report", str(report2)]  # fmt: skip
    assert deploy_run_main(argv) == EXIT_CLEAN
    cams = json.loads(report2.read_text())["camera"]
    assert set(cams) == {"front", "wrist"}
    assert all(c["frames_taken"][0] >= 25 for c in cams.values())  # 1 s at 30 fps
