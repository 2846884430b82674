"""`make bench`: write bench/results.json and print a table.

Measures, per robot and control mode:
- ``mj_step``: MuJoCo physics per control tick (``mj_step(m, d, nstep=decimation)``), alone;
- ``plant``: the whole plant per control tick (``read`` + ``write`` + ``advance``: physics, thermal
  model, sensor model).
Percentiles over ``--ticks`` ticks after a warm-up, timed with ``time.perf_counter_ns``.
"""

from __future__ import annotations

import argparse
import gc
import json
import platform
import time
from pathlib import Path

import mujoco
import numpy as np

from deploy.backends.sim import SimBackend
from robots import load_robot

RESULTS = Path(__file__).resolve().parent / "results.json"


def percentiles(samples_ns: np.ndarray) -> dict[str, float]:
    us = samples_ns / 1e3
    return {
        "p50_us": float(np.percentile(us, 50)),
        "p99_us": float(np.percentile(us, 99)),
        "p99.9_us": float(np.percentile(us, 99.9)),
        "mean_us": float(us.mean()),
    }


def bench_mj_step(robot, mode: str, ticks: int) -> dict[str, float]:
    m = robot.plant_model(mode)
    d = mujoco.MjData(m)
    d.qpos[:] = robot.home
    d.ctrl[:] = robot.home if mode == "position" else 0.0
    out = np.empty(ticks, dtype=np.int64)
    for _ in range(200):
        mujoco.mj_step(m, d, nstep=robot.decimation)
    for i in range(ticks):
        t = time.perf_counter_ns()
        mujoco.mj_step(m, d, nstep=robot.decimation)
        out[i] = time.perf_counter_ns() - t
    return percentiles(out)


def bench_plant(robot, mode: str, ticks: int) -> dict[str, float]:
    plant = SimBackend(robot, mode=mode)
    cmd = robot.home[None].copy() if mode == "position" else np.zeros((1, robot.n_joints))
    out = np.empty(ticks, dtype=np.int64)
    for i in range(ticks + 200):
        t = time.perf_counter_ns()
        plant.read()
        plant.write(cmd)
        plant.advance()
        if i >= 200:
            out[i - 200] = time.perf_counter_ns() - t
    return percentiles(out)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    p.add_argument("--ticks", type=int, default=20_000)
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    results = {"machine": platform.platform(), "python": platform.python_version(), "rows": []}
    gc.collect()
    gc.freeze()
    gc.disable()
    try:
        for name in ("arm3", "arm6"):
            robot = load_robot(name)
            for mode in ("position", "velocity", "torque"):
                for what, fn in (("mj_step", bench_mj_step), ("plant", bench_plant)):
                    row = {
                        "robot": name,
                        "mode": mode,
                        "what": what,
                        "decimation": robot.decimation,
                    }
                    row.update(fn(robot, mode, args.ticks))
                    results["rows"].append(row)
    finally:
        gc.enable()
    args.out.write_text(json.dumps(results, indent=2))
    header = ("robot", "mode", "per control tick", "dec", "p50 us", "p99 us", "p99.9 us")
    print("{:6} {:9} {:18} {:>3} {:>8} {:>8} {:>9}".format(*header))
    for r in results["rows"]:
        print(
            f"{r['robot']:6} {r['mode']:9} {r['what']:18} {r['decimation']:>3} "
            f"{r['p50_us']:8.1f} {r['p99_us']:8.1f} {r['p99.9_us']:9.1f}"
        )
    print(f"written {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
