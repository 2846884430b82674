"""The base estimate against the simulator's truth, per shipped legged robot, in steady walking.

``python -m bench.estimation [--robots go2,h1,h1_2] [--seconds 20] [--command 0.5] [--json out]``

Each robot's shipped policy (``sim2real/policies/go2.onnx``, unitree_rl_gym's published H1 and H1-2
policies in ``tests/data/unitree_rl_gym``) walks at ``--command`` m/s through
:class:`sim2real.deploy.runtime.Runtime` over :class:`~sim2real.deploy.backends.sim.plant.SimBackend` with the
IMU noise model its ``robot.toml`` ships; :class:`sim2real.deploy.monitors.estimation.EstimationMonitor`
compares the base estimate with the truth on every RUNNING tick after ``--settle`` s: attitude
error (mean, p95, deg), forward speed estimated and true, the bias (target within 5 %) and the
planar RMS error (target 0.1 m/s); attitude targets: mean 1 deg, p95 2 deg. For the published
humanoid policies it also gives the walking speed (planar path over the same window, truth)
through the runtime and in the policy's own loop on the true state (unitree_rl_gym's
deploy_mujoco loop, :func:`bench.push_reference.unitree_loop`): a policy trained on the
simulator's state should walk within 10 % of its own loop's speed through the runtime.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
POLICIES = {
    "go2": ROOT / "sim2real" / "policies" / "go2.onnx",
    "h1": ROOT / "tests" / "data" / "unitree_rl_gym" / "h1" / "h1.onnx",
    "h1_2": ROOT / "tests" / "data" / "unitree_rl_gym" / "h1_2" / "h1_2.onnx",
}
#: Robots whose published policy's own loop runs here (unitree_rl_gym's deploy_mujoco loop).
OWN_LOOP = ("h1", "h1_2")
#: The targets of a policy-grade estimate (deg, deg, fraction, m/s).
TARGETS = {"attitude_mean": 1.0, "attitude_p95": 2.0, "bias": 0.05, "rms": 0.1}


def measure(
    robot_name: str,
    seconds: float,
    command: float,
    settle: float,
    seed: int,
    user: dict | None = None,
) -> dict:
    """One robot's walk; the :meth:`EstimationMonitor.summary` of its RUNNING ticks after
    ``settle`` s, with ``"final_state"``. ``user``: a user's robot (``{"robot": folder,
    "policy": ONNX}`` and, for its own loop, ``"config"``: unitree_rl_gym's deploy_mujoco yaml,
    ``"torchscript"``: its ``motion.pt``) in place of a shipped one."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.monitors.estimation import EstimationMonitor
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime
    from sim2real.robots import load_robot

    path = Path(user["policy"]) if user else POLICIES[robot_name]
    if not path.exists() and path.with_suffix(".pt").exists():
        from sim2real.deploy.export import run_export

        run_export(path.with_suffix(".pt"))
    robot = load_robot(user["robot"] if user else robot_name)
    policy = OnnxPolicy(path, robot)
    backend = SimBackend(robot, mode=policy.spec.action.mode, seed=seed)
    rt = Runtime(robot, policy, backend)
    rt.velocity_command[:] = (command, 0.0, 0.0)
    monitor = EstimationMonitor(robot, 1)

    start = {}

    def on_tick(r):
        if r.time >= settle:
            truth = backend.true_base_state()
            monitor.update(r, truth)
            start.setdefault("xy", truth[0, :2].copy())
            start.setdefault("t", r.time)

    rt.start()
    rt.run(int(round(seconds / robot.control_period)), on_tick=on_tick)
    out = monitor.summary() or {}
    out["final_state"] = rt.mode_names()[0]
    if start:
        out["speed_m_s"] = _speed(start, rt.time, backend.true_base_state()[0, :2])
    if user and "config" in user:
        files = (Path(user["config"]), Path(user["torchscript"]))
        out["own_loop_speed_m_s"] = own_loop_speed(robot, files, seconds, command, settle)
    elif robot_name in OWN_LOOP:
        from bench.push_reference import DATA

        files = (DATA / robot_name / f"{robot_name}.yaml", DATA / robot_name / "motion.pt")
        out["own_loop_speed_m_s"] = own_loop_speed(robot, files, seconds, command, settle)
    return out


