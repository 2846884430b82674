"""``python -m sim2real.deploy.harness.unitree_hil``: deploy-run over DDS against the emulator.

Hardware-in-the-loop without the robot: starts the Unitree emulator
(``python -m sim2real.deploy.backends.unitree.emulator``) in its own process on the loopback interface,
waits for its first line, runs ``deploy-run --backend unitree --network-interface lo
--domain-id N`` with the remaining arguments in a second process (two processes, as a robot and
its controller are: the plant's thread and the runtime would otherwise share one interpreter
lock), then stops the emulator, which prints its counters (LowState rate, command-to-state
latency, drivers cut off, the base's true path length). ``make hil ROBOT=go2`` runs the shipped
Go2 policy through it for 60 s::

    python -m sim2real.deploy.harness.unitree_hil --robot go2 [--fault lose:0.01 ...] -- \\
        --policy sim2real/policies/go2.onnx --command 0.5,0,0 --duration 60

The exit code is deploy-run's (0 clean, 2 fault, 3 bad input); 3 also when the emulator does
not start.
"""

from __future__ import annotations

import json
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sim2real.deploy.backends.unitree.emulator.band import BAND_HELP
from sim2real.deploy.backends.unitree.emulator.faults import FAULT_HELP
from sim2real.deploy.backends.unitree.emulator.robot import START_HELP, STARTS
from sim2real.deploy.backends.unitree.emulator.truth import walk_truth
from sim2real.deploy.harness.common import (
    deploy_run_command,
    hil_parser,
    parse_hil,
    run_beside,
    spawn_emulator,
)


def main(argv: list[str] | None = None) -> int:
    """Run the emulator and deploy-run against it; see the module docstring."""
    p = hil_parser(
        "unitree_hil",
        "deploy-run --backend unitree against the Unitree emulator on the loopback interface; "
        "arguments after '--' go to deploy-run.",
        fault_help=FAULT_HELP,
        domain=(1, "DDS domain"),
    )
    p.add_argument("--start", choices=STARTS, default=STARTS[0], help=START_HELP)
    p.add_argument(
        "--family",
        choices=("unitree_go", "unitree_hg"),
        default=None,
        help="message family of both ends (default: robot.toml's)",
    )
    p.add_argument("--band", default=None, metavar="LENGTH[@RELEASE]", help=BAND_HELP)
    p.add_argument(
        "--remote",
        default=None,
        metavar="TOML",
        help="the emulator plays this scripted wireless remote (an operator session: give "
        "deploy-run --operator unitree after '--')",
    )
    args, rest = parse_hil(p, argv)
    with tempfile.TemporaryDirectory(prefix="hil-") as tmp:
        return _run(args, rest, Path(tmp))


def _run(args, rest: list[str], tmp: Path) -> int:
    trace = tmp / "trace.npz"
    if "--report" not in rest:
        rest = [*rest, "--report", str(tmp / "report.json")]
    report = Path(rest[rest.index("--report") + 1])
    extra = ["--start", args.start, "--trace", str(trace)]
    if args.remote:
        extra += ["--remote", args.remote]
    if args.band:
        extra += ["--band", args.band]
    if args.family:
        extra += ["--family", args.family]
        rest = [*rest, "--family", args.family]
    emulator, ready = start_emulator(
        args.robot, args.domain_id, args.seed, args.fault, extra, stderr=None
    )
    run = deploy_run_command(
        "unitree", "--network-interface", "lo", "--domain-id", str(args.domain_id)
    )
    run += ["--robot", args.robot, *rest]
    code = run_beside(emulator, ready, f"Unitree emulator: {ready}", run)
    if ready and report.is_file() and trace.is_file():
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
    """``python -m sim2real.deploy.backends.unitree.emulator`` on the loopback interface in its own
    process, and its first line of stdout (None when it exits or says nothing within
    :data:`sim2real.deploy.harness.common.START_TIMEOUT` s). ``faults``: ``--fault`` texts; ``extra``:
    more of its arguments. ``stderr``: where its messages go (None: inherited). Stop it with
    :func:`sim2real.deploy.harness.common.stop_emulator`."""
    args = ["--robot", robot, "--network-interface", "lo", "--domain-id", str(domain_id)]
    args += ["--seed", str(seed), *extra]
    return spawn_emulator("sim2real.deploy.backends.unitree.emulator", args, faults, stderr=stderr)


if __name__ == "__main__":
    raise SystemExit(main())
