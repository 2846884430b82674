"""A scripted run of the MuJoCo plant: ``python -m sim2real.deploy.backends.sim.demo`` holds a robot at its
home pose on its measured encoder angles and prints what the plant did (joint error, torque,
winding temperature, dropped readings, simulation speed).

The controller sees only the sensor frame (:meth:`sim2real.deploy.backends.sim.plant.SimBackend.read`), like
a real one; the summary reads the plant's true state.
"""

from __future__ import annotations

import argparse
import time as _time

import numpy as np

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.robots import CONTROL_MODES, load_robot


def main(argv: list[str] | None = None) -> int:
    """Hold the robot at its home pose with a scripted controller and print a summary.

    The controller acts on the *measured* (noisy, quantized) encoder angles only, like a real one.
    """
    p = argparse.ArgumentParser(
        prog="python -m sim2real.deploy.backends.sim.demo", description=main.__doc__
    )
    p.add_argument("--robot", default="arm3", help="shipped robot name or robot.toml path")
    p.add_argument("--mode", choices=CONTROL_MODES, default=None, help="default: from robot.toml")
    p.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    robot = load_robot(args.robot)
    plant = SimBackend(robot, mode=args.mode, seed=args.seed)
    ticks = int(round(args.duration / robot.control_period))
    target = robot.home[None, :]
    last = target.copy()
    peak = np.full(robot.n_joints, -np.inf)
    worst_error = np.zeros(robot.n_joints)
    dropped = 0
    t0 = _time.perf_counter()
    step_time = 0.0
    for _ in range(ticks):
        frame = plant.read()
        missing = np.isnan(frame.position)
        dropped += int(missing.sum())
        q = np.where(missing, last, frame.position)
        last = q
        if plant.mode == "position":
            cmd = target
        elif plant.mode == "velocity":
            cmd = np.clip(5.0 * (target - q), -robot.velocity_limit, robot.velocity_limit)
        else:
            cmd = robot.gravity_torque(q[0])[None, :] + 50.0 * (target - q)
        plant.write(cmd)
        s = _time.perf_counter()
        plant.advance()
        step_time += _time.perf_counter() - s
        peak = np.maximum(peak, frame.winding_temperature[0])
        worst_error = np.maximum(worst_error, np.abs(plant.true_position()[0] - robot.home))
    wall = _time.perf_counter() - t0
    names = robot.joint_names
    print(
        f"robot {robot.name}: {robot.n_joints} joints, {plant.mode} control, "
        f"{1 / robot.control_period:.0f} Hz control, {1 / robot.physics_timestep:.0f} Hz physics"
    )
    print(
        f"simulated {args.duration:.1f} s in {wall:.2f} s wall "
        f"({args.duration / wall:.0f}x real time); "
        f"physics + thermal {1e6 * step_time / ticks:.1f} us per control tick"
    )
    print("scripted controller: hold the home pose on measured encoder angles")
    print(f"encoder readings dropped: {dropped} of {ticks * robot.n_joints}")
    for i, name in enumerate(names):
        print(
            f"  {name:>14}: max |q - home| {worst_error[i]:.4f} rad, torque "
            f"{plant.joint_torque()[0, i]:+7.3f} N m, "
            f"winding {plant.thermal.winding_temperature[0, i]:6.2f} degC "
            f"(reported peak {peak[i]:.0f} degC, max {robot.motors[i].max_winding_temperature:.0f})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
