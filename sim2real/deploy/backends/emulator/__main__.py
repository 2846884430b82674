"""``python -m sim2real.deploy.backends.emulator``: serve a robot's servo bus on a pseudo-terminal."""

from __future__ import annotations

import sys

from sim2real.deploy.backends.emulator.bus import PROTOCOLS, ServoBusEmulator
from sim2real.deploy.backends.emulator.faults import FAULT_HELP, WireFaults, parse_fault
from sim2real.deploy.backends.emulator_main import (
    emulator_parser,
    open_emulator,
    parse_faults,
    serve,
)


def main(argv: list[str] | None = None) -> int:
    """Open a pty, print its path (first line of stdout), answer as the robot's servos until
    interrupted (Ctrl-C or SIGTERM); print the bus counters at the end. Exit code 0, or 2 on a
    bad argument or robot."""
    p = emulator_parser(
        "sim2real.deploy.backends.emulator",
        "Emulate a robot's serial servo bus (Feetech STS or Dynamixel Protocol 2.0) on a "
        "pseudo-terminal, with the MuJoCo plant behind the registers.",
    )
    p.add_argument("--protocol", choices=PROTOCOLS, default=None, help="default: the motors'")
    p.add_argument("--baudrate", type=int, default=1_000_000, help="bit/s (timing model)")
    p.add_argument(
        "--latency-us",
        type=float,
        default=None,
        help="reply latency in us (default: each servo's Return_Delay_Time, 500 us)",
    )
    p.add_argument("--mode", choices=("position", "velocity"), default=None)
    p.add_argument("--fault", action="append", default=[], metavar="FAULT", help=FAULT_HELP)
    args = p.parse_args(argv)
    faults = parse_faults(p, args.fault, WireFaults(), parse_fault)
    emulator = open_emulator("servo", ServoBusEmulator, args, faults=faults)
    if emulator is None:
        return 2

    def announce() -> None:
        print(emulator.port, flush=True)
        ids = ", ".join(f"{s.servo_id} ({s.model.name})" for s in emulator.servos)
        print(
            f"{emulator.robot.name}: {emulator.protocol} servos {ids} at {emulator.baudrate} "
            f"bit/s, plant in {emulator.plant.mode} mode",
            file=sys.stderr,
            flush=True,
        )

    # the plant steps on a second thread of this process: a short interpreter-lock slice lets
    # the answering thread take it within ~0.2 ms of a packet (the default slice is 5 ms)
    sys.setswitchinterval(2e-4)
    serve(emulator, emulator.stop, announce=announce)
    print(f"bus counters: {dict(emulator.stats)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
