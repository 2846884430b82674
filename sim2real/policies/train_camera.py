"""Train the camera arm policy (``sim2real/policies/arm_camera.pt`` and ``.onnx``): a student
distilled by DAgger from the shipped state policy, reaching a goal it sees only in a depth image.

``make train-camera`` runs ``python -m sim2real.policies.train_camera`` with the defaults below.

The teacher is the shipped ``arm.pt``: it reads the goal's position. The student
(:mod:`sim2real.policies.camera_student`) reads the proprioceptive blocks and the depth frame of
arm3's task-scene camera, in which the goal's marker is the only thing in range. Train what you
deploy: the episodes are the state policy's recipe (:class:`sim2real.policies.envs.ReachTask`:
the runtime's stages, guard and smoother included, the soak's dynamics, sensor and fault draws,
the recipe's start poses), and the camera is the one ``deploy-run --backend sim`` renders
(:func:`sim2real.deploy.backends.sim.camera.attach_plant_camera`: the same block, the D435 depth
model, frames at the block's 30 Hz beside the 200 Hz control loop, held between renders,
delivered 40 ms late), read by the runtime's own camera stage.

DAgger (Ross, Gordon and Bagnell, AISTATS 2011): round 0 the teacher drives; in round ``i`` each
env is driven by the teacher with probability ``beta_i`` (``--betas``) and by the student
otherwise, the teacher's action on the states visited is the label, and the student is trained
on everything gathered so far (mean squared action error). What is stored every
``--store-every`` ticks is the MLP's input (the proprioceptive vector and the fixed marker
detector's features of the frame the runtime's camera stage gave that tick).

The end: the student alone and the teacher alone each run ``--eval-seconds`` on the same seed
(goals reached / goals decided in these episodes, printed); the student is written to ``--out``
(``.pt``) with its two-input ONNX graph beside it (parity with torch checked) and its curve
(``.curve.json``); each round's student is kept in ``--logdir``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from sim2real.deploy.policy.mlp_checkpoint import load_checkpoint
from sim2real.policies.camera_student import (
    CameraActor,
    export_camera_actor,
    save_camera_actor,
    student_spec,
)
from sim2real.policies.envs import ReachConfig, ReachTask
from sim2real.policies.train import start_poses
from sim2real.robots import load_robot


def _rollout(task, teacher, teacher_spec, student, teacher_envs, ticks, store_every):
    """Run ``ticks`` control periods; envs in ``teacher_envs`` (bool) act by the teacher, the
    others by the student. Returns the stored (obs, image, teacher action, goal xy) and the goals
    reached and decided."""
    envs = task.envs
    tobs = np.zeros((envs, teacher_spec.obs_dim), np.float32)
    cameras = task.learner_tick.cameras
    stored = {"features": [], "action": []}
    reached = decided = 0
    goals = task.task  # the episodes' counts: this rollout's are those past where it began
    r0, d0 = goals.reached.copy(), goals.reached + goals.missed
    for t in range(ticks):
        teacher_spec.observation(task.state, task.goal, out=tobs)
        with torch.no_grad():
            label = teacher(torch.from_numpy(tobs)).numpy()
            action = label.copy()
            features = student.features(torch.from_numpy(task.obs), torch.from_numpy(cameras.image))
            if not teacher_envs.all():
                mine = torch.clamp(student.mlp(features), -1.0, 1.0)
                action[~teacher_envs] = mine.numpy()[~teacher_envs]
        if t % store_every == 0:
            stored["features"].append(features.numpy().copy())
            stored["action"].append(label)
        _, _, terminated, truncated = task.step(action)
        done = terminated | truncated
        if done.any():
            reached += int((goals.reached - r0)[done].sum())
            decided += int((goals.reached + goals.missed - d0)[done].sum())
            task.reset(done)
            r0[done], d0[done] = 0, 0
    reached += int((goals.reached - r0).sum())
    decided += int((goals.reached + goals.missed - d0).sum())
    return {k: np.concatenate(v) for k, v in stored.items()}, reached, decided


def _fit(student, data, steps, batch, lr, rng):
    """``steps`` Adam steps on minibatches of ``data`` (its MLP inputs, ``features``); the last
    100 steps' mean squared action error."""
    opt = torch.optim.Adam(student.mlp.parameters(), lr=lr)
    n = len(data["features"])
    features, action = torch.from_numpy(data["features"]), torch.from_numpy(data["action"])
    losses = []
    for _ in range(steps):
        idx = torch.from_numpy(rng.integers(0, n, batch))
        loss = torch.mean((torch.clamp(student.mlp(features[idx]), -1, 1) - action[idx]) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    return {"action_mse": float(np.mean(losses[-100:]))}


def _task(args, robot, spec, seed):
    config = ReachConfig(
        episode_seconds=args.episode_seconds,
        start_poses=start_poses(args.start_poses, robot),
    )
    return ReachTask(robot, args.envs, config, spec=spec, seed=seed)


def train(args: argparse.Namespace) -> dict:
    """DAgger (module docstring); returns the curve written beside ``args.out``."""
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    robot = load_robot("arm3")
    teacher, teacher_spec, _ = load_checkpoint(args.teacher)
    spec = student_spec(teacher_spec)
    student = CameraActor(spec.obs_dim, spec.act_dim, spec.images[0].input_shape)
    task = _task(args, robot, spec, args.seed)
    ticks = int(round(args.round_seconds * robot.config.control.control_rate))
    data, curve, start = None, [], time.perf_counter()
    for i, beta in enumerate(args.betas):
        teacher_envs = rng.random(args.envs) < beta
        if i == 0:
            teacher_envs[:] = True
        torch.set_num_threads(1)  # one env batch a tick: no spin-waits
        new, reached, decided = _rollout(
            task, teacher, teacher_spec, student, teacher_envs, ticks, args.store_every
        )
        torch.set_num_threads(args.threads)
        data = new if data is None else {k: np.concatenate([data[k], new[k]]) for k in data}
        fit = _fit(student, data, args.fit_steps, args.batch, args.lr, rng)
        row = {
            "round": i,
            "beta": beta,
            "student_envs": int((~teacher_envs).sum()),
            "samples": len(data["features"]),
            "goals_reached": reached,
            "goals_decided": decided,
            "wall_s": round(time.perf_counter() - start, 1),
            **fit,
        }
        curve.append(row)
        print(json.dumps(row), flush=True)
        args.logdir.mkdir(parents=True, exist_ok=True)  # each round's student, to compare
        save_camera_actor(
            args.logdir / f"{args.out.stem}.round{i}.pt", student, spec, {"curve": curve}
        )
    evaluation = _evaluate(args, robot, spec, teacher, teacher_spec, student)
    print(json.dumps(evaluation), flush=True)
    info = {
        "algorithm": "DAgger from the shipped state policy",
        "command": "python -m sim2real.policies.train_camera " + " ".join(args.argv),
        "teacher": str(args.teacher),
        "seed": args.seed,
        "wall_seconds": round(time.perf_counter() - start, 1),
        "curve": curve,
        "evaluation": evaluation,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_camera_actor(args.out, student, spec, info)
    info["parity"] = export_camera_actor(student, spec, args.out.with_suffix(".onnx"))
    args.out.with_suffix(".curve.json").write_text(json.dumps(info, indent=1) + "\n")
    print(f"wrote {args.out} and {args.out.with_suffix('.onnx')}")
    return info


def _evaluate(args, robot, spec, teacher, teacher_spec, student) -> dict:
    """The student alone and the teacher alone, ``--eval-seconds`` each on the same seed."""
    ticks = int(round(args.eval_seconds * robot.config.control.control_rate))
    out = {"seconds": args.eval_seconds, "envs": args.envs, "seed": args.seed + 1000}
    for name, teacher_envs in (("student", False), ("teacher", True)):
        task = _task(args, robot, spec, args.seed + 1000)
        mask = np.full(args.envs, teacher_envs)
        _, reached, decided = _rollout(task, teacher, teacher_spec, student, mask, ticks, 10**9)
        out[name] = {"reached": reached, "decided": decided}
    return out


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.policies.train_camera", description=__doc__
    )
    p.add_argument("--teacher", type=Path, default=Path("sim2real/policies/arm.pt"))
    p.add_argument("--envs", type=int, default=16, help="robots per batch (one camera each)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--betas",
        type=lambda s: [float(x) for x in s.split(",")],
        default=[1.0, 0.5, 0.25, 0.0, 0.0, 0.0, 0.0, 0.0],
        help="teacher probability per DAgger round (round 0: the teacher drives)",
    )
    p.add_argument("--round-seconds", type=float, default=10.0, help="simulated s per round")
    p.add_argument("--episode-seconds", type=float, default=30.0)
    p.add_argument(
        "--start-poses", type=Path, default=Path("sim2real/policies/arm3_missed_poses.json")
    )
    p.add_argument("--store-every", type=int, default=2, help="ticks between stored samples")
    p.add_argument("--fit-steps", type=int, default=2000, help="Adam steps per round")
    p.add_argument("--batch", type=int, default=512)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--eval-seconds", type=float, default=20.0)
    p.add_argument("--threads", type=int, default=1, help="torch threads when fitting")
    p.add_argument("--logdir", type=Path, default=Path("runs/train_camera"))
    p.add_argument("--out", type=Path, default=Path("sim2real/policies/arm_camera.pt"))
    return p


def main(argv: list[str] | None = None) -> int:
    """Train (``python -m sim2real.policies.train_camera``); 0 when written."""
    args = _parser().parse_args(argv)
    args.argv = list(argv) if argv is not None else __import__("sys").argv[1:]
    train(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
