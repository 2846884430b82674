"""The Go2 training recipe (sim2real.policies.train_legged): the learner acts inside the runtime's tick."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("stable_baselines3")

from sim2real.deploy.policy.mlp_checkpoint import read_checkpoint  # noqa: E402
from sim2real.deploy.policy.onnx_policy import OnnxPolicy  # noqa: E402
from sim2real.policies.train_legged import main  # noqa: E402
from sim2real.robots import load_robot  # noqa: E402


def test_training_acts_through_the_runtime_and_ships_generator_plus_residual(tmp_path, monkeypatch):
    """Two robots, two rollouts: the rollout buffer holds the observations the runtime built and
    the runtime received prior + residual; the candidate checkpoint is the trot generator plus
    the Gaussian mean, and its ONNX export computes the same action."""
    import sim2real.policies.train_legged as tl

    seen = {}
    collect = tl.RuntimePPO.collect_rollouts

    def spy(self, env, callback, buffer, n_rollout_steps):
        ok = collect(self, env, callback, buffer, n_rollout_steps)
        task = env.task
        seen["last_obs"] = buffer.observations[-1].copy()
        seen["runtime_obs"] = task.policy.obs.copy()
        seen["residual"] = np.clip(buffer.actions[-1], -tl.RESIDUAL_BOUND, tl.RESIDUAL_BOUND)
        seen["prior"] = self.prior(torch.as_tensor(task.policy.obs)).numpy()
        seen["action"] = task.runtime.action.copy()
        return ok

    monkeypatch.setattr(tl.RuntimePPO, "collect_rollouts", spy)
    main(
        ["--envs", "2", "--steps", "32", "--n-steps", "16", "--batch-size", "16"]
        + ["--epochs", "1", "--save-every", "0", "--logdir", str(tmp_path), "--gate-hours", "0"]
    )
    np.testing.assert_array_equal(seen["last_obs"], seen["runtime_obs"])
    np.testing.assert_allclose(seen["action"], seen["prior"] + seen["residual"], atol=1e-6)

    candidate = tmp_path / "go2_seed1.pt"
    ckpt = read_checkpoint(candidate)
    assert ckpt.actor.gait is not None
    go2 = load_robot("go2")
    obs = np.random.default_rng(0).normal(size=(3, ckpt.spec.obs_dim)).astype(np.float32)
    with torch.no_grad():
        expected = ckpt.actor(torch.as_tensor(obs)).numpy()
    onnx = OnnxPolicy(candidate.with_suffix(".onnx"), go2)
    np.testing.assert_allclose(onnx(obs), expected, atol=1e-5)


def test_a_candidate_ships_only_through_its_soak_gate(tmp_path):
    """make train ROBOT=go2 ends with the shipping soak over several seeds: --out is written
    only when the gate's report passed, and the gate's sessions are the seeds asked for."""
    import json

    out = tmp_path / "ship" / "go2.pt"
    args = ["--envs", "2", "--steps", "32", "--n-steps", "16", "--batch-size", "16"]
    args += ["--epochs", "1", "--save-every", "0", "--logdir", str(tmp_path), "--out", str(out)]
    code = main(args + ["--gate-hours", "0.001", "--gate-sessions", "2", "--gate-seed", "40"])
    report = json.loads((tmp_path / "go2_seed1.gate" / "report.json").read_text())
    assert [s["seed"] for s in report["sessions"]] == [40, 41]
    assert code == (0 if report["passed"] else 1)
    assert out.exists() == report["passed"]
    if out.exists():
        assert json.loads(out.with_suffix(".curve.json").read_text())["gate"]["passed"]


def test_fine_tuning_starts_from_the_shipped_actor_and_warms_the_critic_first(tmp_path):
    """--init-from sim2real/policies/go2.pt starts the Gaussian mean at the shipped actor: while the critic
    warms up (--critic-warmup) the actor does not move, so a run that is all warm-up writes a
    candidate equal to the shipped policy; after the warm-up it learns."""
    from pathlib import Path

    shipped = read_checkpoint(Path("sim2real/policies/go2.pt")).actor.state_dict()
    common = ["--envs", "2", "--n-steps", "16", "--batch-size", "16", "--epochs", "1"]
    common += ["--save-every", "0", "--gate-hours", "0", "--init-from", "sim2real/policies/go2.pt"]
    common += ["--initial-std", "0.2"]
    main(common + ["--steps", "32", "--critic-warmup", "32", "--logdir", str(tmp_path / "w")])
    warmed = read_checkpoint(tmp_path / "w" / "go2_seed1.pt").actor.state_dict()
    assert shipped.keys() == warmed.keys()
    for key in shipped:
        torch.testing.assert_close(warmed[key], shipped[key], rtol=0, atol=0)

    main(common + ["--steps", "64", "--critic-warmup", "32", "--logdir", str(tmp_path / "t")])
    tuned = read_checkpoint(tmp_path / "t" / "go2_seed1.pt").actor.state_dict()
    assert any(not torch.equal(tuned[k], shipped[k]) for k in shipped)


def test_fine_tuning_from_another_recipes_checkpoint_names_the_file(tmp_path):
    """A checkpoint of another robot or observation layout is refused before training starts."""
    with pytest.raises(ValueError, match=r"so101\.pt.*spec"):
        main(
            ["--envs", "2", "--steps", "16", "--n-steps", "8", "--batch-size", "16"]
            + [
                "--init-from",
                "sim2real/policies/so101.pt",
                "--logdir",
                str(tmp_path),
                "--gate-hours",
                "0",
            ]
        )


# The tests reading the module fixture scan_tuned: on one pytest-xdist worker (make test's
# --dist loadgroup), which builds it once, not once per worker.
ON_ONE_WORKER = pytest.mark.xdist_group("scan_tuned")


@pytest.fixture(scope="module")
def scan_tuned(tmp_path_factory):
    """A perceptive Go2 made by the recipe: --height-scan --init-from sim2real/policies/go2.pt,
    64 steps after a 32-step critic warm-up (and the warm-up alone beside it)."""
    from pathlib import Path

    tmp = tmp_path_factory.mktemp("scan")
    common = ["--envs", "2", "--n-steps", "16", "--batch-size", "16", "--epochs", "1"]
    common += ["--save-every", "0", "--gate-hours", "0", "--init-from", "sim2real/policies/go2.pt"]
    common += ["--height-scan", "--critic-warmup", "32"]
    main(common + ["--steps", "32", "--logdir", str(tmp / "w")])
    main(common + ["--steps", "96", "--logdir", str(tmp / "t")])
    shipped = read_checkpoint(Path("sim2real/policies/go2.pt"))
    return shipped, tmp / "w" / "go2_seed1.pt", tmp / "t" / "go2_seed1.pt"


@ON_ONE_WORKER
def test_a_height_scan_fine_tune_starts_blind_and_learns_weights_on_its_scan(scan_tuned):
    """--height-scan appends legged_gym's 187 terrain heights to the shipped spec: the fine-tune
    starts from the shipped actor with the scan's input weights at 0 (the warm-up's candidate
    acts as the shipped policy), and training gives them weights; the ONNX export carries the
    block and computes the candidate's action."""
    shipped, warmed, tuned = scan_tuned
    go2 = load_robot("go2")
    ckpt = read_checkpoint(tuned)
    blocks = ckpt.spec.observation_blocks
    assert blocks[-1].name == "height_scan" and blocks[-1].size == 187
    assert ckpt.spec.obs_dim == shipped.spec.obs_dim + 187
    blind = shipped.spec.obs_dim
    first = read_checkpoint(warmed).actor.net[0].weight.detach()
    assert torch.count_nonzero(first[:, blind:]) == 0
    torch.testing.assert_close(first[:, :blind], shipped.actor.net[0].weight, rtol=0, atol=0)
    weights = ckpt.actor.net[0].weight.detach()[:, blind:]
    assert torch.count_nonzero(weights) > 0.9 * weights.numel()
    onnx = OnnxPolicy(tuned.with_suffix(".onnx"), go2)
    assert onnx.spec.observation_blocks[-1].scan == blocks[-1].scan
    obs = np.random.default_rng(0).normal(size=(3, ckpt.spec.obs_dim)).astype(np.float32)
    with torch.no_grad():
        expected = ckpt.actor(torch.as_tensor(obs)).numpy()
    np.testing.assert_allclose(onnx(obs), expected, atol=1e-5)


