"""``deploy-run --terrain`` runs judged as rl_sar's own loop
(:mod:`sim2real.stacks.loops.himloco_terrain_loop`) judges itself (the true base 4 m along x, the tile's rim,
before a fall or a stop), with the runtime's stages
switched off one at a time: where does our runtime stall on a tile the own loop crosses?

``python -m bench.stairs_stages --robot ROBOT_DIR --policy POLICY.onnx --tile stairs_up:0.13
--seeds 0-9 [--seconds 20] [--command 0.5,0,0] [--off STAGE[,STAGE]] [--heading-hold 0.5]
[--stand-max S] [--whole]``

Each run is deploy-run's (``--backend sim --terrain TILE --seed S``: its rig, backend and exit
code, built with its own functions), ``--seconds`` walked from the command (``--whole``: its
``--duration``, the start included); ``--stand-max S``: each seed stands U(0, S) s first, as
:func:`sim2real.stacks.loops.himloco_terrain_loop.start_delay` draws it (docs/soak.md, "The first-step
stall"). ``--off`` (evaluation switches, no deploy-run option): ``guard`` (the filter and the
motion check pass everything), ``pd_barrier`` (its changes undone), ``hard_stop`` (counted,
never stopping: :meth:`SafetyGuard.set_stopping`), ``truth_obs`` (the policy observes the
plant's true joints, gyro and gravity), ``noisy_truth_obs`` (the same with the robot's white
sensor noise, drawn by seed, as the own loop's ``--sensor-noise``), ``fall`` (the fall check
never stops), ``runtime`` (the policy's own loop,
:class:`~sim2real.deploy.rig.own_loop.OwnLoop`, on the same plant; with ``noisy_truth_obs`` its
truth noisy, with ``ramp`` after deploy-run's start and first tick), ``heavy_calves`` (an
experiment: the barrier judges every knee with ``INERTIA_SPREAD`` times its least inertia).

Printed per run: crossed (when, s walked), x reached, the stop or fall, deploy-run's exit code,
the hard-violation ticks, each joint's deepest crossing (rad), the interventions per check;
then the crossings per tile.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from sim2real.deploy.core.attitude import quaternion_to_matrix
from sim2real.deploy.core.modes import RUNNING

CROSSED_X = 4.0  # m, sim2real.stacks.loops.himloco_terrain_loop's
STAGES = (
    "guard", "pd_barrier", "hard_stop", "truth_obs", "noisy_truth_obs", "fall", "runtime", "ramp",
    "heavy_calves",
)  # fmt: skip


def _switch_off(rig, stages: set[str], seed: int = 0) -> None:
    """Switch ``stages`` (module docstring) off in ``rig``'s runtime (instance attributes)."""
    rt = rig.runtime
    guard = rt.guard
    if "guard" in stages:

        def passthrough(target, state, out=None, commanded_position=None):
            if out is not None and out is not target:
                np.copyto(out, target)
                return out
            return target

        guard.filter = passthrough
        guard.check_motion = lambda smoother, state, cmd: cmd
    if "pd_barrier" in stages:
        original = guard.filter
        from sim2real.deploy.safety.checks import row

        r = row("pd_barrier")

        def no_barrier(target, state, out=None, commanded_position=None):
            wanted = target.copy()
            before = guard.count_matrix[r].copy()
            got = original(target, state, out=out, commanded_position=commanded_position)
            fired = guard.count_matrix[r] != before
            if fired.any():  # undo the barrier's clamp of those envs (it only clamps PD targets)
                got[fired] = wanted[fired]
            return got

        guard.filter = no_barrier
    if "heavy_calves" in stages:  # the barrier judges the knees 3x heavier (an experiment)
        from sim2real.deploy.safety import pd_barrier as pb

        own = guard._arrays.own[1]  # noqa: SLF001 - the PD barrier's constants (GUARD_CHECKS[1])
        knees = [j for j, n in enumerate(rig.robot.joint_names) if "calf" in n or "knee" in n]
        own[pb.INV_INERTIA, knees] = own[pb.INV_HEAVY, knees]
    if "hard_stop" in stages:
        guard.set_stopping("hard_limit", False)
    if "truth_obs" in stages or "noisy_truth_obs" in stages:
        plant = rig.backend
        sensors = rig.robot.config.sensors
        sigma = (0.0, 0.0, 0.0, 0.0)
        if (
            "noisy_truth_obs" in stages
        ):  # the white noise sim2real.stacks.loops.himloco_terrain_loop draws
            sigma = (sensors.encoder_noise_sigma, sensors.velocity_noise_sigma or 0.0,
                     sensors.imu.gyro_noise_sigma, sensors.imu.orientation_sigma or 0.0)  # fmt: skip
        noise = np.random.default_rng([seed, 7])
        truth = np.zeros((rt.envs, 13))
        observe = rt._observe  # noqa: SLF001 - an evaluation's switch, as the docstring says

        def truth_observe(s):
            kept = (s.q.copy(), s.dq.copy(), s.base.projected_gravity.copy())
            kept += (s.base.angular_velocity.copy(),)
            n = s.q.shape[1]
            s.q[:] = plant.true_position() + noise.normal(0.0, 1.0, n) * sigma[0]
            s.dq[:] = plant.true_velocity() + noise.normal(0.0, 1.0, n) * sigma[1]
            plant.true_base_state(out=truth)
            rot = quaternion_to_matrix(truth[:, 3:7])
            g = -rot[:, 2] + noise.normal(0.0, 1.0, 3) * sigma[3]  # a tilt of about sigma rad
            s.base.projected_gravity[:] = g / np.linalg.norm(g, axis=1, keepdims=True)
            s.base.angular_velocity[:] = truth[:, 10:13] + noise.normal(0.0, 1.0, 3) * sigma[2]
            obs = observe(s)
            s.q[:], s.dq[:], s.base.projected_gravity[:], s.base.angular_velocity[:] = kept
            return obs

        rt._observe = truth_observe  # noqa: SLF001
    if "fall" in stages:  # its limits past reach, in place (the compiled check reads them)
        limits = rt.fall_detector._limits  # noqa: SLF001 - an evaluation's switch
        limits[0], limits[1], limits[2:5] = 10.0, 0.0, 1e9


