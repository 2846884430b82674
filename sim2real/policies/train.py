"""Train the shipped arm policy with Stable-Baselines3 PPO and write ``sim2real/policies/arm.pt``.

``make train`` runs ``python -m sim2real.policies.train`` with the defaults below (seed 1); the shipped
``sim2real/policies/arm.pt`` is such a run without faults, fine-tuned with them (``--init-from
policies/arm.pt``, :mod:`sim2real.policies.finetune`; ``--init-from RUN.zip`` continues a saved run; both
stages in ``sim2real/policies/arm.curve.json``). Logs go to TensorBoard (``runs/train/``): SB3's episode
length, return and success rate, plus ``reach/joint_limit_violations``, ``reach/success_rate``
and ``reach/intervention_rate``.

Each episode draws its dynamics, encoder settings and fault schedule (at ``--fault-interval``,
:mod:`sim2real.policies.episode_faults`; ``--no-faults``: none) from the robot's soak ranges
(:func:`sim2real.eval.world.session_ranges.session_ranges`), or from ``--ranges FILE``
(:func:`sim2real.eval.world.ranges_file.load_ranges`), which the shipping soak then runs too.

Shipping is gated on the soak. Training writes its candidate (and its periodic saves) next to its
logs, ``<logdir>/<robot>_<mode>_seed<seed>.pt``; at the end it exports the candidate to ONNX and
runs a randomized soak of ``--gate-hours`` simulated hours (``--gate-sessions`` sessions from
``--gate-seed``, the soak's full randomization and faults, its default thresholds). Only a
candidate whose soak passes is copied to ``--out`` (with its ``.onnx`` and ``.curve.json``); a
failed one stays in the log folder with the soak's report, and the command exits with 1.

Why PPO: the field's usual choice for reaching and locomotion; with one batched MuJoCo plant
stepping many robots per call it turns two cores into samples faster than SAC's one update per
sample. Why 64 robots with 128-step rollouts (8,192 samples per update, as 16 x 512): the forward
pass is shared by more robots and the more diverse rollouts learned faster per sample
(``docs/measurements.md``).

The PPO actor's mean network becomes an :class:`~sim2real.deploy.policy.mlp_checkpoint.MLPActor` with the
same weights and the env's PolicySpec (:func:`sim2real.deploy.policy.mlp_checkpoint.save_checkpoint`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import time
from pathlib import Path

import numpy as np
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.vec_env import VecEnv, VecMonitor, VecNormalize

from sim2real.deploy.export import sb3_actor
from sim2real.deploy.policy.mlp_checkpoint import MLPActor, save_checkpoint
from sim2real.eval.world.dynamics import DynamicsRanges
from sim2real.eval.world.fault_schedule import FaultRanges
from sim2real.eval.world.ranges_file import load_ranges
from sim2real.eval.world.session_ranges import session_ranges
from sim2real.policies.callbacks import NoiseAnneal, ReachLogger
from sim2real.policies.envs import ReachConfig, ReachTask, RewardConfig
from sim2real.policies.episode_faults import fault_settings
from sim2real.policies.finetune import (
    add_finetune_arguments,
    learn_with_critic_warmup,
    load_shipped_actor,
)
from sim2real.policies.gate import add_gate_arguments, gate
from sim2real.robots import load_robot

HIDDEN = (64, 64)
ACTIVATION = "tanh"  # SB3 PPO's MlpPolicy default


class ReachVecEnv(VecEnv):
    """Stable-Baselines3 ``VecEnv`` over one batched :class:`ReachTask` (one MuJoCo plant object,
    ``envs`` robots). Finished envs are reset automatically; their last observation is in
    ``info["terminal_observation"]``, and ``info["TimeLimit.truncated"]`` marks truncations so
    that PPO bootstraps them."""

    def __init__(self, task: ReachTask):
        self.task = task
        super().__init__(task.envs, *task.spaces())
        self._actions = np.zeros((task.envs, task.spec.act_dim))

    def reset(self):
        self.task.reset(np.ones(self.num_envs, dtype=bool))
        return self.task.obs.copy()

    def step_async(self, actions):
        self._actions = actions

    def step_wait(self):
        obs, reward, terminated, truncated = self.task.step(self._actions)
        done = terminated | truncated
        infos = [{} for _ in range(self.num_envs)]
        if done.any():
            for e in np.nonzero(done)[0]:
                info = self.task.episode_info(e)
                info["terminal_observation"] = obs[e].copy()
                info["TimeLimit.truncated"] = bool(truncated[e])
                infos[e] = info
            self.task.reset(done)
        return self.task.obs.copy(), reward.astype(np.float32), done, infos

    def close(self):
        pass

    def get_attr(self, attr_name, indices=None):
        value = None if attr_name == "render_mode" else getattr(self.task, attr_name)
        return [value] * len(self._indices(indices))

    def set_attr(self, attr_name, value, indices=None):
        setattr(self.task, attr_name, value)

    def env_method(self, method_name, *args, indices=None, **kwargs):
        return [getattr(self.task, method_name)(*args, **kwargs)] * len(self._indices(indices))

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False] * len(self._indices(indices))

    def _indices(self, indices):
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else indices


def actor_from_model(model: PPO | SAC) -> MLPActor:
    """The trained policy's deterministic action (PPO's Gaussian mean, SAC's ``tanh(mu)``) as an
    :class:`MLPActor` with the same weights, read as the export reads SB3 models
    (:func:`sim2real.deploy.export.sb3_actor`)."""
    activation = "relu" if isinstance(model, SAC) else ACTIVATION  # SAC: SB3's default
    actor, _ = sb3_actor(model.policy.state_dict(), activation, path=f"{type(model).__name__}")
    return actor


def make_model(args: argparse.Namespace, env) -> PPO | SAC:
    """The learner: PPO (default) or SAC."""
    if args.algo == "sac":
        return SAC(
            "MlpPolicy",
            env,
            learning_rate=args.learning_rate,
            buffer_size=1_000_000,
            learning_starts=10_000,
            batch_size=256,
            gamma=args.gamma,
            train_freq=1,
            gradient_steps=args.gradient_steps,
            policy_kwargs={"net_arch": {"pi": list(args.hidden), "qf": [256, 256]}},
            **_run_settings(args),
        )
    return PPO(
        "MlpPolicy",
        env,
        gamma=args.gamma,
        # generalized state-dependent exploration (Raffin et al., CoRL 2021): noise that is smooth
        # in time, so exploration survives the smoother's acceleration and jerk limits at 200 Hz
        use_sde=args.sde,
        sde_sample_freq=args.sde_sample_freq,
        policy_kwargs={
            "net_arch": {"pi": list(args.hidden), "vf": [128, 128]},
            "log_std_init": args.log_std_init,
            "activation_fn": torch.nn.Tanh,
        },
        **ppo_settings(args),
    )


def ppo_settings(args: argparse.Namespace) -> dict:
    """The PPO settings both trainers (this one and the legged one) share: ``--n-steps``,
    ``--batch-size``, ``--epochs``, ``--learning-rate``; GAE lambda 0.95, clip range 0.2, no
    entropy bonus (SB3's defaults, stated); logged, seeded and placed as :func:`_run_settings`."""
    rollout = {"n_steps": args.n_steps, "batch_size": args.batch_size, "n_epochs": args.epochs}
    update = {"learning_rate": args.learning_rate, "gae_lambda": 0.95, "clip_range": 0.2}
    return rollout | update | {"ent_coef": 0.0} | _run_settings(args)


def _run_settings(args: argparse.Namespace) -> dict:
    """Every learner's: logged at ``--logdir``, seeded by ``--seed``, on the CPU."""
    return {"tensorboard_log": str(args.logdir), "seed": args.seed, "device": "cpu"}


def start_poses(path: Path | None, robot) -> tuple[tuple[float, ...], ...]:
    """Joint poses (rad) to start episodes from; ``()`` without a path.

    ``path`` is a soak's ``report.json`` (the poses where it saw the policy miss its goal,
    :func:`sim2real.eval.report.build.missed_states`) or a JSON file ``{"robot": name, "poses": [[rad,
    ...]]}``
    (such poses kept with the recipe, e.g. ``sim2real/policies/arm3_missed_poses.json``).

    Raises:
        sim2real.eval.report.schema.ReportError: unreadable file, poses of another robot or joint count.
    """
    if path is None:
        return ()
    from sim2real.eval.report.build import missed_states
    from sim2real.eval.report.schema import ReportError, load_report

    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ReportError(f"{path}: not a readable JSON file ({exc})") from None
    if isinstance(doc, dict) and "poses" in doc:
        if doc.get("robot") != robot.name:
            raise ReportError(
                f"{path}: field 'robot': expected '{robot.name}', got {doc.get('robot')!r}"
            )
        raw = doc["poses"]
    else:
        raw = [m["q"] for m in missed_states(load_report(path))]
    poses = tuple(tuple(float(x) for x in p) for p in raw)
    bad = [p for p in poses if len(p) != robot.n_joints]
    if bad:
        raise ReportError(
            f"{path}: field 'poses': expected {robot.n_joints} joint angles per pose (robot "
            f"{robot.name}), got {len(bad[0])}"
        )
    return poses


def train(args: argparse.Namespace) -> Path | None:
    """Train, gate and ship (see the module docstring).

    Returns:
        ``args.out`` when the candidate passed the gate (or the gate is off), else None.
    """
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    config, task = _reach_task(args)
    # Rewards (not observations: those are already scaled by physical maxima) are
    # normalized by a running estimate of the return's scale, as SB3's PPO recipes do.
    env = VecNormalize(VecMonitor(ReachVecEnv(task)), norm_obs=False, gamma=args.gamma)
    model = _learner(args, env, task)
    start = time.perf_counter()
    args.logdir.mkdir(parents=True, exist_ok=True)
    candidate = args.logdir / f"{args.robot}_{args.mode}_seed{args.seed}.pt"

    def save(model, history):
        actor = actor_from_model(model)
        info = {
            "algorithm": f"stable-baselines3 {args.algo.upper()}",
            "command": "python -m sim2real.policies.train " + " ".join(args.argv),
            "seed": args.seed,
            "timesteps": int(model.num_timesteps),
            "wall_seconds": round(time.perf_counter() - start, 1),
            "randomized_dynamics": bool(args.randomize),
            "ranges": None if args.ranges is None else str(args.ranges),
            "episode_seconds": args.episode_seconds,
            "reward": dataclasses.asdict(args.reward),
            "start_poses": len(config.start_poses),
            "success_radius": task.success_radius,
            "faults": fault_settings(config.faults, task.fault_ranges),
            "init_from": None if args.init_from is None else str(args.init_from),
            "critic_warmup": args.critic_warmup,
            "curve": history,
        }
        save_checkpoint(candidate, actor, task.spec, info=info)
        model.save(candidate.with_suffix(".zip"))  # the whole learner, for --init-from
        return info

    # episodes of minutes finish rarely: a curve point per finished batch of episodes
    points = max(1, min(16, args.envs // 2))
    callbacks = [ReachLogger(save, args.save_every, points_every=points)]
    if args.anneal_steps and args.algo == "ppo":
        callbacks.append(NoiseAnneal(args.steps, args.anneal_steps, args.final_log_std))
    logger = callbacks[0]
    name = f"{args.algo}_{args.robot}_{args.mode}"
    learn_with_critic_warmup(
        model,
        args.steps,
        args.critic_warmup,
        callback=callbacks,
        progress_bar=args.progress,
        tb_log_name=name,
    )
    info = save(model, logger.history)
    wall = info["wall_seconds"]
    print(f"trained {candidate} in {args.steps} steps, {wall / 60:.1f} min")
    for row in logger.history[:: max(1, len(logger.history) // 10)] + logger.history[-1:]:
        print(
            f"  step {row['step']:>9}: success {row['success_rate']:.2f}, joint limit "
            f"violations/episode {row['joint_limit_violations']:.3f}, interventions "
            f"{100 * row['intervention_rate']:.2f} % of ticks"
        )
    return _ship(args, candidate, info)


def _reach_task(args: argparse.Namespace) -> tuple[ReachConfig, ReachTask]:
    """The reach task's configuration and its envs, from the flags and the soak's ranges of the
    robot (or of ``--ranges FILE``, which the gate's soak runs too)."""
    robot = load_robot(args.robot)
    ranges = session_ranges(robot) if args.ranges is None else load_ranges(args.ranges, robot)
    config = ReachConfig(
        mode=args.mode,
        reference=args.reference,
        dynamics=ranges.dynamics if args.randomize else DynamicsRanges.none(),
        sensors=ranges.sensors,
        reward=args.reward,
        episode_seconds=args.episode_seconds,
        start_poses=start_poses(args.start_poses, robot),
        success_radius=args.success_radius,
        faults=args.faults,
        fault_ranges=ranges.faults,
    )
    if args.fault_interval is not None:
        config = dataclasses.replace(config, fault_interval=args.fault_interval)
    return config, ReachTask(robot, args.envs, config, seed=args.seed)


def _learner(args: argparse.Namespace, env, task: ReachTask):
    """A new SB3 learner, a saved run continued (``--init-from RUN.zip``: weights, optimizer
    state and noise), or a new PPO learner whose actor is a shipped policy's (``.pt``).

    Raises:
        ValueError: ``--init-from`` a ``.pt`` without ``--algo ppo``.
    """
    if args.init_from is not None and args.init_from.suffix == ".zip":
        algo = SAC if args.algo == "sac" else PPO
        return algo.load(args.init_from, env=env, device="cpu", tensorboard_log=str(args.logdir))
    model = make_model(args, env)
    if args.init_from is not None:
        if args.algo != "ppo":
            raise ValueError(f"{args.init_from}: --init-from a shipped .pt needs --algo ppo")
        load_shipped_actor(model, args.init_from, task.spec, args.hidden)
    return model


def _ship(args: argparse.Namespace, candidate: Path, info: dict) -> Path | None:
    """Gate the candidate (a soak of ``--gate-hours``, when set) and copy it, its ONNX export
    and its curve to ``args.out``; None (nothing copied) when the gate failed."""
    if args.gate_hours > 0:
        from sim2real.deploy.export import export_policy

        export_policy(candidate, candidate.with_suffix(".onnx"))
        passed, soak = gate(candidate, args)
        if not passed:
            print(
                f"NOT shipped: the {args.gate_hours} h soak of {candidate} failed (see "
                f"{soak / 'report.html'}); {args.out} is unchanged"
            )
            return None
        info["gate"] = {
            "hours": args.gate_hours,
            "sessions": args.gate_sessions,
            "seed": args.gate_seed,
            "report": str(soak / "report.json"),
        }
        print(f"the {args.gate_hours} h soak passed ({soak / 'report.html'})")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(candidate, args.out)
    if candidate.with_suffix(".onnx").exists():
        shutil.copyfile(candidate.with_suffix(".onnx"), args.out.with_suffix(".onnx"))
    curve = args.out.with_suffix(".curve.json")
    curve.write_text(json.dumps(info, indent=1) + "\n")
    print(f"wrote {args.out}")
    return args.out


def add_fault_flags(parser: argparse.ArgumentParser, interval: float) -> None:
    """``--no-faults`` (``args.faults``) and ``--fault-interval S`` (``args.fault_interval``, None:
    the task's default ``interval`` s)."""
    parser.add_argument(
        "--no-faults",
        dest="faults",
        action="store_false",
        help="episodes meet no faults (default: each draws the soak's fault schedule)",
    )
    parser.add_argument(
        "--fault-interval",
        type=float,
        default=None,
        metavar="S",
        help=f"mean time between faults in training, s (default {interval:g}; the soak's "
        f"{FaultRanges.mean_interval:g})",
    )


def parse_reward(overrides: list[str], parser: argparse.ArgumentParser, config=RewardConfig):
    """``config`` (a dataclass of reward coefficients: :class:`RewardConfig` by default,
    :class:`sim2real.policies.locomotion.LocomotionReward` for legs) with ``NAME=VALUE`` overrides; a bad
    name or value exits with usage."""
    names = {f.name for f in dataclasses.fields(config)}
    values = {}
    for item in overrides:
        name, _, value = item.partition("=")
        if name not in names:
            parser.error(
                f"--reward {item}: unknown coefficient '{name}', expected one of {sorted(names)}"
            )
        try:
            values[name] = float(value)
        except ValueError:
            parser.error(f"--reward {item}: expected a number after '{name}='")
    return config(**values)


def _parser() -> argparse.ArgumentParser:
    """The training command's options: the robot, the learner's, then the episodes' and outputs'."""
    p = argparse.ArgumentParser(prog="python -m sim2real.policies.train", description=__doc__)
    p.add_argument("--robot", default="arm3")
    _add_learner_options(p)
    _add_episode_options(p)
    return p


def _add_learner_options(p: argparse.ArgumentParser) -> None:
    """The algorithm, the action's meaning, the network and its exploration."""
    p.add_argument("--algo", default="ppo", choices=["ppo", "sac"])
    p.add_argument("--gradient-steps", type=int, default=1, help="SAC: updates per batch step")
    p.add_argument("--mode", default="velocity", choices=["velocity", "position"])
    p.add_argument(
        "--reference",
        default="absolute",
        choices=["absolute", "current"],
        help="position mode: an action spans the joint range, or steps from the current position",
    )
    p.add_argument("--steps", type=int, default=10_000_000, help="environment steps")
    p.add_argument("--envs", type=int, default=64, help="robots per batch")
    p.add_argument("--seed", type=int, default=1, help="1: the shipped arm.pt")
    p.add_argument("--n-steps", type=int, default=128, help="PPO rollout length per env")
    p.add_argument("--batch-size", type=int, default=1024)
    p.add_argument("--epochs", type=int, default=10)
    p.add_argument("--learning-rate", type=float, default=3e-4)
    p.add_argument("--gamma", type=float, default=0.99)
    p.add_argument(
        "--hidden",
        type=lambda s: tuple(int(x) for x in s.split(",")),
        default=HIDDEN,
        help="actor hidden layer widths, e.g. 64,64",
    )
    p.add_argument("--log-std-init", type=float, default=-2.0)
    p.add_argument("--no-sde", dest="sde", action="store_false", help="Gaussian noise per tick")
    p.add_argument("--sde-sample-freq", type=int, default=8, help="ticks between gSDE draws")
    p.add_argument(
        "--anneal-steps",
        type=int,
        default=3_000_000,
        help="PPO: anneal the exploration noise over this many final steps (0: off)",
    )
    p.add_argument("--final-log-std", type=float, default=-4.0, help="log_std after annealing")
    p.add_argument("--threads", type=int, default=1, help="torch threads (1: no spin-waits)")


def _add_episode_options(p: argparse.ArgumentParser) -> None:
    """The episodes' dynamics, rewards, goals and faults, the gate, and where the outputs go."""
    p.add_argument(
        "--no-randomize", dest="randomize", action="store_false", help="nominal dynamics only"
    )
    p.add_argument(
        "--ranges",
        type=Path,
        default=None,
        metavar="FILE",
        help="TOML file overriding the robot's soak ranges (soak-test --ranges; the gate uses it)",
    )
    p.add_argument(
        "--reward",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="override a RewardConfig coefficient, e.g. --reward shaping=2 (repeatable)",
    )
    p.add_argument(
        "--save-every", type=int, default=250_000, help="steps between saves of the candidate"
    )
    p.add_argument(
        "--episode-seconds", type=float, default=120.0, help="episode length, s (goals chained)"
    )
    p.add_argument(
        "--start-poses",
        type=Path,
        default=None,
        metavar="REPORT.json",
        help="also start episodes where this soak report saw the policy miss its goal",
    )
    add_finetune_arguments(p, "sim2real/policies/arm.pt")
    p.add_argument(
        "--success-radius",
        type=float,
        default=None,
        help="m, training's goal radius (default the robot's task.success_radius, as the soak)",
    )
    add_gate_arguments(p)
    add_fault_flags(p, ReachConfig.fault_interval)
    p.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    p.add_argument("--logdir", type=Path, default=Path("runs/train"))
    p.add_argument("--out", type=Path, default=Path("sim2real/policies/arm.pt"))


def main(argv: list[str] | None = None) -> int:
    """Train (``python -m sim2real.policies.train``); 0 when the candidate shipped (it passed the
    gate, or the gate is off), else 1."""
    p = _parser()
    args = p.parse_args(argv)
    args.reward = parse_reward(args.reward, p)
    if args.fault_interval is not None and not args.fault_interval > 0:
        p.error(f"--fault-interval: expected > 0 s, got {args.fault_interval}")
    args.argv = list(argv) if argv is not None else __import__("sys").argv[1:]
    return 0 if train(args) is not None else 1


if __name__ == "__main__":
    raise SystemExit(main())
