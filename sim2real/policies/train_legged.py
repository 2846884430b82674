"""Train the shipped Go2 walking policy: PPO on a residual to the trot generator, through the
runtime, and write ``sim2real/policies/go2.pt``.

``make train ROBOT=go2`` runs ``python -m sim2real.policies.train_legged`` with the defaults below. The task
is :class:`sim2real.policies.locomotion.LocomotionTask`: the learner acts from inside the runtime's tick
(:class:`~sim2real.policies.locomotion.LearnerPolicy`), so the collection loop is ours
(:meth:`RuntimePPO.collect_rollouts`, which fills Stable-Baselines3's own rollout buffer in the
order SB3's loop does) and everything else is SB3's PPO: the Gaussian policy, GAE, the clipped
update. The candidate is the Gaussian mean plus the trot generator: an
:class:`~sim2real.deploy.policy.mlp_checkpoint.MLPActor` with ``gait``
(:func:`sim2real.policies.gait.make_policy`'s spec and generator), exported to ONNX next to it. Logs:
TensorBoard (``runs/train_legged/``), SB3's episode return and length plus ``walk/tracking`` (fraction of
RUNNING time within 0.2 m/s of the command, the soak's success) and ``walk/distance``. Each episode meets the
soak's faults at the training interval (``--fault-interval S``; ``--no-faults``: none, as the shipped go2.pt
was trained): :mod:`sim2real.policies.episode_faults`. Shipping is gated as the arm's recipe is
(:func:`sim2real.policies.gate.gate`): a randomized soak of ``--gate-sessions`` seeds; only a candidate
that passes is copied to ``--out``. ``--init-from sim2real/policies/go2.pt`` fine-tunes a shipped policy
(its actor; ``--critic-warmup`` trains the fresh critic first), e.g. on the slippery floors of
``--ranges sim2real/policies/go2_slippery.toml``. ``--height-scan`` adds legged_gym's terrain heights
to the observation (the plant's ray casts, :mod:`sim2real.deploy.backends.sim.height_scan`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sim2real.deploy.export import sb3_actor
from sim2real.deploy.policy.mlp_checkpoint import MLPActor, save_checkpoint
from sim2real.eval.world.ranges_file import load_ranges
from sim2real.policies.episode_faults import fault_settings
from sim2real.policies.finetune import (
    add_finetune_arguments,
    learn_with_critic_warmup,
    load_shipped_actor,
)
from sim2real.policies.gait import make_policy
from sim2real.policies.gate import add_gate_arguments, gate
from sim2real.policies.locomotion import LocomotionConfig, LocomotionReward, LocomotionTask
from sim2real.policies.train import add_fault_flags, parse_reward, ppo_settings
from sim2real.robots import load_robot

#: The residual network (legged_gym's actor is 512-256-128 with ELU; a residual needs less).
HIDDEN = (128, 64)
#: Bound of the residual, action units (0.25 rad each: +-1 rad about the generator's target).
RESIDUAL_BOUND = 4.0


class TaskVecEnv(VecEnv):
    """The spaces of a :class:`LocomotionTask` for SB3 (its collection loop is
    :meth:`RuntimePPO.collect_rollouts`: the runtime, not SB3, steps the task)."""

    def __init__(self, task: LocomotionTask):
        obs = spaces.Box(-np.inf, np.inf, (task.spec.obs_dim,), np.float32)
        act = spaces.Box(-RESIDUAL_BOUND, RESIDUAL_BOUND, (task.spec.act_dim,), np.float32)
        self.render_mode = None
        super().__init__(task.envs, obs, act)
        self.task = task

    def reset(self):
        return self.task.policy.obs.copy()

    def step_async(self, actions):
        raise NotImplementedError("LocomotionTask is stepped by RuntimePPO.collect_rollouts")

    def step_wait(self):
        raise NotImplementedError("LocomotionTask is stepped by RuntimePPO.collect_rollouts")

    def close(self):
        pass

    def get_attr(self, attr_name, indices=None):
        return [getattr(self, attr_name)] * self.num_envs

    def set_attr(self, attr_name, value, indices=None):
        setattr(self, attr_name, value)

    def env_method(self, method_name, *args, indices=None, **kwargs):
        return [None] * self.num_envs

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * self.num_envs


class RuntimePPO(PPO):
    """SB3's PPO whose rollouts are ticks of the task's runtime (module docstring).

    Each tick the runtime calls the learner with the observation it built; the learner samples a
    residual, keeps ``(obs, residual, value, log-prob)`` and returns ``prior(obs) + residual``.
    After the tick the task's reward and ends complete the transition. A truncated episode
    bootstraps with the value of its last observation (SB3 uses the terminal observation's,
    which the runtime builds only on the next tick, after the reset).
    """

    prior: torch.nn.Module

    def collect_rollouts(self, env, callback, rollout_buffer, n_rollout_steps) -> bool:
        task: LocomotionTask = env.task
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        callback.on_rollout_start()
        low, high = self.action_space.low, self.action_space.high
        step: dict = {}

        def act(obs: np.ndarray) -> np.ndarray:
            with torch.no_grad():
                tensor = torch.as_tensor(obs)
                actions, values, log_probs = self.policy(tensor)
                prior = self.prior(tensor).numpy()
            actions = actions.numpy()
            step.update(obs=obs.copy(), actions=actions, values=values, log_probs=log_probs)
            return (prior + np.clip(actions, low, high)).astype(np.float32)

        task.policy.act = act
        for _ in range(n_rollout_steps):
            rewards, terminated, truncated = task.tick()
            self.num_timesteps += task.envs
            done = terminated | truncated
            infos = [task.episode_info(e) if done[e] else {} for e in range(task.envs)]
            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, done)
            values = step["values"]
            rewards = rewards + self.gamma * truncated * values.numpy().ravel()
            rollout_buffer.add(
                step["obs"],
                step["actions"],
                rewards.astype(np.float32),
                self._last_episode_starts,
                values,
                step["log_probs"],
            )
            self._last_episode_starts = done
            if done.any():
                task.reset(done)
        with torch.no_grad():
            last = self.policy.predict_values(torch.as_tensor(task.policy.obs))
        rollout_buffer.compute_returns_and_advantage(last_values=last, dones=done)
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True


class WalkLogger(BaseCallback):
    """TensorBoard ``walk/tracking`` and ``walk/distance`` of finished episodes, a curve point
    per rollout, and a save every ``save_every`` steps."""

    def __init__(self, save, save_every: int):
        super().__init__()
        self.save, self.save_every, self.last_save = save, save_every, 0
        self.tracking: list[float] = []
        self.distance: list[float] = []
        self.history: list[dict] = []

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            if "tracking" in info:
                self.tracking.append(info["tracking"])
                self.distance.append(info["distance"])
        return True

    def _on_rollout_end(self) -> None:
        if self.tracking:
            row = {
                "step": int(self.num_timesteps),
                "tracking": float(np.mean(self.tracking)),
                "distance": float(np.mean(self.distance)),
                "episodes": len(self.tracking),
                "return": float(np.mean([e["r"] for e in self.model.ep_info_buffer])),
                "length_s": float(np.mean([e["t"] for e in self.model.ep_info_buffer])),
            }
            self.history.append(row)
            self.logger.record("walk/tracking", row["tracking"])
            self.logger.record("walk/distance", row["distance"])
            print(
                f"step {row['step']:>9}: tracking {row['tracking']:.3f}, episode "
                f"{row['length_s']:.1f} s, return {row['return']:.3f}, distance "
                f"{row['distance']:.2f} m ({row['episodes']} episodes)",
                flush=True,
            )
            self.tracking, self.distance = [], []
        if self.save_every and self.num_timesteps - self.last_save >= self.save_every:
            self.last_save = self.num_timesteps
            self.save(self.model, self.history)


def candidate_actor(model: PPO, template: MLPActor) -> MLPActor:
    """The deployed actor: the Gaussian mean network of ``model`` with ``template``'s trot
    generator (``architecture.gait``)."""
    mean, _ = sb3_actor(model.policy.state_dict(), "elu", path="RuntimePPO")
    actor = MLPActor(
        template.obs_dim, template.act_dim, HIDDEN, "elu", gait=template.gait.description
    )
    actor.net.load_state_dict(mean.net.state_dict())
    return actor


def train(args: argparse.Namespace) -> Path | None:
    """Train, save, export and gate (module docstring); returns the candidate's path, or None
    when it failed the shipping soak (then ``--out`` is not written)."""
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    robot = load_robot(args.robot)
    template, spec = make_policy(args.robot)
    if args.height_scan:  # legged_gym's 17 x 11 terrain heights after the blind blocks
        from sim2real.deploy.export.scan_input import with_height_scan

        spec = with_height_scan(spec)
        gait = template.gait.description
        template = MLPActor(spec.obs_dim, spec.act_dim, HIDDEN, "elu", gait=gait)
    # the soak's ranges of the robot, or of --ranges FILE
    ranges = None if args.ranges is None else load_ranges(args.ranges, robot)
    config = LocomotionConfig(reward=args.reward, ranges=ranges, faults=args.faults)
    if args.fault_interval is not None:
        config = dataclasses.replace(config, fault_interval=args.fault_interval)
    task = LocomotionTask(robot, spec, args.envs, config, seed=args.seed)
    env = TaskVecEnv(task)
    model = _learner(args, env, spec)
    model.prior = template.gait
    args.logdir.mkdir(parents=True, exist_ok=True)
    candidate = args.logdir / f"{args.robot}_seed{args.seed}.pt"
    start = time.perf_counter()

    def save(model, history):
        info = {
            "algorithm": "stable-baselines3 PPO, residual on the trot generator, in the runtime",
            "command": "python -m sim2real.policies.train_legged " + " ".join(args.argv),
            "seed": args.seed,
            "timesteps": int(model.num_timesteps),
            "wall_seconds": round(time.perf_counter() - start, 1),
            "init_from": None if args.init_from is None else str(args.init_from),
            "critic_warmup": args.critic_warmup,
            "reward": dataclasses.asdict(args.reward),
            "ranges": None if args.ranges is None else str(args.ranges),
            "height_scan": bool(args.height_scan),
            "faults": fault_settings(config.faults, task.ranges.faults),
            "curve": history,
        }
        save_checkpoint(candidate, candidate_actor(model, template), spec, info=info)
        model.save(candidate.with_suffix(".zip"))
        return info

    logger = WalkLogger(save, args.save_every)
    learn_with_critic_warmup(
        model, args.steps, args.critic_warmup, callback=logger, tb_log_name=f"ppo_{args.robot}"
    )
    info = save(model, logger.history)
    from sim2real.deploy.export import export_policy

    export_policy(candidate, candidate.with_suffix(".onnx"))
    rate = info["timesteps"] / max(info["wall_seconds"], 1e-9)
    print(
        f"trained {candidate}: {info['timesteps']} steps in {info['wall_seconds'] / 60:.1f} min "
        f"({rate:.0f} steps/s)"
    )
    return _ship(args, candidate, info)


def _learner(args: argparse.Namespace, env, spec):
    """The PPO learner: a saved run continued (``--init-from RUN.zip``), else a new one (the
    recipe's hyperparameters), its actor a shipped policy's where ``--init-from`` names a
    ``.pt``."""
    if args.init_from is not None and args.init_from.suffix == ".zip":
        return RuntimePPO.load(args.init_from, env=env, device="cpu")
    model = RuntimePPO(
        "MlpPolicy",
        env,
        gamma=0.99,
        max_grad_norm=1.0,
        policy_kwargs={
            "net_arch": {"pi": list(HIDDEN), "vf": [256, 128]},
            "activation_fn": torch.nn.ELU,
            "log_std_init": float(np.log(args.initial_std)),
        },
        **ppo_settings(args),
    )
    if args.init_from is not None:
        load_shipped_actor(model, args.init_from, spec, HIDDEN)
    return model


def _ship(args: argparse.Namespace, candidate: Path, info: dict) -> Path | None:
    """Gate the candidate (a soak of ``--gate-hours``, when set) and copy it, its ONNX export
    and its curve to ``args.out``; returns the candidate, or None when the gate failed."""
    if args.gate_hours > 0:
        passed, soak = gate(candidate, args)
        info["gate"] = {
            "hours": args.gate_hours,
            "sessions": args.gate_sessions,
            "seed": args.gate_seed,
            "passed": passed,
            "report": str(soak / "report.json"),
        }
        if not passed:
            print(
                f"NOT shipped: the {args.gate_hours} h soak of {candidate} failed (see "
                f"{soak / 'report.html'}); {args.out} is unchanged"
            )
            return None
        print(f"the {args.gate_hours} h soak passed ({soak / 'report.html'})")
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(candidate, args.out)
        shutil.copyfile(candidate.with_suffix(".onnx"), args.out.with_suffix(".onnx"))
        args.out.with_suffix(".curve.json").write_text(json.dumps(info, indent=1) + "\n")
        print(f"wrote {args.out}")
    return candidate


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.policies.train_legged", description=__doc__.split("\n")[0]
    )
    p.add_argument("--robot", default="go2")
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--steps", type=int, default=4_000_000)
    p.add_argument("--n-steps", type=int, default=64, help="ticks per env per rollout")
    p.add_argument("--batch-size", type=int, default=1024)
    p.add_argument("--epochs", type=int, default=5)
    p.add_argument("--learning-rate", type=float, default=3e-4)
    p.add_argument("--initial-std", type=float, default=0.5, help="residual noise, action units")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--save-every", type=int, default=500_000)
    add_finetune_arguments(p, "sim2real/policies/go2.pt")
    p.add_argument("--logdir", type=Path, default=Path("runs/train_legged"))
    p.add_argument(
        "--ranges",
        type=Path,
        default=None,
        metavar="FILE",
        help="TOML file overriding the robot's soak ranges (soak-test --ranges)",
    )
    p.add_argument(
        "--out", type=Path, default=None, help="copy the candidate here (sim2real/policies/go2.pt)"
    )
    add_gate_arguments(p)
    p.add_argument(
        "--height-scan",
        action="store_true",
        help="a perceptive policy: legged_gym's height_scan block (17 x 11 terrain heights, ray "
        "casts on the plant) after the blind blocks; with --init-from a blind .pt its weights "
        "start at 0",
    )
    p.add_argument(
        "--reward",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a LocomotionReward coefficient (repeatable)",
    )
    add_fault_flags(p, LocomotionConfig.fault_interval)
    args = p.parse_args(argv)
    args.reward = parse_reward(args.reward, p, LocomotionReward)
    if args.fault_interval is not None and not args.fault_interval > 0:
        p.error(f"--fault-interval: expected > 0 s, got {args.fault_interval}")
    args.argv = list(argv) if argv is not None else sys.argv[1:]
    return 0 if train(args) is not None else 1


if __name__ == "__main__":
    raise SystemExit(main())