def one_run(robot_path: str, policy: str, tile: str, seed: int, seconds: float, command: str,
            off: set[str], heading: str | None, whole: bool = False,
            stand_max: float = 0.0) -> dict:  # fmt: skip
    """One run (module docstring): a dict of crossed, t_s, x_m, stop, exit code, hard ticks."""
    from sim2real.deploy.backends.registry import make_backend
    from sim2real.deploy.cli.deploy_run import build_rig, run_policies, run_report
    from sim2real.deploy.cli.run_operator import parse_policies
    from sim2real.deploy.cli.run_parser import (
        attach_vectors,
        build_parser,
        parse_terrain_option,
    )
    from sim2real.deploy.cli.run_verdict import exit_code
    from sim2real.deploy.runtime import SimClock
    from sim2real.deploy.spec.drive import drive_robot
    from sim2real.robots import load_robot

    argv = ["--backend", "sim", "--robot", robot_path, "--policy", policy, "--terrain", tile]
    argv += ["--command", command, "--duration", str(seconds), "--seed", str(seed)]
    if heading is not None:
        argv += ["--heading-hold", heading]
    argv = attach_vectors(argv)
    args = build_parser(argv).parse_args(argv)
    parse_terrain_option(args)  # --terrain's text made its tile draw, as deploy-run's main does
    args.policies = parse_policies(args.policy)
    robot = load_robot(args.robot)
    policies = run_policies(args, robot)
    robot, _ = drive_robot(robot, next(iter(policies.values())).spec)
    backend = make_backend(args, robot, "position")
    clock = SimClock(robot.control_period)
    rig = build_rig(args, robot, policies, backend, None, clock, None, None, None)
    if "runtime" in off:  # the policy's own loop on this plant (the runtime not run)
        noisy, ramp = "noisy_truth_obs" in off, "ramp" in off
        stand = start_delay(seed, stand_max)
        return _own_loop(rig, backend, robot, seed, seconds, command, noisy, ramp, stand)
    _switch_off(rig, off, seed)
    rt = rig.runtime
    truth = np.zeros((1, 13))
    out = {"seed": seed, "crossed": False, "t_s": None, "stop": None, "walk_from": None}
    asked = np.array([float(x) for x in command.split(",")])
    stand = start_delay(seed, stand_max)
    out["stand_s"] = stand

    def on_tick(r) -> bool:
        stop = rig.after_tick(r)
        if out["walk_from"] is None and r.mode[0] == RUNNING:
            out["walk_from"] = r.time - r.dt + stand  # the command's start
        if out["walk_from"] is not None:
            if r.time < out["walk_from"] - 1e-9:  # standing: no command (the next tick's)
                r.velocity_command[0] = 0.0
            elif r.time < out["walk_from"] + r.dt - 1e-9:  # the command given
                r.velocity_command[0, :2] = asked[:2]
        backend.true_base_state(out=truth)
        if out["stop"] is None and rig.true_falls():
            out["stop"] = f"fell at {r.time:.2f} s"
        if out["stop"] is None and r.mode[0] != RUNNING and r.time > 3.0:
            out["stop"] = f"{r.cause_names()[0]} stop at {r.time:.2f} s"
        if out["stop"] is None and not out["crossed"] and truth[0, 0] >= CROSSED_X:
            out.update(crossed=True, t_s=r.time - out["walk_from"])
        walked = out["walk_from"] is not None and r.time - out["walk_from"] >= seconds - 1e-9
        return stop or (walked and not whole)

    backend.open()
    rig.start()
    # ``seconds`` walked (RUNNING) as the own loop walks them after its get-up; ``whole``: the
    # run's --duration ``seconds`` as deploy-run counts it (its start's RAMP_IN included)
    extra = 0.0 if whole else 5.0 + stand
    rt.run(int(round((seconds + extra) / robot.control_period)), on_tick=on_tick)
    rig.close()
    backend.true_base_state(out=truth)
    report = run_report(args, rig, 0.0, False, None, clock)
    report["diverged"] = None
    out["exit"] = exit_code(report, rig)
    out["x_m"] = float(truth[0, 0])
    ticks = rig.violations.hard_joint_ticks[0]
    out["hard"] = {robot.joint_names[j]: int(t) for j, t in enumerate(ticks) if t}
    out["hard"].update(report["hard_violations"])
    out["depth"] = {
        k: round(v["depth_rad"], 4) for k, v in report["violations"]["hard_limit_joints"].items()
    }
    checks = report["interventions"]["checks"]
    out["interventions"] = {k: c["count"] for k, c in checks.items() if c["count"]}
    backend.close()
    return out


