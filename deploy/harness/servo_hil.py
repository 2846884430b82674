"""``python -m deploy.harness.servo_hil``: deploy-run on a servo bus, against the emulator.

Hardware-in-the-loop without the hardware: starts the wire-protocol emulator
(``python -m deploy.backends.emulator``) in its own process, reads the pseudo-terminal it
prints, runs ``deploy-run --backend <protocol> --port <pty>`` with the remaining arguments in a
second process (two processes, as a real bus has: the emulator's plant and the SDK's busy
receive loop would otherwise share one interpreter lock), then stops the emulator and prints
its bus counters. ``make hil`` runs the shipped SO-101 policy through it for 60 s::

    python -m deploy.harness.servo_hil --robot so101 --protocol feetech \\
        [--fault corrupt:0.01 ...] -- --policy policies/so101.onnx --duration 60

The exit code is deploy-run's (0 clean, 2 fault, 3 bad input); 3 also when the emulator does
not start.
"""

from __future__ import annotations

import argparse
import selectors
import signal
import subprocess
import sys
from collections.abc import Sequence

from deploy.backends.emulator.bus import PROTOCOLS
from deploy.backends.emulator.faults import FAULT_HELP
from deploy.cli.run_parser import split_passthrough

#: s to wait for the emulator's first line (its pty path): loading the robot and its plant.
START_TIMEOUT = 60.0
EXIT_BAD_INPUT = 3


def main(argv: list[str] | None = None) -> int:
    """Run the emulator and deploy-run against it; see the module docstring."""
    argv, rest = split_passthrough(argv)
    p = argparse.ArgumentParser(
        prog="python -m deploy.harness.servo_hil",
        description="deploy-run on a servo bus served by the wire-protocol emulator; arguments "
        "after '--' go to deploy-run.",
    )
    p.add_argument("--robot", required=True, help="shipped robot name or robot.toml path")
    p.add_argument("--protocol", choices=PROTOCOLS, required=True)
    p.add_argument("--baudrate", type=int, default=1_000_000, help="bit/s, both sides")
    p.add_argument("--seed", type=int, default=0, help="the emulator plant's seed")
    p.add_argument("--fault", action="append", default=[], metavar="FAULT", help=FAULT_HELP)
    args = p.parse_args(argv)
    emulator, port = start_emulator(
        args.robot, args.protocol, args.baudrate, args.seed, args.fault, stderr=None
    )
    try:
        if port is None:
            print(
                f"hil: the emulator did not start (exit code {emulator.poll()}); its error is "
                "above",
                file=sys.stderr,
            )
            return EXIT_BAD_INPUT
        run = [
            sys.executable,
            "-m",
            "deploy.cli.deploy_run",
            "--backend",
            args.protocol,
            "--port",
            port,
            "--baudrate",
            str(args.baudrate),
            "--robot",
            args.robot,
            *rest,
        ]
        print(f"hil: {args.protocol} emulator on {port}; deploy-run {' '.join(run[3:])}")
        sys.stdout.flush()
        return subprocess.call(run)
    finally:
        stop_emulator(emulator)


def start_emulator(
    robot: str,
    protocol: str,
    baudrate: int = 1_000_000,
    seed: int = 0,
    faults: Sequence[str] = (),
    stderr=subprocess.DEVNULL,
) -> tuple[subprocess.Popen, str | None]:
    """``python -m deploy.backends.emulator`` in its own process, and the pty it serves on (its
    first line of stdout; None when it exits or says nothing within ``START_TIMEOUT`` s).
    ``faults``: ``--fault`` texts. ``stderr``: where its messages go (None: inherited). Stop it
    with :func:`stop_emulator`."""
    cmd = [
        sys.executable,
        "-m",
        "deploy.backends.emulator",
        "--robot",
        robot,
        "--protocol",
        protocol,
        "--baudrate",
        str(baudrate),
        "--seed",
        str(seed),
    ]
    for fault in faults:
        cmd += ["--fault", fault]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=stderr, text=True)
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    if not sel.select(timeout=START_TIMEOUT):
        return proc, None
    return proc, proc.stdout.readline().strip() or None


def stop_emulator(proc: subprocess.Popen) -> None:
    """SIGTERM (the emulator prints its bus counters and exits), then kill after 10 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


if __name__ == "__main__":
    raise SystemExit(main())
