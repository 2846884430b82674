"""``python -m deploy.harness.unitree_hil``: deploy-run over DDS against the emulator.

Hardware-in-the-loop without the robot: starts the Unitree emulator
(``python -m deploy.backends.unitree.emulator``) in its own process on the loopback interface,
waits for its first line, runs ``deploy-run --backend unitree --network-interface lo
--domain-id N`` with the remaining arguments in a second process (two processes, as a robot and
its controller are: the plant's thread and the runtime would otherwise share one interpreter
lock), then stops the emulator, which prints its counters (LowState rate, command-to-state
latency, drivers cut off, the base's true path length). ``make hil ROBOT=go2`` runs the shipped
Go2 policy through it for 60 s::

    python -m deploy.harness.unitree_hil --robot go2 [--fault lose:0.01 ...] -- \\
        --policy policies/go2.onnx --command 0.5,0,0 --duration 60

The exit code is deploy-run's (0 clean, 2 fault, 3 bad input); 3 also when the emulator does
not start.
"""

from __future__ import annotations

import argparse
import json
import selectors
import signal
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from deploy.backends.unitree.emulator.faults import FAULT_HELP
from deploy.backends.unitree.emulator.truth import walk_truth
from deploy.cli.run_parser import split_passthrough

#: s to wait for the emulator's first line: loading the robot, its plant, joining DDS.
START_TIMEOUT = 60.0
EXIT_BAD_INPUT = 3


def main(argv: list[str] | None = None) -> int:
    """Run the emulator and deploy-run against it; see the module docstring."""
    argv, rest = split_passthrough(argv)
    p = argparse.ArgumentParser(
        prog="python -m deploy.harness.unitree_hil",
        description="deploy-run --backend unitree against the Unitree emulator on the loopback "
        "interface; arguments after '--' go to deploy-run.",
    )
    p.add_argument("--robot", required=True, help="shipped robot name or robot.toml path")
    p.add_argument("--domain-id", type=int, default=1, help="DDS domain (default 1)")
    p.add_argument("--seed", type=int, default=0, help="the emulator plant's seed")
    p.add_argument(
        "--start",
        choices=("lying", "standing"),
        default="lying",
        help="lying: folded on the floor, drivers off (as after the robot's stand-down); "
        "standing: holding the home pose until the first LowCmd",
    )
    p.add_argument(
        "--family",
        choices=("unitree_go", "unitree_hg"),
        default=None,
        help="message family of both ends (default: robot.toml's)",
    )
    p.add_argument("--fault", action="append", default=[], metavar="FAULT", help=FAULT_HELP)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="hil-") as tmp:
        return _run(args, rest, Path(tmp))


def _run(args, rest: list[str], tmp: Path) -> int:
    trace = tmp / "trace.npz"
    if "--report" not in rest:
        rest = [*rest, "--report", str(tmp / "report.json")]
    report = Path(rest[rest.index("--report") + 1])
    extra = ["--start", args.start, "--trace", str(trace)]
    if args.family:
        extra += ["--family", args.family]
        rest = [*rest, "--family", args.family]
    emulator, ready = start_emulator(
        args.robot, args.domain_id, args.seed, args.fault, extra, stderr=None
    )
    code = EXIT_BAD_INPUT
    try:
        if not ready:
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
            "unitree",
            "--network-interface",
            "lo",
            "--domain-id",
            str(args.domain_id),
            "--robot",
            args.robot,
            *rest,
        ]
        print(f"hil: Unitree emulator: {ready}; deploy-run {' '.join(run[3:])}", flush=True)
        code = subprocess.call(run)
    finally:
        stop_emulator(emulator)
    if report.is_file() and trace.is_file():
        print_truth(json.loads(report.read_text()), np.load(trace))
    return code


def print_truth(report: dict, saved) -> None:
    """The walk as the emulator saw it (:mod:`.truth`), beside deploy-run's estimate."""
    loco = report.get("locomotion")
    onsets = saved["damping_onsets"]
    if not loco or not len(onsets) or not loco["running_s"]:
        return
    truth = walk_truth(saved["trace"], float(onsets[-1]), loco["running_s"], loco["command"][0])
    speed, track = truth["mean_forward_speed_m_s"], truth["tracking_success"]
    print(
        f"hil: truth (emulator, the {loco['running_s']:.1f} s the policy ran): walked "
        f"{truth['distance_m']:.2f} m, mean forward speed "
        + (f"{speed:.3f} m/s" if speed is not None else "n/a")
        + "; tracking "
        + (f"{100 * track:.1f} %" if track is not None else "n/a"),
        flush=True,
    )


def start_emulator(
    robot: str,
    domain_id: int,
    seed: int = 0,
    faults: Sequence[str] = (),
    extra: Sequence[str] = (),
    stderr=subprocess.DEVNULL,
) -> tuple[subprocess.Popen, str | None]:
    """``python -m deploy.backends.unitree.emulator`` on the loopback interface in its own
    process, and its first line of stdout (None when it exits or says nothing within
    ``START_TIMEOUT`` s). ``faults``: ``--fault`` texts; ``extra``: more of its arguments.
    ``stderr``: where its messages go (None: inherited). Stop it with :func:`stop_emulator`."""
    cmd = [
        sys.executable,
        "-m",
        "deploy.backends.unitree.emulator",
        "--robot",
        robot,
        "--network-interface",
        "lo",
        "--domain-id",
        str(domain_id),
        "--seed",
        str(seed),
        *extra,
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
    """SIGTERM (the emulator prints its counters and exits), then kill after 10 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


if __name__ == "__main__":
    raise SystemExit(main())
