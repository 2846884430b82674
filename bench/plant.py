"""The MuJoCo plant alone, per robot and control mode (the former ``make bench``).

- ``mj_step``: MuJoCo physics per control tick (``mj_step(m, d, nstep=decimation)``), alone;
- ``plant``: the whole simulated plant per control tick (``SimBackend.read`` + ``write`` +
  ``advance``: physics, divergence check, thermal model, sensor model).

Percentiles of ``ticks`` ticks after a 200-tick warm-up, each timed with
``time.perf_counter_ns``, the garbage collector frozen and disabled.
"""

from __future__ import annotations

import gc
import time

import mujoco
import numpy as np

from bench.common import histogram, summary

MODES = ("position", "velocity", "torque")
WARMUP = 200


def bench_mj_step(robot, mode: str, ticks: int) -> np.ndarray:
    """ns per control tick of bare ``mj_step`` (``nstep=decimation``), shape (ticks,)."""
    m = robot.plant_model(mode)
    d = mujoco.MjData(m)
    d.qpos[:] = robot.home
    if m.na:
        d.act[:] = robot.home
    d.ctrl[:] = robot.home if mode == "position" else 0.0
    if mode == "torque":
        mujoco.mj_forward(m, d)
        d.ctrl[:] = d.qfrc_bias
    out = np.empty(ticks, dtype=np.int64)
    for _ in range(WARMUP):
        mujoco.mj_step(m, d, nstep=robot.decimation)
    for i in range(ticks):
        t = time.perf_counter_ns()
        mujoco.mj_step(m, d, nstep=robot.decimation)
        out[i] = time.perf_counter_ns() - t
    return out


def bench_plant(robot, mode: str, ticks: int) -> np.ndarray:
    """ns per control tick of ``SimBackend`` read + write + advance, shape (ticks,)."""
    from sim2real.deploy.backends.sim.plant import SimBackend

    plant = SimBackend(robot, mode=mode)
    # the command that holds the home pose (what SimBackend.reset starts with)
    if mode == "position":
        cmd = np.array(robot.home)[None]
    elif mode == "velocity":
        cmd = np.zeros((1, robot.n_joints))
    else:
        cmd = robot.gravity_torque(robot.home)[None]
    out = np.empty(ticks, dtype=np.int64)
    for i in range(ticks + WARMUP):
        t = time.perf_counter_ns()
        plant.read()
        plant.write(cmd)
        plant.advance()
        if i >= WARMUP:
            out[i - WARMUP] = time.perf_counter_ns() - t
    return out


def measure(robots: list, ticks: int) -> dict:
    """The ``plant`` entry of results.json: ``{"ticks", "rows": [{robot, mode, what,
    decimation, p50_us, p99_us, p99.9_us, max_us, mean_us, samples}]}``."""
    rows = []
    gc.collect()
    gc.freeze()
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        for robot in robots:
            for mode in MODES:
                for what, fn in (("mj_step", bench_mj_step), ("plant", bench_plant)):
                    row = {
                        "robot": robot.name,
                        "mode": mode,
                        "what": what,
                        "decimation": robot.decimation,
                    }
                    row.update(summary(histogram(fn(robot, mode, ticks))))
                    rows.append(row)
    finally:
        if was_enabled:
            gc.enable()
        gc.unfreeze()
    return {"ticks": ticks, "rows": rows}
