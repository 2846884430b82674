"""Action chunks on the MuJoCo plant (:func:`run_chunks`): a LeRobot export
(:class:`~sim2real.deploy.policy.lerobot_policy.LeRobotChunkPolicy`) at its own rate beside the
robot's servo loop, each servo tick's held target through the joint estimator, the safety guard
and (or not) the Ruckig smoother with the guard's motion check, as ``Runtime.tick`` runs them; and
the joint jerk at chunk boundaries against the jerk inside chunks (:func:`boundary_jerk`).

Not the whole runtime: no state machine (ramp-in, safe stops), no supervision; the cameras are
stand-ins (``frames``: by default a new uniform-noise image per camera every policy tick) until
the plant renders RGB.

``python -m sim2real.eval.lerobot.action_chunks POLICY.onnx [--seconds S] [--seed N]`` prints the figures
with and without the smoother.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.state import Kinematics, RobotState
from sim2real.deploy.estimation.joints import JointStateEstimator
from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.deploy.smoothing import CommandSmoother
from sim2real.robots import load_robot


@dataclass
class ChunkRun:
    """One run's record.

    Attributes:
        dt: s, the servo period. position: (ticks, n) rad, the plant's true joint positions.
        command: (ticks, n) rad, the command written. boundary_ticks: servo ticks at which a new
        chunk was taken. policy_ticks, calls: the policy's ticks and network calls.
        guard_clamps: servo ticks whose target the guard changed. policy_period: s.
    """

    dt: float
    position: np.ndarray
    command: np.ndarray
    boundary_ticks: np.ndarray
    policy_ticks: int
    calls: int
    guard_clamps: int
    policy_period: float = 0.0


def noise_frames(policy: LeRobotChunkPolicy, seed: int) -> Callable[[float], dict]:
    """Per camera a uniform-noise float32 image in [0, 1], a new one every policy tick."""
    rng = np.random.default_rng(seed)
    cache: dict = {}

    def frames(t: float) -> dict:
        k = int(np.floor(t / policy.period + 1e-9))
        if cache.get("k") != k:
            cache["k"] = k
            cache["f"] = {
                key: rng.uniform(0, 1, shape).astype(np.float32)
                for key, shape in policy.contract.cameras
            }
        return cache["f"]

    return frames


def run_chunks(
    onnx_path,
    robot_name: str = "so101",
    seconds: float = 10.0,
    smoothing: bool = True,
    seed: int = 0,
    frames: Callable[[float], dict] | None = None,
    env_state: Callable[[float], np.ndarray] | None = None,
) -> ChunkRun:
    """Run the export on the plant for ``seconds`` s (module docstring).

    Without ``smoothing`` the guard's target is written to the position servos as it is (the
    LeRobot loop's way: ``robot.send_action`` every policy tick); with it, Ruckig's step and the
    guard's motion check, as the runtime does.
    """
    robot = load_robot(robot_name)
    policy = LeRobotChunkPolicy(onnx_path, robot)
    frames = frames or noise_frames(policy, seed)
    plant = SimBackend(robot, "position", envs=1, seed=seed)
    plant.open()
    n, dt = robot.n_joints, robot.control_period
    est, kin = JointStateEstimator(robot, 1), Kinematics(robot)
    state = RobotState.zeros(1, n)
    guard, smoother = SafetyGuard(robot, 1, "position"), CommandSmoother(robot, 1, "position")
    episode = None
    frame = plant.read()
    q0 = frame.position.copy()
    est.reset(q0, frame.position_stamp)
    state.q[:] = q0
    guard.reset(q0)
    smoother.reset(q0, np.zeros_like(q0))
    acc = guard.estimator_input(smoother)
    ticks = int(round(seconds / dt))
    pos, cmds, boundary, clamps = np.zeros((ticks, n)), np.zeros((ticks, n)), [], 0
    for k in range(ticks):
        t = k * dt
        frame = plant.read()
        state = est.update(frame, state, acc if smoothing else None)
        kin.update(state)
        es = env_state(t) if env_state is not None else None
        if es is not None and (episode is None or not np.array_equal(es, episode)):
            episode = np.array(es)
            policy.reset()  # a new episode (a new goal): a fresh chunk from this tick
        calls = policy.chunks.calls
        target = policy.step(t, state.q[0].copy(), frames(t), es)[None].copy()
        if policy.chunks.calls != calls:
            boundary.append(k)
        wanted = target.copy()
        target = guard.filter(target, state)
        clamps += int(not np.allclose(target, wanted))
        if smoothing:
            cmd = smoother.step(target)
            cmd = guard.check_motion(smoother, state, cmd)
        else:
            cmd = target
        plant.write(cmd)
        plant.advance()
        pos[k] = plant.true_position()[0]
        cmds[k] = cmd[0]
    return ChunkRun(
        dt,
        pos,
        cmds,
        np.array(boundary),
        policy.policy_ticks,
        policy.chunks.calls,
        clamps,
        policy.period,
    )


def goal_schedule(robot, goals: int, period: float, seed: int):
    """``goals`` goals from the robot's task region (``sample_goal``, the goal task's own draw,
    from ``default_rng(seed + 1)`` as deploy-run seeds its task), a new one every ``period`` s:
    the goals and ``env_state(t)``, the goal (m, base frame) at time ``t`` s."""
    from sim2real.deploy.tasks.goals import sample_goal

    rng = np.random.default_rng(seed + 1)
    targets = [sample_goal(robot, rng) for _ in range(goals)]

    def env_state(t: float) -> np.ndarray:
        return targets[min(int(t // period), goals - 1)]

    return targets, env_state


def reach_success(
    onnx_path,
    robot_name: str = "so101",
    goals: int = 20,
    period: float = 4.0,
    success_time: float = 3.0,
    seed: int = 0,
    smoothing: bool = True,
) -> tuple[dict, ChunkRun]:
    """A goal-conditioned export (``observation.environment_state`` = the goal, m, base frame) on
    the plant, :func:`goal_schedule`'s goals; a goal is reached when the true end effector comes
    within the task's ``success_radius`` of it at most ``success_time`` s after it was issued
    (``deploy-run``'s rule and defaults). Returns ``{"goals", "reached", "rate",
    "median_closest"}`` (m) and the run."""
    robot = load_robot(robot_name)
    targets, env_state = goal_schedule(robot, goals, period, seed)
    run = run_chunks(onnx_path, robot_name, goals * period, smoothing, seed, env_state=env_state)
    radius = robot.config.task.success_radius
    per_goal = int(round(period / run.dt))
    window = int(round(success_time / run.dt))
    closest = []
    for g in range(goals):
        qs = run.position[g * per_goal : g * per_goal + window]
        closest.append(min(np.linalg.norm(robot.forward_kinematics(q) - targets[g]) for q in qs))
    reached = int(np.sum(np.asarray(closest) <= radius))
    figures = {
        "goals": goals,
        "reached": reached,
        "rate": reached / goals,
        "median_closest": float(np.median(closest)),
    }
    return figures, run


def jerk(x: np.ndarray, dt: float) -> np.ndarray:
    """(ticks - 3, n) rad/s^3, the third finite difference of ``x`` over ``dt``."""
    return np.diff(x, n=3, axis=0) / dt**3


def boundary_jerk(run: ChunkRun, what: str = "position", skip_first: int = 1) -> dict:
    """Peak |jerk| (rad/s^3, over joints) within one policy period after each chunk boundary,
    against the same after each policy tick inside a chunk.

    Returns ``{"boundary_median", "boundary_max", "inside_median", "inside_max", "boundaries"}``:
    medians and maxima over the windows (NaN where there is none: with temporal ensembling every
    policy tick takes a chunk); the first ``skip_first`` boundaries (the start from rest) left
    out.
    """
    j = np.abs(jerk(getattr(run, what), run.dt)).max(axis=1)
    period_ticks = max(1, int(round(run.policy_period / run.dt)))
    starts = set(run.boundary_ticks.tolist()[skip_first:])
    step = run.policy_period / run.dt
    policy_starts = np.unique(np.ceil(np.arange(0, len(j), step) - 1e-9).astype(int))

    def peaks(ticks) -> np.ndarray:
        out = [
            j[max(0, s - 2) : s + period_ticks].max() for s in ticks if s + period_ticks <= len(j)
        ]
        return np.asarray(out) if out else np.full(1, np.nan)

    b = peaks(sorted(starts))
    inside = peaks([s for s in policy_starts if s not in starts and s > period_ticks])
    return {
        "boundary_median": float(np.median(b)),
        "boundary_max": float(b.max()),
        "inside_median": float(np.median(inside)),
        "inside_max": float(inside.max()),
        "boundaries": len(b),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.eval.lerobot.action_chunks", description=__doc__
    )
    p.add_argument("policy", help="the ONNX file policy-export wrote from a LeRobot folder")
    p.add_argument("--robot", default="so101")
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--goals",
        type=int,
        default=0,
        help="a goal-conditioned policy (observation.environment_state): this many goals, 4 s "
        "each, and the goals it reaches (instead of --seconds)",
    )
    args = p.parse_args(argv)
    for smoothing in (False, True):
        if args.goals:
            figures, run = reach_success(
                args.policy, args.robot, args.goals, seed=args.seed, smoothing=smoothing
            )
            print(
                f"smoother {'on ' if smoothing else 'off'}: reached {figures['reached']} of "
                f"{figures['goals']} goals ({figures['rate']:.0%}); median closest approach "
                f"{figures['median_closest'] * 1000:.1f} mm"
            )
        else:
            run = run_chunks(args.policy, args.robot, args.seconds, smoothing, args.seed)
        for what in ("position", "command"):
            f = boundary_jerk(run, what)
            inside = (
                "no policy tick inside a chunk (a call every tick)"
                if np.isnan(f["inside_median"])
                else f"after a policy tick inside a chunk median {f['inside_median']:.3g} max "
                f"{f['inside_max']:.3g}"
            )
            print(
                f"smoother {'on ' if smoothing else 'off'} {what:8s}: peak |jerk| after a chunk "
                f"boundary median {f['boundary_median']:.3g} max {f['boundary_max']:.3g} rad/s^3 "
                f"({f['boundaries']} boundaries); {inside}"
            )
        print(
            f"  {run.policy_ticks} policy ticks, {run.calls} network calls, "
            f"{len(run.position)} servo ticks at {1 / run.dt:g} Hz, guard changed "
            f"{run.guard_clamps} targets"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
