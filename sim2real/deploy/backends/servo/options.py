"""``deploy-run --backend feetech|dynamixel``: the serial-bus servos' registration and options
(:mod:`sim2real.deploy.backends.registry`)."""

from __future__ import annotations

from pathlib import Path

from sim2real.deploy.backends.registry import register_backend


def add_options(group) -> None:
    """The serial bus's options: port, bit rate, calibration, torque at the end."""
    group.add_argument("--port", default="/dev/ttyACM0", help="serial port of the servo bus")
    group.add_argument("--baudrate", type=int, default=1_000_000, help="servo bus bit/s")
    group.add_argument(
        "--calibration",
        type=Path,
        default=None,
        help="LeRobot calibration JSON (servo IDs, homing offsets, directions, ranges); "
        "default: IDs 1..n, 2048 ticks = 0 rad",
    )
    group.add_argument(
        "--hold-on-close",
        action="store_true",
        help="leave the torque on at the end (default: off)",
    )


def _bus(cls, args, robot, mode: str):
    if args.envs != 1:
        raise ValueError(f"--backend {args.backend} drives one robot: --envs must be 1")
    if args.inject:
        raise ValueError(
            f"--inject is simulation-only; with --backend {args.backend} use the emulator's "
            "faults (python -m sim2real.deploy.backends.emulator --fault ...)"
        )
    return cls(
        robot,
        args.port,
        baudrate=args.baudrate,
        calibration=args.calibration,
        mode=mode,
        hold_on_close=args.hold_on_close,
    )


def make_feetech(args, robot, mode: str):
    """A Feetech STS bus (``scservo_sdk``) on ``args.port``."""
    from sim2real.deploy.backends.servo.feetech import FeetechBackend

    return _bus(FeetechBackend, args, robot, mode)


def make_dynamixel(args, robot, mode: str):
    """A Dynamixel X bus (Protocol 2.0, ``dynamixel_sdk``) on ``args.port``."""
    from sim2real.deploy.backends.servo.dynamixel import DynamixelBackend

    return _bus(DynamixelBackend, args, robot, mode)


register_backend(
    "feetech",
    "Feetech STS serial-bus servos (wall clock only)",
    "sim2real.deploy.backends.servo.options:make_feetech",
    add_options,
)
register_backend(
    "dynamixel",
    "Dynamixel X serial-bus servos (wall clock only)",
    "sim2real.deploy.backends.servo.options:make_dynamixel",
    add_options,
)
