"""``python -m sim2real.deploy.backends.unitree.emulator``: serve a Unitree robot's low-level DDS topics."""

from __future__ import annotations

import argparse
import json
import sys

from sim2real.deploy.backends.emulator_main import (
    emulator_parser,
    open_emulator,
    parse_faults,
    serve,
)
from sim2real.deploy.backends.unitree.emulator.band import BAND_HELP
from sim2real.deploy.backends.unitree.emulator.faults import FAULT_HELP, EmulatorFaults, parse_fault
from sim2real.deploy.backends.unitree.emulator.robot import START_HELP, STARTS, UnitreeEmulator


def build_parser() -> argparse.ArgumentParser:
    """The emulator's command line (``--help`` lists it)."""
    p = emulator_parser(
        "sim2real.deploy.backends.unitree.emulator",
        "Emulate a Unitree robot's low-level DDS interface (rt/lowstate, rt/lowcmd, the motion "
        "switcher) with the MuJoCo plant behind it.",
    )
    p.add_argument("--family", choices=("unitree_go", "unitree_hg"), default=None)
    p.add_argument("--network-interface", default="lo", metavar="IF", help="default: lo")
    p.add_argument("--domain-id", type=int, default=1, help="DDS domain (default 1)")
    p.add_argument(
        "--sport-mode",
        default="",
        help="report this high-level mode active (e.g. normal): the robot ignores LowCmd until "
        "it is released",
    )
    p.add_argument("--mode-machine", type=int, default=0, help="unitree_hg: mode_machine")
    p.add_argument(
        "--cutoff-temperature",
        type=float,
        default=None,
        help="degC at which a driver cuts off (default: the motor's maximum winding + 10 K)",
    )
    p.add_argument("--start", choices=STARTS, default=STARTS[0], help=START_HELP)
    p.add_argument(
        "--bridge",
        choices=("unitree_mujoco",),
        default=None,
        help="behave as Unitree's simulation bridge: LowState without CRC, tick or foot forces, "
        "the PD torque computed on a LowCmd's arrival and held",
    )
    p.add_argument("--band", default=None, metavar="LENGTH[@RELEASE]", help=BAND_HELP)
    p.add_argument("--fault", action="append", default=[], metavar="FAULT", help=FAULT_HELP)
    p.add_argument(
        "--remote",
        default=None,
        metavar="TOML",
        help="play a scripted wireless remote in LowState's wireless_remote (times after the "
        "first LowCmd; sim2real.deploy.backends.unitree.remote)",
    )
    p.add_argument(
        "--trace",
        default=None,
        metavar="NPZ",
        help="write the base's true planar trajectory (50 Hz) and the damping onsets here at "
        "the end",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Serve until interrupted (Ctrl-C or SIGTERM); the first line of stdout says where, the
    counters go to stderr at the end as JSON. Exit code 0, or 2 on a bad argument."""
    p = build_parser()
    args = p.parse_args(argv)
    faults = parse_faults(p, args.fault, EmulatorFaults(), parse_fault)
    emulator = open_emulator(
        "unitree", UnitreeEmulator, args, interface=args.network_interface, faults=faults
    )
    if emulator is None:
        return 2

    def announce() -> None:
        print(
            f"{emulator.robot.name} on interface {args.network_interface}, domain {args.domain_id}",
            flush=True,
        )
        print(
            f"{emulator.robot.name}: {emulator.family.name}, rt/lowstate at "
            f"{1.0 / emulator.period:.0f} Hz, motors {emulator.slots.tolist()}",
            file=sys.stderr,
            flush=True,
        )

    def close() -> None:
        emulator.stop()
        if args.trace:
            emulator.save_trace(args.trace)

    counters = serve(emulator, close, emulator.counters, announce)
    print(f"emulator counters: {json.dumps(counters)}", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
