"""LeRobot's Diffusion Policy: its folder exported to ONNX with the contract
(sim2real/deploy/export/lerobot_diffusion.py) and checked against lerobot's own select_action
with the same noise (folders written in tmp_path by lerobot's own classes; these skip, naming the
extra 'lerobot', without it: run them with lerobot's environment); the refusals of the folder's
config.json (no lerobot needed); and a Diffusion-Policy-shaped ONNX with the contract, built here,
through deploy-run on the simulated SO-101 (sim2real/deploy/policy/lerobot_diffusion_policy.py):
its history, its noise and its chunks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sim2real.deploy.cli.policy_export import EXIT_BAD_INPUT, EXIT_OK, main
from sim2real.deploy.spec.foreign import lerobot as lr
from tests.lerobot_folder import write_act_folder, write_diffusion_onnx


def lerobot_dp_folder(
    folder,
    *,
    scheduler="DDPM",
    cameras=True,
    env_state=True,
    steps=10,
    crop=(28, 36),
    seed=0,
    wrist=False,
):
    """A small Diffusion Policy saved by lerobot's DiffusionPolicy and processors (random
    weights; a ResNet-18 from scratch with GroupNorm, as DiffusionConfig's defaults; a 2-level
    U-Net of 16 and 32 channels): ``n_obs_steps`` 2, ``horizon`` 8, ``n_action_steps`` 4,
    ``steps`` training timesteps all used at inference; ``cameras`` a front camera of 3 x 32 x 40
    centre-cropped to ``crop`` (``wrist``: and a wrist camera, each with its own encoder:
    ``use_separate_rgb_encoder_per_camera``)."""
    pytest.importorskip(
        "lerobot", reason="the extra 'lerobot' (lerobot's own classes) is not installed"
    )
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
    from lerobot.policies.factory import make_pre_post_processors

    from tests.lerobot_folder import stats

    torch.manual_seed(seed)
    cams = {"observation.images.front": (3, 32, 40)} if cameras else {}
    if wrist:
        cams["observation.images.wrist"] = (3, 32, 40)
    inputs = {"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(6,))}
    if env_state:
        inputs["observation.environment_state"] = PolicyFeature(type=FeatureType.ENV, shape=(3,))
    inputs.update({k: PolicyFeature(type=FeatureType.VISUAL, shape=s) for k, s in cams.items()})
    cfg = DiffusionConfig(
        input_features=inputs,
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(6,))},
        n_obs_steps=2,
        horizon=8,
        n_action_steps=4,
        crop_shape=crop if cameras else None,
        spatial_softmax_num_keypoints=8,
        down_dims=(16, 32),
        kernel_size=3,
        n_groups=4,
        diffusion_step_embed_dim=16,
        noise_scheduler_type=scheduler,
        num_train_timesteps=steps,
        use_separate_rgb_encoder_per_camera=wrist,
        device="cpu",
    )
    policy = DiffusionPolicy(cfg)
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
    ("scheduler", "wrist"), [("DDPM", False), ("DDIM", True)], ids=["DDPM", "DDIM-two-cameras"]
)
def test_a_diffusion_folder_exports_with_parity_against_select_action(
    tmp_path, capsys, scheduler, wrist
):
    """Same noise in, same actions out: 24 ticks, a call every 4 (n_action_steps), the history of
    2 observations, the cameras' centre crop and ResNet (one shared, or one per camera), the
    unrolled sampler."""
    folder = lerobot_dp_folder(tmp_path / "pm", scheduler=scheduler, wrist=wrist)
    out = tmp_path / "dp.onnx"
    assert main([str(folder), "--robot", "so101", "--fps", "25", "--out", str(out)]) == EXIT_OK
    text = capsys.readouterr().out
    assert "over 24 ticks and 6 network calls" in text
    assert f"{scheduler} sampler, 10 denoising steps of 10" in text
    c = lr.read_onnx(out)
    assert (c.policy_type, c.n_obs_steps, c.horizon, c.chunk_size, c.n_action_steps) == (
        "diffusion", 2, 8, 5, 4,
    )  # fmt: skip
    assert c.diffusion["timesteps"] == list(range(9, -1, -1))
    noise = {"noise": [1, 8, 6]}
    if scheduler == "DDPM":
        noise["variance_noise"] = [10, 1, 8, 6]
    assert c.diffusion["noise_inputs"] == noise
    import onnxruntime as ort

    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    got = {i.name: i.shape for i in sess.get_inputs()}
    cams = ["front", "wrist"] if wrist else ["front"]
    assert got == {
        "observation.state": [1, 2, 6],
        "observation.environment_state": [1, 2, 3],
        **{f"observation.images.{c}": [1, 2, 3, 32, 40] for c in cams},
        **noise,
    }
    assert sess.get_outputs()[0].shape == [1, 5, 6]  # n_action_steps and the next one


def test_the_noise_changes_the_actions_and_the_parity_would_see_it(tmp_path):
    """The parity is not blind to the noise: the exported graph's chunk moves with its noise
    input (a sampler that ignored it would pass a same-noise check trivially)."""
    import onnxruntime as ort

    from sim2real.deploy.export.lerobot_diffusion import export_lerobot_diffusion

    folder = lerobot_dp_folder(tmp_path / "pm", scheduler="DDIM", cameras=False)
    r = export_lerobot_diffusion(folder, tmp_path / "dp.onnx", fps=25)
    assert r.max_rel_error <= 1e-4 and r.calls == 6
    sess = ort.InferenceSession(str(r.path), providers=["CPUExecutionProvider"])
    feed = {
        "observation.state": np.zeros((1, 2, 6), np.float32),
        "observation.environment_state": np.zeros((1, 2, 3), np.float32),
    }
    rng = np.random.default_rng(0)
    a = sess.run(None, feed | {"noise": rng.standard_normal((1, 8, 6), np.float32)})[0]
    b = sess.run(None, feed | {"noise": rng.standard_normal((1, 8, 6), np.float32)})[0]
    assert np.abs(a - b).max() > 1e-3


# ---------------------------------------------------------------- refusals (no lerobot)
def _dp_config(**edits):
    cfg = {
        "type": "diffusion",
        "n_obs_steps": 2,
        "horizon": 16,
        "n_action_steps": 8,
        "down_dims": [64, 128],
        "noise_scheduler_type": "DDPM",
        "num_train_timesteps": 100,
        "num_inference_steps": None,
        "beta_schedule": "squaredcos_cap_v2",
        "prediction_type": "epsilon",
        "clip_sample": True,
        "clip_sample_range": 1.0,
        "vision_backbone": "resnet18",
        "pretrained_backbone_weights": None,
        "resize_shape": None,
        "crop_shape": [40, 56],
        "use_group_norm": True,
        "compile_model": False,
    }
    cfg.update(edits)
    return cfg


def test_a_diffusion_folder_is_read_without_lerobot(tmp_path):
    folder = write_act_folder(tmp_path / "pm", config_edits=_dp_config(), train_env_fps=30)
    c = lr.read(folder)
    assert (c.policy_type, c.n_obs_steps, c.horizon, c.chunk_size, c.n_action_steps) == (
        "diffusion", 2, 16, 9, 8,
    )  # fmt: skip
    assert c.diffusion["num_inference_steps"] == 100 and c.diffusion["crop_shape"] == [40, 56]
    text = "\n".join(lr.describe(c))
    assert "8 of a horizon of 16 per call, from index 1" in text and "DDPM sampler" in text
    assert "centre-cropped to 40x56" in text


@pytest.mark.parametrize(
    "edit, said",
    [
        ({"noise_scheduler_type": "DPMSolver"}, "noise_scheduler_type 'DPMSolver' is not read"),
        ({"prediction_type": "v_prediction"}, "prediction_type 'v_prediction' is not read"),
        (
            {"pretrained_backbone_weights": "ResNet18_Weights.IMAGENET1K_V1"},
            "pretrained_backbone_weights 'ResNet18_Weights.IMAGENET1K_V1' is not read",
        ),
        ({"resize_shape": [96, 128]}, "resize_shape [96, 128] is not read (expected null"),
        ({"n_action_steps": 16}, "n_action_steps 16 exceeds horizon - n_obs_steps + 1 = 15"),
        ({"horizon": 10}, "horizon 10 must be a multiple of 2 ** len(down_dims) = 4"),
        ({"crop_shape": [50, 56]}, "crop_shape [50, 56] exceeds observation.images.front's"),
        ({"num_inference_steps": 200}, "num_inference_steps 200 exceeds num_train_timesteps"),
        ({"compile_model": True}, "compile_model true is not read (expected false)"),
    ],
    ids=[
        "scheduler",
        "prediction",
        "pretrained",
        "resize",
        "n_action_steps",
        "horizon",
        "crop",
        "steps",
        "compile",
    ],  # fmt: skip
)
def test_what_the_export_does_not_build_is_refused_in_one_line(tmp_path, capsys, edit, said):
    folder = write_act_folder(tmp_path / "pm", config_edits=_dp_config(**edit))
    assert main([str(folder), "--robot", "so101", "--fps", "30"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "config.json: " in err and said in err, err


# ---------------------------------------------------------------- the runtime (no lerobot)
def _run(tmp_path, policy, *extra):
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    report = tmp_path / "report.json"
    code = deploy_run_main(
        ["--robot", "so101", "--policy", str(policy), "--report", str(report), *extra]
    )
    return code, (json.loads(report.read_text()) if report.exists() else {})


def test_a_diffusion_export_runs_in_deploy_run_on_the_so101(tmp_path, capsys):
    """A DP-shaped graph (the newest state of the history plus 0.1 x its noise, over the
    executed slice): deploy-run --backend sim at 25 Hz beside 100 Hz, a chunk every
    n_action_steps policy ticks, each held target through the guard and the smoother."""
    from sim2real.deploy.cli.run_verdict import EXIT_CLEAN

    path = write_diffusion_onnx(tmp_path / "dp.onnx", fps=25.0)
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "3", "--goal-period", "1")
    err = capsys.readouterr().err
    assert code == EXIT_CLEAN, err
    assert "LeRobot diffusion policy at 25 Hz beside the servo loop" in err
    c = r["chunks"]
    # async inference (the default): a chunk asked one policy tick before it is taken plays
    # n_action_steps from its second action
    assert c["policy_ticks_per_chunk"] == [4] and c["servo_ticks_per_policy_tick"] == [4]
    assert r["final_state"] == ["RUNNING"] and r["violations"]["any"] == 0
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "3", "--inference", "sync")
    assert code == EXIT_CLEAN and r["chunks"]["policy_ticks_per_chunk"] == [4]


def test_the_history_and_the_noise_are_the_stages_state(tmp_path):
    """Two policies, one loaded with the other's state mid-run: the same actions after (the
    history, the queue and the noise's call count carried); the history holds the last
    n_obs_steps policy ticks' states, oldest first, filled with copies after a reset."""
    from sim2real.deploy.policy.lerobot_diffusion_policy import DiffusionChunkPolicy
    from sim2real.robots import load_robot

    so101 = load_robot("so101")
    path = write_diffusion_onnx(tmp_path / "dp.onnx", fps=25.0, n_obs_steps=3)
    a, b = DiffusionChunkPolicy(path, so101), DiffusionChunkPolicy(path, so101)
    dim = a.spec.obs_dim
    rng = np.random.default_rng(1)
    obs = [rng.uniform(-0.3, 0.3, (1, dim)).astype(np.float32) for _ in range(40)]
    a.reset()
    a(obs[0])
    h = a.history.stacked(0)["observation.state"]
    np.testing.assert_array_equal(h[0], h[2])  # filled with copies of the first
    for o in obs[1:9]:  # 9 servo ticks: policy ticks at 0, 4, 8
        a(o)
    h = a.history.stacked(0)["observation.state"]
    assert np.abs(h[1] - h[2]).max() > 0 and np.abs(h[0] - h[1]).max() > 0
    block = a.spec.observation_blocks[0]  # joint_position: value * scale + offset, rad
    assert block.name == "joint_position"
    q = obs[8][0, : block.size] * np.asarray(block.scale) + np.asarray(block.offset)
    np.testing.assert_allclose(h[2], a.to_lerobot(q), rtol=1e-5, atol=1e-4)
    b.load_state_dict(a.state_dict())
    for o in obs[9:]:
        np.testing.assert_array_equal(a(o), b(o))
        assert (a.new_chunk == b.new_chunk).all()
    assert a.calls[0] >= 3
    other = DiffusionChunkPolicy(path, so101, seed=1)
    fresh = DiffusionChunkPolicy(path, so101)
    x, y = other(obs[0]).copy(), fresh(obs[0]).copy()
    assert np.abs(x - y).max() > 0  # another seed, other noise


