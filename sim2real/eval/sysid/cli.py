"""``sysid``: fit the plant's motors to a robot's log and report the reality gap.

::

    deploy-run --robot so101 --excitation default --duration 66 \
        --record-commands run.npz                          # on the robot (docs/sysid.md)
    sysid --robot so101 --log run.npz --out sysid/         # here

It writes ``sysid/plant_motors.toml`` (the fitted motors, a plant motors file:
``deploy-run --plant-motors``, ``soak-test --plant-motors``; its ``source`` names the log, the date,
the residual and the uncertainties) and the gap between the log and the plant with the described
motors and with the fitted ones (``gap.json``, ``gap.md``, ``gap.png``, ``gap.html``). Exit
codes: 0 the fit reads closer than the described motors, 1 it does not, 3 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

EXIT_OK, EXIT_NO_GAIN, EXIT_BAD_INPUT = 0, 1, 3


def build_parser() -> argparse.ArgumentParser:
    """``sysid``'s options."""
    from sim2real.eval.sysid.fit import MAX_DELAY

    p = argparse.ArgumentParser(prog="sysid", description=__doc__.split("::")[0].strip())
    p.add_argument("--robot", required=True, help="shipped robot name or robot.toml path")
    p.add_argument("--log", type=Path, required=True, help="deploy-run --record-commands file")
    p.add_argument("--out", type=Path, required=True, help="folder for the fit and the report")
    p.add_argument(
        "--max-delay", type=float, default=MAX_DELAY, help="s, the longest command delay searched"
    )
    p.add_argument(
        "--with-damping",
        action="store_true",
        help="fit the viscous damping too (it trades against the dry friction unless the log "
        "spans a wide range of joint speeds)",
    )
    p.add_argument(
        "--truth", type=Path, default=None, help="a plant motors file the log ran on (an "
        "emulated robot): reported beside the fit"
    )  # fmt: skip
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from sim2real.deploy.observe.command_log import read_command_log
    from sim2real.eval.sysid.fit import fit_motors
    from sim2real.eval.sysid.gap import gap_report, write_gap
    from sim2real.robots import load_robot
    from sim2real.robots.files import atomic_write
    from sim2real.robots.plant_motors import load_plant_motors

    try:
        robot = load_robot(args.robot)
        meta, arrays = read_command_log(args.log)
        truth = None if args.truth is None else load_plant_motors(args.truth, robot)
        result = fit_motors(robot, meta, arrays, args.max_delay, args.with_damping)
    except (ValueError, OSError) as exc:
        print(f"sysid: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    args.out.mkdir(parents=True, exist_ok=True)
    text = result.to_toml(str(args.log)) + result.joint_tables(list(robot.joint_names))
    fitted_path = atomic_write(args.out / "plant_motors.toml", text)
    plants = {"described": None, "fitted": load_plant_motors(fitted_path, robot)}
    if truth is not None:
        plants["truth"] = truth
    report = gap_report(robot, meta, arrays, plants)
    write_gap(report, args.out, arrays["t"])
    for m in result.motors:
        values = ", ".join(f"{k} {v:.4g} +- {m.sigma[k]:.2g}" for k, v in m.values.items())
        print(f"sysid: {m.name}: {values}")
    print(
        f"sysid: command delay {1e3 * result.command_delay:.1f} ms; readings "
        f"{1e3 * result.rms_fitted:.2f} mrad RMS off the replay (described motors "
        f"{1e3 * result.rms_described:.2f}); {fitted_path}, {args.out / 'gap.md'}"
    )
    return EXIT_OK if result.rms_fitted < result.rms_described else EXIT_NO_GAIN


if __name__ == "__main__":
    raise SystemExit(main())
