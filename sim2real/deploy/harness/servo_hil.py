"""``python -m sim2real.deploy.harness.servo_hil``: deploy-run on a servo bus, against the emulator.

Hardware-in-the-loop without the hardware: starts the wire-protocol emulator
(``python -m sim2real.deploy.backends.emulator``) in its own process, reads the pseudo-terminal it
prints, runs ``deploy-run --backend <protocol> --port <pty>`` with the remaining arguments in a
second process (two processes, as a real bus has: the emulator's plant and the SDK's busy
receive loop would otherwise share one interpreter lock), then stops the emulator and prints
its bus counters. ``make hil`` runs the shipped SO-101 policy through it for 60 s::

    python -m sim2real.deploy.harness.servo_hil --robot so101 --protocol feetech \\
        [--fault corrupt:0.01 ...] -- --policy sim2real/policies/so101.onnx --duration 60

The exit code is deploy-run's (0 clean, 2 fault, 3 bad input); 3 also when the emulator does
not start.
"""

from __future__ import annotations

import subprocess
from collections.abc import Sequence

from sim2real.deploy.backends.emulator.bus import PROTOCOLS
from sim2real.deploy.backends.emulator.faults import FAULT_HELP
from sim2real.deploy.backends.sim.options import add_plant_motors_option
from sim2real.deploy.harness.common import (
    deploy_run_command,
    hil_parser,
    parse_hil,
    run_beside,
    spawn_emulator,
    stop_emulator,
)

__all__ = ["main", "start_emulator", "stop_emulator"]


def main(argv: list[str] | None = None) -> int:
    """Run the emulator and deploy-run against it; see the module docstring."""
    p = hil_parser(
        "servo_hil",
        "deploy-run on a servo bus served by the wire-protocol emulator; arguments after '--' go "
        "to deploy-run.",
        fault_help=FAULT_HELP,
    )
    p.add_argument("--protocol", choices=PROTOCOLS, required=True)
    p.add_argument("--baudrate", type=int, default=1_000_000, help="bit/s, both sides")
    add_plant_motors_option(p)  # the servos as they really are, unknown to deploy-run
    args, rest = parse_hil(p, argv)
    emulator, port = start_emulator(
        args.robot, args.protocol, args.baudrate, args.seed, args.fault, stderr=None,
        plant_motors=args.plant_motors,
    )  # fmt: skip
    run = deploy_run_command(
        args.protocol, "--port", str(port), "--baudrate", str(args.baudrate), "--robot", args.robot
    )
    return run_beside(emulator, port, f"{args.protocol} emulator on {port}", [*run, *rest])


def start_emulator(
    robot: str,
    protocol: str,
    baudrate: int = 1_000_000,
    seed: int = 0,
    faults: Sequence[str] = (),
    stderr=subprocess.DEVNULL,
    plant_motors: str | None = None,
) -> tuple[subprocess.Popen, str | None]:
    """``python -m sim2real.deploy.backends.emulator`` in its own process, and the pty it serves on (its
    first line of stdout; None when it exits or says nothing within
    :data:`sim2real.deploy.harness.common.START_TIMEOUT` s). ``faults``: ``--fault`` texts. ``stderr``:
    where its messages go (None: inherited). ``plant_motors``: the emulator's plant motors file
    (:mod:`sim2real.robots.plant_motors`). Stop it with :func:`stop_emulator`."""
    args = ["--robot", robot, "--protocol", protocol, "--baudrate", str(baudrate)]
    if plant_motors is not None:
        args += ["--plant-motors", str(plant_motors)]
    return spawn_emulator(
        "sim2real.deploy.backends.emulator", [*args, "--seed", str(seed)], faults, stderr=stderr
    )


if __name__ == "__main__":
    raise SystemExit(main())
