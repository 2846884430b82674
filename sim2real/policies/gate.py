"""The shipping gate of the training recipes: a candidate is exported to ONNX and soaked over
several seeds with the soak's full randomization and faults; only one that passes is shipped.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path


def add_gate_arguments(p: argparse.ArgumentParser) -> None:
    """The shipping soak's options (both recipes): ``--gate-hours`` (0: off), ``--gate-sessions``
    (several seeds, not one) and ``--gate-seed`` (the first; the nightly and the README's soaks
    use other seeds)."""
    p.add_argument(
        "--gate-hours",
        type=float,
        default=1.0,
        help="simulated hours per session of the shipping soak (0: off)",
    )
    p.add_argument("--gate-sessions", type=int, default=3, help="sessions (seeds) of the gate")
    p.add_argument(
        "--gate-seed", type=int, default=100, help="first session seed of the shipping soak"
    )


def gate(candidate: Path, args: argparse.Namespace) -> tuple[bool, Path]:
    """Soak ``candidate``'s ONNX export (``candidate.with_suffix(".onnx")``, written by the
    caller; see the module docstring).

    Returns:
        ``(passed, soak folder)``; the soak's report.json and report.html are in the folder.
    """
    from sim2real.eval.cli import main as soak_main

    onnx = candidate.with_suffix(".onnx")
    out = candidate.with_suffix(".gate")
    if out.exists():
        shutil.rmtree(out)
    code = soak_main(
        [
            "--robot",
            args.robot,
            "--policy",
            str(onnx),
            "--hours",
            str(args.gate_hours),
            "--sessions",
            str(args.gate_sessions),
            "--seed",
            str(args.gate_seed),
            "--out",
            str(out),
            "--no-progress",
        ]
        + ([] if args.ranges is None else ["--ranges", str(args.ranges)])
    )
    return code == 0, out
