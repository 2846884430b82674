"""A LeRobot dataset written from our simulation (:func:`record_demonstrations`,
:func:`write_dataset`): a demonstrator policy (ours, e.g. the shipped SO-101 reach policy) run by
the runtime on the MuJoCo plant with the goal task, recorded at a policy rate and written with
lerobot's own ``LeRobotDataset`` (the extra ``lerobot``), so a user can train LeRobot's policies on
it and bring them back through ``policy-export``.

Features (LeRobot's units for the robot, :data:`~sim2real.deploy.policy.lerobot_policy.LEROBOT_UNITS`):
``observation.state`` the estimated joint positions; ``observation.environment_state`` the goal
(m, base frame, x y z); ``action`` the guard's joint target of that tick (what the servo loop
was told to reach); with ``cameras``, ``observation.images.<name>`` per camera (the SO-101's
``front`` and ``wrist``, :mod:`sim2real.eval.lerobot.cameras`: the plant's colour cameras
rendering the robot's task scene, the goal marker at the goal), uint8 (rows, columns, 3) R, G, B
of the plant as the tick read it, captured at the dataset's fps. One episode per goal, its frames
from the tick the goal was issued until the next goal.

``python -m sim2real.eval.lerobot.dataset POLICY.onnx ROOT [--seconds S] [--fps F] [--cameras]
[--videos DIR]``; ``--videos`` also writes ``<name>.mp4`` of each camera for one episode.
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
from sim2real.eval.lerobot.cameras import CAMERAS, KEY, SHAPE, SceneCameras
from sim2real.robots import load_robot

#: The task string of every frame (LeRobot datasets carry one per frame).
TASK = "reach the goal with the end effector"


@dataclass
class Episode:
    """One goal's frames: state (k, n) and action (k, n) in LeRobot's units, goal (k, 3) m;
    images: per camera name, k uint8 (rows, columns, 3) frames (empty without cameras)."""

    state: list = field(default_factory=list)
    goal: list = field(default_factory=list)
    action: list = field(default_factory=list)
    images: dict = field(default_factory=dict)


class _Recorder(RunHook):
    """Every ``every``-th tick of a RUNNING env 0: its state, goal and target, and the cameras'
    frames of the plant as that tick read it (rendered after the tick before: the plant has
    advanced past the tick's read when its hooks run); a new episode when the goal changes."""

    def __init__(self, every: int, to_lerobot, cameras=None, dt: float = 0.0):
        self.every, self.to_lerobot, self.k = every, to_lerobot, 0
        self.cameras, self.dt = cameras, dt
        self.episodes: list[Episode] = []
        self._goal = None
        self._pending = None

    def after_tick(self, runtime) -> None:
        k, self.k = self.k, self.k + 1
        images, self._pending = self._pending, None
        if self.cameras is not None and (k + 1) % self.every == 0:
            # the plant now is what tick k + 1 reads; the goal now is the one it is given
            self._pending = self.cameras.capture((k + 1) * self.dt, runtime.goal[0])
        if k % self.every or runtime.mode_names()[0] != "RUNNING":
            return None
        if self.cameras is not None and images is None:  # the first tick: nothing rendered before
            images = self.cameras.capture(k * self.dt, runtime.goal[0])
        goal = runtime.goal[0].copy()
        if self._goal is None or not np.array_equal(goal, self._goal):
            self.episodes.append(Episode())
            self._goal = goal
        ep = self.episodes[-1]
        ep.state.append(self.to_lerobot(runtime.state.q[0]))
        ep.goal.append(goal.astype(np.float32))
        ep.action.append(self.to_lerobot(runtime.target[0]))
        for name, image in (images or {}).items():
            ep.images.setdefault(name, []).append(image)
        return None


def record_demonstrations(
    onnx_path,
    robot_name: str = "so101",
    seconds: float = 60.0,
    fps: float = 25.0,
    seed: int = 0,
    cameras: tuple[str, ...] = (),
    shape: tuple[int, int] = SHAPE,
) -> tuple[list[Episode], dict]:
    """Run the demonstrator ``seconds`` s with a new goal every 4 s (deploy-run's default) and
    record at ``fps`` (the control rate must be a multiple of it), with the task scene's
    ``cameras`` (names; e.g. :data:`~sim2real.eval.lerobot.cameras.CAMERAS`) rendered at
    ``shape`` (rows, columns). Returns the episodes and the goal task's report (``issued``,
    ``reached``, ``success_rate``: the demonstrator's own).

    Raises:
        ValueError: an fps that does not divide the control rate; cameras for a robot without a
            task scene. CameraError: a camera the scene lacks."""
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
    cams = SceneCameras(robot, backend, fps, shape, cameras, seed) if cameras else None
    recorder = rig.add(_Recorder(every, to_lerobot, cams, robot.control_period))
    rig.start()
    rig.run(int(round(seconds * rate)))
    report = rig.report()
    rig.close()
    if cams is not None:
        cams.close()
    episodes = [e for e in recorder.episodes if len(e.state) >= 2]
    return episodes, report["goals"]


def write_dataset(episodes: list[Episode], root, fps: float, robot_name: str = "so101"):
    """Write ``episodes`` as a LeRobot dataset at ``root`` (a new folder) with lerobot's own
    ``LeRobotDataset.create``/``add_frame``/``save_episode``/``finalize``; returns the dataset.
    The episodes' cameras become ``image`` features ``observation.images.<name>`` of shape
    (height, width, 3) (stored as PNG frames, ``use_videos=False``).

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
    cameras = {name: frames[0].shape for name, frames in episodes[0].images.items()}
    for name, shape in cameras.items():  # lerobot's image feature: (height, width, channels)
        features[KEY.format(name)] = {
            "dtype": "image",
            "shape": tuple(shape),
            "names": ["height", "width", "channels"],
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
        for i, (s, g, a) in enumerate(zip(ep.state, ep.goal, ep.action, strict=True)):
            frame = {
                "observation.state": s,
                "observation.environment_state": g,
                "action": a,
                "task": TASK,
            }
            for name in cameras:
                frame[KEY.format(name)] = ep.images[name][i]
            ds.add_frame(frame)
        ds.save_episode()
    ds.finalize()
    return ds


def write_videos(episode: Episode, folder, fps: float) -> list[Path]:
    """Each camera's frames of ``episode`` as ``<folder>/<name>.mp4`` (OpenCV's ``VideoWriter``,
    ``mp4v``, at ``fps``); returns the files written.

    Raises:
        ValueError: the episode has no camera frames, or OpenCV cannot open the file."""
    import cv2

    if not episode.images:
        raise ValueError("write_videos: the episode has no camera frames (record with cameras)")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, frames in episode.images.items():
        path = folder / f"{name}.mp4"
        rows, cols = frames[0].shape[:2]
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (cols, rows))
        if not writer.isOpened():
            raise ValueError(f"{path}: OpenCV cannot write an mp4v video here")
        for frame in frames:
            writer.write(np.ascontiguousarray(frame[..., ::-1]))  # OpenCV writes B, G, R
        writer.release()
        out.append(path)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim2real.eval.lerobot.dataset", description=__doc__)
    p.add_argument("policy", help="the demonstrator's ONNX file (ours, with its PolicySpec)")
    p.add_argument("root", type=Path, help="the dataset folder to create")
    p.add_argument("--robot", default="so101")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--fps", type=float, default=25.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--cameras",
        action="store_true",
        help=f"record the task scene's cameras {', '.join(CAMERAS)} (observation.images.<name>)",
    )
    p.add_argument(
        "--shape", type=int, nargs=2, default=SHAPE, metavar=("ROWS", "COLUMNS"),
        help="the cameras' image size (default %(default)s)",
    )  # fmt: skip
    p.add_argument(
        "--videos",
        type=Path,
        default=None,
        help="also write <name>.mp4 of each camera for the second episode (a whole goal) here",
    )
    args = p.parse_args(argv)
    cameras = CAMERAS if args.cameras or args.videos else ()
    episodes, goals = record_demonstrations(
        args.policy, args.robot, args.seconds, args.fps, args.seed, cameras, tuple(args.shape)
    )
    ds = write_dataset(episodes, args.root, args.fps, args.robot)
    print(
        f"wrote {args.root}: {ds.meta.total_episodes} episodes, {ds.meta.total_frames} frames at "
        f"{args.fps:g} fps; the demonstrator reached {goals['reached']} of {goals['issued']} goals"
    )
    if args.videos:
        episode = episodes[min(1, len(episodes) - 1)]
        for path in write_videos(episode, args.videos, args.fps):
            print(f"wrote {path}: {len(episode.state)} frames at {args.fps:g} fps")
    return 0


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
    env_state: bool = True,
    cameras: bool = True,
    lr_backbone: float = 1e-4,
    budget: float | None = None,
):
    """A small ACT trained on the dataset at ``root`` with lerobot's own classes (``LeRobotDataset``
    with ACT's ``action_delta_indices``, ``make_pre_post_processors`` on the dataset's statistics,
    ``ACTPolicy.forward`` as the loss), its folder written as ``lerobot-train`` writes
    ``pretrained_model/`` (``save_pretrained`` of the policy and both processors) at ``out``.

    Inputs: ``observation.state``; ``observation.environment_state`` (the goal) with
    ``env_state``; every ``observation.images.<name>`` of the dataset with ``cameras`` (ACT's
    ResNet-18 backbone from scratch: ``pretrained_backbone_weights`` None, no download; its
    parameters at ``lr_backbone``, as ``ACTPolicy.get_optim_params`` gives them).

    The frames are read once through ``LeRobotDataset`` (images kept as uint8) and the steps
    drawn from memory: ``lerobot-train``'s data loader ran at 2-3 s per step on a busy 2-core
    machine. ``budget``: s of training (after the frames are read) at most; the steps stop there
    and the folder is written as after the last. Returns the last step's loss and the steps
    taken.
    """
    import time

    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.datasets.lerobot_dataset import LeRobotDataset, LeRobotDatasetMetadata
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    torch.manual_seed(seed)
    meta = LeRobotDatasetMetadata("sim2real/so101_reach", root=root)
    ft = meta.features
    inputs = {
        "observation.state": PolicyFeature(
            FeatureType.STATE, tuple(ft["observation.state"]["shape"])
        )
    }
    if env_state:
        inputs["observation.environment_state"] = PolicyFeature(
            FeatureType.ENV, tuple(ft["observation.environment_state"]["shape"])
        )
    images = [k for k, f in ft.items() if f["dtype"] in ("image", "video")] if cameras else []
    for key in images:  # lerobot's VISUAL feature: (channels, height, width)
        h, w, c = ft[key]["shape"]
        inputs[key] = PolicyFeature(FeatureType.VISUAL, (c, h, w))
    cfg = ACTConfig(
        input_features=inputs,
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
        optimizer_lr_backbone=lr_backbone,
    )
    delta = {"action": [i / meta.fps for i in cfg.action_delta_indices]}
    ds = LeRobotDataset("sim2real/so101_reach", root=root, delta_timestamps=delta)
    keys = [*inputs, "action", "action_is_pad"]
    data = {k: [] for k in keys}
    for i in range(len(ds)):
        row = ds[i]
        for k in keys:  # images as uint8: a float copy of every frame would not fit in memory
            data[k].append((row[k] * 255).round().to(torch.uint8) if k in images else row[k])
    data = {k: torch.stack(v) for k, v in data.items()}
    policy = ACTPolicy(cfg)
    pre, post = make_pre_post_processors(cfg, dataset_stats=meta.stats)
    params = policy.get_optim_params()
    opt = torch.optim.AdamW(params, lr=lr, weight_decay=cfg.optimizer_weight_decay)
    gen = torch.Generator().manual_seed(seed)
    policy.train()
    loss = float("nan")
    n = len(data["action"])
    start, taken = time.monotonic(), 0
    for step in range(steps):
        if budget is not None and time.monotonic() - start > budget:
            log(f"step {step}: the budget of {budget:g} s is spent")
            break
        idx = torch.randint(0, n, (batch_size,), generator=gen)
        batch = {k: v[idx] for k, v in data.items()}
        for k in images:
            batch[k] = batch[k].float() / 255.0
        batch = pre(batch)  # as lerobot-train: the preprocessor on the whole batch
        out_loss, _ = policy.forward(batch)
        opt.zero_grad()
        out_loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), 10.0)
        opt.step()
        loss = float(out_loss.detach())
        taken = step + 1
        if step % log_every == 0 or step == steps - 1:
            log(f"step {step}: loss {loss:.4f}")
    policy.eval()
    out = Path(out)
    policy.save_pretrained(out)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    return loss, taken


if __name__ == "__main__":
    raise SystemExit(main())
