"""A LeRobot export's action chunks on the MuJoCo SO-101 as ``deploy-run --backend sim`` runs them
(:func:`run_chunks`): a thin wrapper over the Rig (the runtime with its state machine,
supervision, guard and smoother; the chunked policy,
:class:`~sim2real.deploy.policy.lerobot_policy.LeRobotChunkPolicy`, at its own rate beside the
servo loop; the goal task's goals for a goal-conditioned export) and its
:class:`~sim2real.deploy.rig.chunk_hook.ChunkHook`.

``python -m sim2real.eval.lerobot.action_chunks POLICY.onnx [--goals N] [--seconds S] [--seed N]``
prints the goals reached (``--goals``: N goals, :data:`GOAL_PERIOD` s each, the goal task's rule:
within its radius and 3 s) and the peak joint jerk after a chunk boundary against after a policy
tick inside a chunk, of the true joints, of the guard's target (what a loop without the smoother
writes to the servos, LeRobot's own) and of the smoothed command
(:mod:`sim2real.deploy.observe.chunk_jerk`); the same figures as ``deploy-run --backend sim
--robot so101 --policy POLICY.onnx --duration D --goal-period 4``. A camera key needs the MJCF's
camera of its name (deploy-run's ``--camera-source`` for a recorded video).
"""

from __future__ import annotations

import argparse

import numpy as np

#: s per goal (deploy-run's ``--goal-period`` default; the goal task's ``success_time`` 3 s).
GOAL_PERIOD = 4.0


def run_chunks(
    onnx_path, robot_name: str = "so101", seconds: float = 10.0, seed: int = 0
) -> tuple[dict, dict]:
    """The export on the plant for ``seconds`` s with the goal task (a new goal every
    :data:`GOAL_PERIOD` s from ``default_rng(seed + 1)``, as deploy-run seeds it): the rig's
    report (``goals``, ``interventions``, ``violations``, ...) and its ``chunks`` figures.

    Raises:
        LeRobotFormatError: the export does not fit the robot (one line).
        ValueError: a camera key the MJCF has no camera for (one line).
    """
    from sim2real.deploy.backends.sim import camera as plant_camera
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy
    from sim2real.deploy.rig.chunk_hook import ChunkHook
    from sim2real.deploy.rig.rig import MotionHook, Rig
    from sim2real.robots import load_robot

    robot = load_robot(robot_name)
    policy = LeRobotChunkPolicy(onnx_path, robot)
    backend = SimBackend(robot, "position", envs=1, seed=seed)
    plant_camera.attach_plant_camera(backend, policy.spec, None, None, seed=seed)
    task = {"period": GOAL_PERIOD, "rng": np.random.default_rng(seed + 1), "schedule": False}
    rig = Rig(robot, policy, backend, envs=1, task=task)
    rig.add(MotionHook(rig))
    chunks = rig.add(ChunkHook(rig))
    backend.open()
    try:
        rig.start()
        rig.run(int(round(seconds / robot.control_period)))
        rig.close()
        return rig.report(), chunks.figures()
    finally:
        backend.close()


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
        help=f"this many goals, {GOAL_PERIOD:g} s each, and the goals reached (instead of "
        "--seconds)",
    )
    args = p.parse_args(argv)
    seconds = args.goals * GOAL_PERIOD if args.goals else args.seconds
    report, c = run_chunks(args.policy, args.robot, seconds, args.seed)
    g = report.get("goals") or {}
    if args.goals:
        print(f"goals: {g.get('reached')} of {g.get('issued')} reached")
    print(
        f"policy at {c['policy_rate_hz']:g} Hz beside {c['servo_rate_hz']:g} Hz: "
        f"{c['policy_ticks']} policy ticks, {c['network_calls']} network calls; policy ticks "
        f"per chunk {c['policy_ticks_per_chunk']}"
    )
    for what, label in (
        ("position", "true joints"),
        ("target", "target, no smoother"),
        ("command", "command, smoothed"),
    ):
        f = c[what]
        print(
            f"{label:20s}: peak |jerk| after a chunk boundary median {f['boundary_median']:.3g} "
            f"max {f['boundary_max']:.3g} rad/s^3 ({f['boundaries']} boundaries); inside a "
            f"chunk median {f['inside_median']:.3g} max {f['inside_max']:.3g} ({f['inside']})"
        )
    print(f"interventions: {report['interventions']['any']['fraction']:.2%} of ticks")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