def _own_loop(
    rig, backend, robot, seed: int, seconds: float, command: str, noisy: bool, ramp: bool = False,
    stand: float = 0.0,
) -> dict:  # fmt: skip
    """:class:`~sim2real.deploy.rig.own_loop.OwnLoop` (the true state, no guard, no estimate)
    on ``rig``'s plant: the result of :func:`one_run` without the exit code. ``noisy``: the
    true state with the white noise of ``noisy_truth_obs`` (module docstring)."""
    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.rig.own_loop import OwnLoop

    state = RobotState.legged(1, robot.n_joints, robot.n_feet)
    state.command[0] = [float(x) for x in command.split(",")]
    loop = OwnLoop(rig.policy, backend, state, np.zeros((1, 3)), robot.control_period)
    if noisy:
        sensors, rng = robot.config.sensors, np.random.default_rng([seed, 7])
        sigma = (sensors.encoder_noise_sigma, sensors.velocity_noise_sigma or 0.0,
                 sensors.imu.gyro_noise_sigma, sensors.imu.orientation_sigma or 0.0)  # fmt: skip
        observe = loop.spec.observation

        def noisy_observation(s, goal, out=None):
            n = s.q.shape[1]
            s.q += rng.normal(0.0, 1.0, n) * sigma[0]
            s.dq += rng.normal(0.0, 1.0, n) * sigma[1]
            g = s.base.projected_gravity + rng.normal(0.0, 1.0, 3) * sigma[3]
            s.base.projected_gravity[:] = g / np.linalg.norm(g, axis=1, keepdims=True)
            s.base.angular_velocity += rng.normal(0.0, 1.0, 3) * sigma[2]
            return observe(s, goal, out=out)

        loop.spec = _Spec(loop.spec, noisy_observation)
    backend.open()
    if ramp:  # our runtime's start first: its RAMP_IN, until RUNNING
        rig.start()
        while rig.runtime.mode[0] != RUNNING:
            rig.runtime.tick()
    truth = np.zeros((1, 13))
    out = {"seed": seed, "crossed": False, "t_s": None, "stop": None, "exit": None, "hard": {}}
    lo, up = robot.position_lower, robot.position_upper
    hard = np.zeros(robot.n_joints, dtype=np.int64)
    ground = backend.grounds[0] if getattr(backend, "grounds", None) else None
    asked = state.command[0].copy()
    for _ in range(int(round((seconds + stand) / robot.control_period))):
        state.command[0] = 0.0 if loop.time < stand - 1e-9 else asked
        loop.tick()
        backend.true_base_state(out=truth)
        q = backend.true_position()[0]
        hard += (q < lo) | (q > up)
        floor = 0.0 if ground is None else float(ground.height_at(truth[0, 0], truth[0, 1]))
        up_z = 1 - 2 * (truth[0, 4] ** 2 + truth[0, 5] ** 2)
        if truth[0, 2] - floor < 0.4 * 0.32 or np.arccos(np.clip(up_z, -1, 1)) > 1.0:
            out["stop"] = f"fell at {loop.time:.2f} s"
            break
        if truth[0, 0] >= CROSSED_X and not out["crossed"]:
            out.update(crossed=True, t_s=loop.time - stand)
    out["x_m"] = float(truth[0, 0])
    out["hard"] = {robot.joint_names[j]: int(t) for j, t in enumerate(hard) if t}
    backend.close()
    return out


