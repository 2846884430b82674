"""A small Diffusion Policy trained with lerobot's own classes on a dataset
:mod:`sim2real.eval.lerobot.dataset` wrote (:func:`train_diffusion`), its folder written as
``lerobot-train`` writes ``pretrained_model/``; then ``policy-export`` and ``deploy-run`` as any
LeRobot folder (docs/lerobot.md).

``python -m sim2real.eval.lerobot.train_diffusion ROOT OUT [--budget S]`` (lerobot's
environment).
"""

from __future__ import annotations

import argparse
from pathlib import Path


def train_diffusion(
    root,
    out,
    steps: int = 20000,
    batch_size: int = 64,
    n_obs_steps: int = 2,
    horizon: int = 16,
    n_action_steps: int = 8,
    down_dims: tuple[int, ...] = (64, 128, 256),
    scheduler: str = "DDIM",
    num_inference_steps: int = 10,
    seed: int = 0,
    lr: float = 1e-3,
    budget: float | None = None,
    log=print,
    log_every: int = 200,
):
    """Train a state-and-goal Diffusion Policy (``observation.state``,
    ``observation.environment_state``; no camera) on the dataset at ``root``; write its folder
    at ``out``.

    lerobot's ``LeRobotDataset`` with ``DiffusionConfig``'s ``observation_delta_indices`` and
    ``action_delta_indices`` (the ``n_obs_steps`` history and the ``horizon`` of actions from
    the oldest observation), ``make_pre_post_processors`` on the dataset's statistics and
    ``DiffusionPolicy.forward`` as the loss (the noise-prediction MSE at a random timestep);
    AdamW at ``lr`` with lerobot's DP betas and weight decay, gradient norm clipped at 10. The
    frames are read once and the steps drawn from memory. ``budget``: s of training at most.
    ``scheduler``/``num_inference_steps``: the sampler written in config.json (training is the
    same for DDPM and DDIM: both add noise with the same ``alphas_cumprod``).

    Returns:
        (last loss, steps taken).
    """
    import time

    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy
    from lerobot.policies.factory import make_pre_post_processors

    torch.manual_seed(seed)
    meta = LeRobotDatasetMetadata("sim2real/so101_reach", root=root)
    ft = meta.features
    inputs = {
        k: PolicyFeature(t, tuple(ft[k]["shape"]))
        for k, t in (
            ("observation.state", FeatureType.STATE),
            ("observation.environment_state", FeatureType.ENV),
        )
    }
    cfg = DiffusionConfig(
        input_features=inputs,
        output_features={"action": PolicyFeature(FeatureType.ACTION, tuple(ft["action"]["shape"]))},
        n_obs_steps=n_obs_steps,
        horizon=horizon,
        n_action_steps=n_action_steps,
        down_dims=tuple(down_dims),
        diffusion_step_embed_dim=64,
        noise_scheduler_type=scheduler,
        num_inference_steps=num_inference_steps,
        device="cpu",
        optimizer_lr=lr,
    )
    delta = {k: [i / meta.fps for i in cfg.observation_delta_indices] for k in inputs}
    delta["action"] = [i / meta.fps for i in cfg.action_delta_indices]
    ds = LeRobotDataset("sim2real/so101_reach", root=root, delta_timestamps=delta)
    keys = [*inputs, "action", "action_is_pad"]
    data = {k: [] for k in keys}
    for i in range(len(ds)):
        row = ds[i]
        for k in keys:
            data[k].append(row[k])
    data = {k: torch.stack(v) for k, v in data.items()}
    policy = DiffusionPolicy(cfg)
    pre, post = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    opt = torch.optim.AdamW(
        policy.get_optim_params(),
        lr=lr,
        betas=cfg.optimizer_betas,
        eps=cfg.optimizer_eps,
        weight_decay=cfg.optimizer_weight_decay,
    )
    gen = torch.Generator().manual_seed(seed)
    policy.train()
    loss, taken, n = float("nan"), 0, len(data["action"])
    start = time.monotonic()
    for step in range(steps):
        if budget is not None and time.monotonic() - start > budget:
            log(f"step {step}: the budget of {budget:g} s is spent")
            break
        idx = torch.randint(0, n, (batch_size,), generator=gen)
        batch = pre({k: v[idx] for k, v in data.items()})
        out_loss, _ = policy.forward(batch)
        opt.zero_grad()
        out_loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), 10.0)
        opt.step()
        loss, taken = float(out_loss.detach()), step + 1
        if step % log_every == 0 or step == steps - 1:
            log(f"step {step}: loss {loss:.4f} ({time.monotonic() - start:.0f} s)")
    policy.eval()
    out = Path(out)
    policy.save_pretrained(out)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    return loss, taken


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("root", type=Path, help="the dataset (python -m sim2real.eval.lerobot.dataset)")
    p.add_argument("out", type=Path, help="the pretrained_model folder to write")
    p.add_argument("--steps", type=int, default=20000)
    p.add_argument("--budget", type=float, default=None, help="s of training at most")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    args = p.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    loss, taken = train_diffusion(args.root, args.out, steps=args.steps, budget=args.budget)
    print(f"{taken} steps, last loss {loss:.4f}; wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
