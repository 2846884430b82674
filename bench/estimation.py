"""The base estimate against the simulator's truth, per shipped legged robot, in steady walking.

``python -m bench.estimation [--robots go2,h1,h1_2] [--seconds 20] [--command 0.5] [--json out]``

Each robot's shipped policy (``policies/go2.onnx``, unitree_rl_gym's published H1 and H1-2
policies in ``tests/data/unitree_rl_gym``) walks at ``--command`` m/s through
:class:`deploy.runtime.Runtime` over :class:`~deploy.backends.sim.plant.SimBackend` with the IMU
noise model its ``robot.toml`` ships; :class:`deploy.monitors.estimation.EstimationMonitor`
compares the base estimate with the truth on every RUNNING tick after ``--settle`` s: attitude
error (mean, p95, deg), forward speed estimated and true, the bias (target within 5 %) and the
planar RMS error (target 0.1 m/s); attitude targets: mean 1 deg, p95 2 deg.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
POLICIES = {
    "go2": ROOT / "policies" / "go2.onnx",
    "h1": ROOT / "tests" / "data" / "unitree_rl_gym" / "h1" / "h1.onnx",
    "h1_2": ROOT / "tests" / "data" / "unitree_rl_gym" / "h1_2" / "h1_2.onnx",
}
#: The targets of a policy-grade estimate (deg, deg, fraction, m/s).
TARGETS = {"attitude_mean": 1.0, "attitude_p95": 2.0, "bias": 0.05, "rms": 0.1}


def measure(robot_name: str, seconds: float, command: float, settle: float, seed: int) -> dict:
    """One robot's walk; the :meth:`EstimationMonitor.summary` of its RUNNING ticks after
    ``settle`` s, with ``"final_state"``."""
    from deploy.backends.sim.plant import SimBackend
    from deploy.monitors.estimation import EstimationMonitor
    from deploy.policy.onnx_policy import OnnxPolicy
    from deploy.runtime import Runtime
    from robots import load_robot

    path = POLICIES[robot_name]
    if not path.exists() and path.with_suffix(".pt").exists():
        from deploy.export import run_export

        run_export(path.with_suffix(".pt"))
    robot = load_robot(robot_name)
    policy = OnnxPolicy(path, robot)
    backend = SimBackend(robot, mode=policy.spec.action.mode, seed=seed)
    rt = Runtime(robot, policy, backend)
    rt.velocity_command[:] = (command, 0.0, 0.0)
    monitor = EstimationMonitor(robot, 1)

    def on_tick(r):
        if r.time >= settle:
            monitor.update(r, backend.true_base_state())

    rt.start()
    rt.run(int(round(seconds / robot.control_period)), on_tick=on_tick)
    out = monitor.summary() or {}
    out["final_state"] = rt.mode_names()[0]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.estimation", description=__doc__)
    p.add_argument("--robots", default="go2,h1,h1_2")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--settle", type=float, default=4.0)
    p.add_argument("--command", type=float, default=0.5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    rows = {}
    print("| robot | attitude error mean / p95 (deg) | forward speed est / true (m/s) | bias | "
          "planar RMS (m/s) | final |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- |")
    for name in args.robots.split(","):
        r = measure(name, args.seconds, args.command, args.settle, args.seed)
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
            + f" | {r['velocity_rms_m_s']:.3f} | {r['final_state']} |"
        )
    if args.json is not None:
        args.json.write_text(json.dumps({"targets": TARGETS, "robots": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