def _speed(start: dict, t: float, xy) -> float:
    """m/s, the base's planar displacement since ``start`` over the time since."""
    return float(np.linalg.norm(np.asarray(xy) - start["xy"]) / (t - start["t"]))


def own_loop_speed(robot, files, seconds: float, command: float, settle: float):
    """m/s, the published policy's speed in its own stack's loop on the true state
    (:func:`bench.push_reference.unitree_loop`, no push), over the same window; None if it
    fell."""
    import yaml

    from bench.push_reference import unitree_loop
    from sim2real.stacks.loops.unitree_rl_gym import load_torchscript

    cfg = yaml.safe_load(Path(files[0]).read_text())
    cfg["cmd_init"] = [command, 0.0, 0.0]
    path: list = []
    run = unitree_loop(robot, cfg, load_torchscript(Path(files[1])), 0, seconds, None, path=path)
    if run.fell_at is not None:
        return None
    rows = np.array(path)
    k = int(np.searchsorted(rows[:, 0], settle))
    return _speed({"xy": rows[k, 1:], "t": rows[k, 0]}, rows[-1, 0], rows[-1, 1:])


def _f(x) -> str:
    return "n/a" if x is None else f"{x:.3f}"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.estimation", description=__doc__)
    p.add_argument("--robots", default="go2,h1,h1_2")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--settle", type=float, default=4.0)
    p.add_argument("--command", type=float, default=0.5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None)
    p.add_argument(
        "--user",
        action="append",
        default=[],
        metavar="NAME=ROBOT_DIR,POLICY_ONNX[,DEPLOY_YAML,MOTION_PT]",
        help="a user's imported robot and exported policy (and, for its own loop's speed, "
        "unitree_rl_gym's deploy_mujoco yaml and TorchScript policy); repeatable",
    )
    args = p.parse_args(argv)
    rows = {}
    print("| robot | attitude error mean / p95 (deg) | forward speed est / true (m/s) | bias | "
          "planar RMS (m/s) | speed: runtime / own loop (m/s) | final |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- |")
    users = {}
    for item in args.user:
        name, _, rest = item.partition("=")
        parts = rest.split(",")
        if not name or len(parts) not in (2, 4):
            p.error(f"--user {item!r}: expected NAME=ROBOT_DIR,POLICY[,DEPLOY_YAML,MOTION_PT]")
        users[name] = dict(zip(("robot", "policy", "config", "torchscript"), parts, strict=False))
    names = [n for n in args.robots.split(",") if n] + list(users)
    for name in names:
        r = measure(name, args.seconds, args.command, args.settle, args.seed, users.get(name))
        rows[name] = r
        if "attitude_error_deg" not in r:
            print(f"| {name} | n/a (never RUNNING) | | | | {r['final_state']} |")
            continue
        att, speed, bias = (
            r["attitude_error_deg"],
            r["forward_speed_m_s"],
            r["velocity_bias_fraction"],
        )
        print(
            f"| {name} | {att['mean']:.2f} / {att['p95']:.2f} | {speed['estimated']:.3f} / "
            f"{speed['true']:.3f} | "
            + (f"{100 * bias:+.1f} %" if bias is not None and np.isfinite(bias) else "n/a")
            + f" | {r['velocity_rms_m_s']:.3f} | {_f(r.get('speed_m_s'))} / "
            f"{_f(r.get('own_loop_speed_m_s'))} | {r['final_state']} |"
        )
    if args.json is not None:
        args.json.write_text(json.dumps({"targets": TARGETS, "robots": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