class _Spec:
    """A policy spec whose ``observation`` is another function (the rest delegated)."""

    def __init__(self, spec, observation):
        self._spec, self.observation = spec, observation

    def __getattr__(self, name):
        return getattr(self._spec, name)


def start_delay(seed: int, stand_max: float) -> float:
    """s the robot stands (no command) before the command is given: U(0, ``stand_max``) drawn
    from ``seed`` (``numpy.random.default_rng([seed, 3])``, as
    :func:`sim2real.stacks.loops.himloco_terrain_loop.start_delay` draws it for the own loop); 0
    without one."""
    if stand_max <= 0.0:
        return 0.0
    return float(np.random.default_rng([seed, 3]).uniform(0.0, stand_max))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.stairs_stages", description=__doc__)
    p.add_argument("--robot", required=True)
    p.add_argument("--policy", required=True)
    p.add_argument("--tile", action="append", required=True)
    p.add_argument("--seeds", default="0-2")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--command", default="0.5,0,0")
    p.add_argument("--heading-hold", default=None)
    p.add_argument(
        "--whole", action="store_true",
        help="the run's --duration as deploy-run counts it (its RAMP_IN included); default: "
        "--seconds walked (RUNNING), as the own loop counts them after its get-up",
    )  # fmt: skip
    p.add_argument(
        "--stand-max", type=float, default=0.0,
        help="s: each seed stands U(0, S) s before the command is given (the gait's phase at "
        "the first step drawn; the own loop's --stand-max draws the same)",
    )  # fmt: skip
    p.add_argument("--off", default="", help=f"comma-separated of {', '.join(STAGES)}")
    a = p.parse_args(argv)
    off = {s for s in a.off.split(",") if s}
    if off - set(STAGES):
        p.error(f"--off: unknown {sorted(off - set(STAGES))}; expected of {STAGES}")
    lo, _, hi = a.seeds.partition("-")
    for tile in a.tile:
        runs = []
        for seed in range(int(lo), int(hi or lo) + 1):
            r = one_run(
                a.robot, a.policy, tile, seed, a.seconds, a.command, off, a.heading_hold, a.whole,
                a.stand_max,
            )  # fmt: skip
            runs.append(r)
            when = f"crossed at {r['t_s']:.2f} s" if r["crossed"] else "not crossed"
            print(
                f"  {tile} seed {seed}: {when}, x {r['x_m']:.2f} m, {r['stop'] or 'no stop'}, "
                f"exit {r['exit']}, hard ticks {r['hard']}, depth {r.get('depth')}, "
                f"interventions {r.get('interventions')}",
                flush=True,
            )
        n = sum(r["crossed"] for r in runs)
        print(f"{tile} off={','.join(sorted(off)) or '-'}: crossed {n}/{len(runs)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