@ON_ONE_WORKER
def test_the_tuned_policys_scan_on_a_stair_tile_is_the_truths_ray_casts_plus_its_noise(scan_tuned):
    """The fine-tuned policy's export run by the runtime on a 10 cm stairs-up tile: the scan the
    policy observes each tick is a noise-free scanner's ray casts on the tile from the same
    pose plus the stated uniform noise, seeded; the tile's steps are in it (not a plane's)."""
    import mujoco

    from sim2real.deploy.backends.sim.height_scan import HeightScanNoise, PlantHeightScanner
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.runtime import Mode, Runtime
    from sim2real.eval.world.terrain import apply_terrain, parse_terrain

    _, _, tuned = scan_tuned
    go2 = load_robot("go2")
    spec = go2.mjspec("position")
    ground = apply_terrain(spec, parse_terrain("stairs_up:0.10"), np.random.default_rng(0))
    plant = SimBackend(go2, "position", envs=1, models=[spec.compile()])
    plant.grounds = [ground]
    plant.datas[0].qpos[0] = 1.2  # near the platform's rim (1.5 m): the first steps ahead
    mujoco.mj_forward(plant.models[0], plant.datas[0])
    policy = OnnxPolicy(tuned.with_suffix(".onnx"), go2)
    pattern = policy.spec.observation_blocks[-1].scan
    truth = PlantHeightScanner(plant, pattern)
    plant.height_map_source = PlantHeightScanner(plant, pattern, HeightScanNoise(noise=0.05), 7)
    rt = Runtime(go2, policy, plant)
    rt.velocity_command[0] = (0.5, 0.0, 0.0)
    rt.start()
    draws = np.random.default_rng(7)
    for _ in range(5):
        expected = truth.true_scan().copy()  # the pose the tick's read casts from
        rt.run(1)
        error = rt.state.height_scan - expected
        np.testing.assert_allclose(error, draws.uniform(-0.05, 0.05, (1, 187)), rtol=0, atol=1e-9)
    assert np.ptp(expected) > 0.15  # the stairs' steps (0.1 m each) under the scan's points
    assert rt.mode[0] not in (Mode.SAFE_STOP, Mode.FAULTED)