def test_an_act_export_is_not_taken_for_a_diffusion_one(tmp_path):
    from sim2real.deploy.policy.lerobot_diffusion_policy import DiffusionChunkPolicy
    from sim2real.robots import load_robot
    from tests.lerobot_folder import write_chunk_onnx

    path = write_chunk_onnx(tmp_path / "act.onnx", image_shape=None)
    with pytest.raises(lr.LeRobotFormatError, match="is not a Diffusion Policy export"):
        DiffusionChunkPolicy(path, load_robot("so101"))


def test_the_camera_history_holds_the_frames_of_the_last_policy_ticks(tmp_path):
    """The frames the camera stage wrote at the last n_obs_steps policy ticks, oldest first,
    are what the graph's image input gets (lerobot's image queue); frames written between
    policy ticks are not taken."""
    from sim2real.deploy.policy.lerobot_diffusion_policy import DiffusionChunkPolicy
    from sim2real.robots import load_robot

    path = write_diffusion_onnx(tmp_path / "cam.onnx", fps=25.0, image_shape=(3, 8, 10))
    p = DiffusionChunkPolicy(path, load_robot("so101"))
    key = "observation.images.front"
    obs = np.zeros((1, p.spec.obs_dim), np.float32)
    p.reset()
    for tick in range(9):  # policy ticks at servo ticks 0, 4, 8 (25 Hz beside 100 Hz)
        p.images[key][:] = float(tick)  # the camera stage's write before the tick
        p(obs)
    frames = p.history.stacked(0)[key]
    assert frames.shape == (2, 3, 8, 10)
    assert frames[0].max() == frames[0].min() == 4.0 and frames[1].min() == 8.0


def test_a_diffusion_export_with_a_camera_renders_it_on_the_plant(tmp_path):
    """deploy-run --backend sim renders the scene's front camera into the DP's image history."""
    from sim2real.deploy.cli.run_verdict import EXIT_CLEAN

    path = write_diffusion_onnx(tmp_path / "cam.onnx", fps=25.0, image_shape=(3, 48, 64))
    code, r = _run(tmp_path, path, "--backend", "sim", "--duration", "2")
    assert code == EXIT_CLEAN
    cam = r["camera"].get("front", r["camera"])
    assert cam["frames_taken"][0] >= 45  # 2 s at 25 Hz
    assert r["chunks"]["policy_ticks_per_chunk"] == [4]
