"""A LeRobot dataset written from our simulation (:func:`record_demonstrations`,
:func:`write_dataset`): a demonstrator policy (ours, e.g. the shipped SO-101 reach policy) run by
the runtime on the MuJoCo plant with the goal task, recorded at a policy rate and written with
lerobot's own ``LeRobotDataset`` (the extra ``lerobot``), so a user can train LeRobot's policies on
it and bring them back through ``policy-export``.

Features (LeRobot's units for the robot, :data:`~sim2real.deploy.policy.lerobot_policy.LEROBOT_UNITS`):
``observation.state`` the estimated joint positions; ``observation.environment_state`` the goal
(m, base frame, x y z); ``action`` the guard's joint target of that tick (what the servo loop
was told to reach). One episode per goal, its frames from the tick the goal was issued until the
next goal. No camera yet: the plant renders no RGB here (a camera feature joins when it does).

``python -m sim2real.eval.lerobot.dataset POLICY.onnx ROOT [--seconds S] [--fps F]``.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.rig.hooks import RunHook
from sim2real.deploy.rig.rig import Rig
from sim2real.robots import load_robot

#: The task string of every frame (LeRobot datasets carry one per frame).
TASK = "reach the goal with the end effector"


@dataclass
class Episode:
    """One goal's frames: state (k, n) and action (k, n) in LeRobot's units, goal (k, 3) m."""

    state: list = field(default_factory=list)
    goal: list = field(default_factory=list)
    action: list = field(default_factory=list)


class _Recorder(RunHook):
    """Every ``every``-th tick of a RUNNING env 0: its state, goal and target; a new episode when
    the goal changes."""

    def __init__(self, every: int, to_lerobot):
        self.every, self.to_lerobot, self.k = every, to_lerobot, 0
        self.episodes: list[Episode] = []
        self._goal = None

    def after_tick(self, runtime) -> None:
        k, self.k = self.k, self.k + 1
        if k % self.every or runtime.mode_names()[0] != "RUNNING":
            return None
        goal = runtime.goal[0].copy()
        if self._goal is None or not np.array_equal(goal, self._goal):
            self.episodes.append(Episode())
            self._goal = goal
        ep = self.episodes[-1]
        ep.state.append(self.to_lerobot(runtime.state.q[0]))
        ep.goal.append(goal.astype(np.float32))
        ep.action.append(self.to_lerobot(runtime.target[0]))
        return None


def record_demonstrations(
    onnx_path, robot_name: str = "so101", seconds: float = 60.0, fps: float = 25.0, seed: int = 0
) -> tuple[list[Episode], dict]:
    """Run the demonstrator ``seconds`` s with a new goal every 4 s (deploy-run's default) and
    record at ``fps`` (the control rate must be a multiple of it). Returns the episodes and the
    goal task's report (``issued``, ``reached``, ``success_rate``: the demonstrator's own)."""
    from sim2real.deploy.policy.lerobot_policy import LEROBOT_UNITS

    robot = load_robot(robot_name)
    rate = 1.0 / robot.control_period
    every = int(round(rate / fps))
    if abs(every * fps - rate) > 1e-6:
        raise ValueError(f"fps {fps} does not divide the control rate {rate} Hz")
    units = np.array([u == "deg" for u in LEROBOT_UNITS[robot_name]])
    lo, hi = np.asarray(robot.position_lower), np.asarray(robot.position_upper)

    def to_lerobot(q):
        return np.where(units, np.rad2deg(q), (q - lo) / (hi - lo) * 100.0).astype(np.float32)

    policy = OnnxPolicy(onnx_path, robot)
    backend = SimBackend(robot, envs=1, seed=seed)
    task = {"period": 4.0, "rng": np.random.default_rng(seed + 1), "schedule": False}
    rig = Rig(robot, policy, backend, envs=1, task=task)
    recorder = rig.add(_Recorder(every, to_lerobot))
    rig.start()
    rig.run(int(round(seconds * rate)))
    report = rig.report()
    rig.close()
    episodes = [e for e in recorder.episodes if len(e.state) >= 2]
    return episodes, report["goals"]


def write_dataset(episodes: list[Episode], root, fps: float, robot_name: str = "so101"):
    """Write ``episodes`` as a LeRobot dataset at ``root`` (a new folder) with lerobot's own
    ``LeRobotDataset.create``/``add_frame``/``save_episode``/``finalize``; returns the dataset.

    Raises:
        ImportError: lerobot is not installed (the extra ``lerobot``).
    """
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    robot = load_robot(robot_name)
    names = [f"{j}.pos" for j in robot.joint_names]  # lerobot's SO-101 feature names
    n = len(names)
    features = {
        "observation.state": {"dtype": "float32", "shape": (n,), "names": names},
        "observation.environment_state": {
            "dtype": "float32",
            "shape": (3,),
            "names": ["x", "y", "z"],
        },
        "action": {"dtype": "float32", "shape": (n,), "names": names},
    }
    ds = LeRobotDataset.create(
        repo_id=f"sim2real/{robot_name}_reach",
        fps=int(round(fps)),
        features=features,
        robot_type=robot_name,
        root=Path(root),
        use_videos=False,
    )
    for ep in episodes:
        for s, g, a in zip(ep.state, ep.goal, ep.action, strict=True):
            ds.add_frame(
                {
                    "observation.state": s,
                    "observation.environment_state": g,
                    "action": a,
                    "task": TASK,
                }
            )
        ds.save_episode()
    ds.finalize()
    return ds


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim2real.eval.lerobot.dataset", description=__doc__)
    p.add_argument("policy", help="the demonstrator's ONNX file (ours, with its PolicySpec)")
    p.add_argument("root", type=Path, help="the dataset folder to create")
    p.add_argument("--robot", default="so101")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    episodes, goals = record_demonstrations(
        args.policy, args.robot, args.seconds, args.fps, args.seed
    )
    ds = write_dataset(episodes, args.root, args.fps, args.robot)
    print(
        f"wrote {args.root}: {ds.meta.total_episodes} episodes, {ds.meta.total_frames} frames at "
        f"{args.fps:g} fps; the demonstrator reached {goals['reached']} of {goals['issued']} goals"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


def train_act(
    root,
    out,
    steps: int = 2000,
    batch_size: int = 64,
    chunk_size: int = 10,
    n_action_steps: int = 5,
    seed: int = 0,
    lr: float = 1e-3,
    log=print,
    log_every: int = 100,
):
    """A small ACT trained on the dataset at ``root`` with lerobot's own classes (``LeRobotDataset``
    with ACT's ``action_delta_indices``, ``make_pre_post_processors`` on the dataset's statistics,
    ``ACTPolicy.forward`` as the loss), its folder written as ``lerobot-train`` writes
    ``pretrained_model/`` (``save_pretrained`` of the policy and both processors) at ``out``.

    The frames are read once through ``LeRobotDataset`` and the steps drawn from memory:
    ``lerobot-train``'s data loader ran at 2-3 s per step on a busy 2-core machine.
    Returns the last step's loss.
    """
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    torch.manual_seed(seed)
    meta = LeRobotDatasetMetadata("sim2real/so101_reach", root=root)
    ft = meta.features
    cfg = ACTConfig(
        input_features={
            "observation.state": PolicyFeature(
                FeatureType.STATE, tuple(ft["observation.state"]["shape"])
            ),
            "observation.environment_state": PolicyFeature(
                FeatureType.ENV, tuple(ft["observation.environment_state"]["shape"])
            ),
        },
        output_features={"action": PolicyFeature(FeatureType.ACTION, tuple(ft["action"]["shape"]))},
        chunk_size=chunk_size,
        n_action_steps=n_action_steps,
        dim_model=128,
        n_heads=4,
        dim_feedforward=512,
        n_encoder_layers=2,
        n_decoder_layers=1,
        latent_dim=16,
        n_vae_encoder_layers=2,
        pretrained_backbone_weights=None,
        device="cpu",
        optimizer_lr=lr,
    )
    delta = {"action": [i / meta.fps for i in cfg.action_delta_indices]}
    ds = LeRobotDataset("sim2real/so101_reach", root=root, delta_timestamps=delta)
    keys = ("observation.state", "observation.environment_state", "action", "action_is_pad")
    rows = [ds[i] for i in range(len(ds))]
    data = {k: torch.stack([r[k] for r in rows]) for k in keys}
    policy = ACTPolicy(cfg)
    pre, post = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    opt = torch.optim.AdamW(policy.parameters(), lr=lr, weight_decay=cfg.optimizer_weight_decay)
    gen = torch.Generator().manual_seed(seed)
    policy.train()
    loss = float("nan")
    for step in range(steps):
        idx = torch.randint(0, len(rows), (batch_size,), generator=gen)
        batch = {k: v[idx] for k, v in data.items()}
        batch = pre(batch)  # as lerobot-train: the preprocessor on the whole batch
        out_loss, _ = policy.forward(batch)
        opt.zero_grad()
        out_loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), 10.0)
        opt.step()
        loss = float(out_loss.detach())
        if step % log_every == 0 or step == steps - 1:
            log(f"step {step}: loss {loss:.4f}")
    policy.eval()
    out = Path(out)
    policy.save_pretrained(out)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    return loss
