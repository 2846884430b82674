"""What a height scan adds to a legged tick: the Go2 walker with and without legged_gym's 17 x 11
scan input (:func:`sim2real.deploy.export.scan_input.add_unused_scan`), one env on the plane,
lockstep, the runtime's tick cost (without physics) per tick, and the plant's ray casts alone.

Usage::

    python -m bench.height_scan_cost [--ticks 500] [--out DIR]

Prints one line per figure (us, p50 and p99); a figure, not a test (the machine's load moves it).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import POLICIES


def tick_costs(robot, policy_path: Path, ticks: int) -> np.ndarray:
    """(ticks,) us, the runtime's tick without physics, the walker commanded 0.5 m/s ahead."""
    from sim2real.deploy.backends.sim.height_scan import attach_height_scanner
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime

    policy = OnnxPolicy(policy_path, robot)
    plant = SimBackend(robot, policy.spec.action.mode, envs=1)
    attach_height_scanner(plant, policy.spec)
    rt = Runtime(robot, policy, plant)
    rt.start()
    rt.velocity_command[:] = [0.5, 0.0, 0.0]
    rt.run(50)  # warm
    costs = []
    for _ in range(ticks):
        t0 = time.perf_counter_ns()
        rt.tick()
        costs.append((time.perf_counter_ns() - t0) / 1e3)
    return np.asarray(costs)


def main(argv=None) -> None:
    from sim2real.deploy.backends.sim.height_scan import PlantHeightScanner
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.export import export_policy
    from sim2real.deploy.export.scan_input import add_unused_scan
    from sim2real.deploy.spec.height_scan import HeightScanPattern
    from sim2real.robots import load_robot

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ticks", type=int, default=500)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp())
    robot = load_robot("go2")
    walker = export_policy(POLICIES / "go2.pt", out=out / "go2.onnx")
    scan, _ = add_unused_scan(walker, out / "go2_scan.onnx")
    plant = SimBackend(robot, "position", envs=1)
    scanner = PlantHeightScanner(plant, HeightScanPattern())
    scanner.true_scan()
    casts = []
    for _ in range(args.ticks):
        t0 = time.perf_counter_ns()
        scanner.true_scan()
        casts.append((time.perf_counter_ns() - t0) / 1e3)
    rows = {
        "ray casts alone (187 points, 1 env)": np.asarray(casts),
        "tick, walker": tick_costs(robot, walker, args.ticks),
        "tick, walker + height scan": tick_costs(robot, scan, args.ticks),
    }
    for name, v in rows.items():
        print(f"{name:40s} p50 {np.percentile(v, 50):8.1f} us  p99 {np.percentile(v, 99):8.1f} us")


if __name__ == "__main__":
    main()
