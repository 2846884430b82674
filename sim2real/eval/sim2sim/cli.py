"""``sim2sim``: soak one policy on several physics engines and compare the reports.

Usage::

    sim2sim --robot R --policy P --hours H --seed S [--sessions N] [--engines mujoco,pybullet]
            --out OUT [--no-progress] [--no-film] [--compare-only] [-- SOAK-TEST OPTIONS...]

It runs ``soak-test`` once per engine, one after the other, each in its own process
(``python -m sim2real.eval.cli ... --engine E --out OUT/E`` with ``--robot``, ``--policy``, ``--hours``,
``--seed``, ``--sessions``, ``--no-progress``, ``--no-film`` and whatever follows ``--``,
unchanged), then compares the reports (:func:`sim2real.eval.sim2sim.compare.compare`), writes
``OUT/sim2sim.json``, ``OUT/sim2sim.md`` and ``OUT/sim2sim.png`` (:mod:`sim2real.eval.sim2sim.write`)
and prints the totals' table and the verdict. ``--compare-only`` runs nothing and compares the
existing ``OUT/<engine>/`` folders. A soak that fails a check (the policy's failure, e.g. too few
goals) still wrote its report, and the comparison goes on; a soak that wrote no report (bad input,
interrupted, crashed) stops the run with its exit code.

Exit codes: 0 the figures agree on every engine, 3 the policy's result depends on the engine
(a figure's gap beyond its threshold), 2 bad input (the message names the option, file or field),
or a soak's own exit code when it wrote no report (soak-test's: 3 bad input, 130 interrupted;
130 also when sim2sim itself is interrupted).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

from sim2real.deploy.cli.run_parser import split_passthrough
from sim2real.eval.sim2sim.compare import Sim2SimError, compare
from sim2real.robots.errors import Sim2RealError

EXIT_SAME = 0
EXIT_BAD_INPUT = 2
EXIT_ENGINE_DEPENDENT = 3
EXIT_INTERRUPTED = 130

#: The soak-test command (sim2real/eval/cli.py runs ``main`` under ``python -m``), run with this
#: interpreter so that the soak uses the same installation.
SOAK_COMMAND = (sys.executable, "-m", "sim2real.eval.cli")
#: Options sim2sim sets per engine: refused after ``--``.
OWN_OPTIONS = ("--engine", "--out")
#: An engine name: it is also the name of its folder under --out.
ENGINE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


class BadInput(Sim2RealError, ValueError):
    """A bad command line; the message names the option."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # exit code 2 through main's return value, not sys.exit
        raise BadInput(message)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="sim2sim",
        description="Sim-to-sim: soak one policy on several physics engines (soak-test --engine) "
        "and compare the reports figure by figure. Arguments after '--' go to soak-test.",
        epilog="Exit codes: 0 same result on every engine, 3 the result depends on the engine, "
        "2 bad input, or a soak's own exit code when it wrote no report.",
    )
    p.add_argument("--robot", default=None, help="shipped robot name or robot.toml path")
    p.add_argument("--policy", default=None, help="ONNX policy (policy-export)")
    p.add_argument("--hours", type=float, default=None, help="simulated hours per session")
    p.add_argument("--seed", type=int, default=None, help="seed of the first session")
    p.add_argument("--sessions", type=int, default=None, help="sessions (soak-test's default: 1)")
    p.add_argument(
        "--engines",
        default="mujoco,pybullet",
        help="comma-separated engines, two or more (default mujoco,pybullet)",
    )
    p.add_argument("--out", type=Path, required=True, help="folder: OUT/<engine>/ and sim2sim.*")
    p.add_argument("--no-progress", action="store_true", help="passed to soak-test")
    p.add_argument("--no-film", action="store_true", help="passed to soak-test")
    p.add_argument(
        "--compare-only",
        action="store_true",
        help="run nothing: compare the existing OUT/<engine>/report.json",
    )
    return p


def _engines(text: str) -> list[str]:
    engines = [e.strip() for e in text.split(",") if e.strip()]
    bad = [e for e in engines if not ENGINE_NAME.fullmatch(e)]
    if bad:
        raise BadInput(f"--engines: expected names of letters, digits, '_', '.', '-', got {bad}")
    if len(engines) < 2 or len(set(engines)) != len(engines):
        raise BadInput(f"--engines: expected two different engines or more, got {text!r}")
    return engines


def _check_args(args, rest: list[str]) -> None:
    if not args.compare_only:
        missing = [
            f"--{name}"
            for name in ("robot", "policy", "hours", "seed")
            if getattr(args, name) is None
        ]
        if missing:
            raise BadInput(f"{', '.join(missing)}: required (unless --compare-only)")
        if not args.hours > 0:
            raise BadInput(f"--hours: expected a number > 0, got {args.hours}")
        if args.seed < 0:
            raise BadInput(f"--seed: expected an integer >= 0, got {args.seed}")
        if args.sessions is not None and args.sessions < 1:
            raise BadInput(f"--sessions: expected an integer >= 1, got {args.sessions}")
        if not Path(args.policy).is_file():
            raise BadInput(f"--policy: {args.policy} is not a file")
    for arg in rest:
        if arg.split("=", 1)[0] in OWN_OPTIONS:
            raise BadInput(f"{arg}: set by sim2sim for each engine; not allowed after '--'")
    for folder in (args.out, *args.out.parents):
        if folder.exists() and not folder.is_dir():
            raise BadInput(f"--out: {folder} is a file; expected a folder (new or existing)")


def soak_command(args, engine: str, rest: list[str]) -> list[str]:
    """The soak-test command line of ``engine``: :data:`SOAK_COMMAND` and the options."""
    cmd = [*SOAK_COMMAND, "--robot", args.robot, "--policy", str(args.policy)]
    cmd += ["--hours", repr(args.hours), "--seed", str(args.seed)]
    if args.sessions is not None:
        cmd += ["--sessions", str(args.sessions)]
    cmd += ["--engine", engine, "--out", str(args.out / engine)]
    cmd += [
        flag for flag in ("--no-progress", "--no-film") if getattr(args, flag[2:].replace("-", "_"))
    ]
    return cmd + rest


def _stamp(path: Path) -> tuple | None:
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def _run_soak(cmd: list[str], report: Path) -> int | None:
    """Run one soak; None when it wrote its report (whatever its checks), else its exit code."""
    before = _stamp(report)
    print(f"sim2sim: {' '.join(cmd)}", flush=True)
    code = subprocess.run(cmd).returncode
    after = _stamp(report)
    if after is not None and after != before:
        return None
    return code if code != 0 else EXIT_BAD_INPUT


def run(args, rest: list[str]) -> int:
    """Run the soaks (unless ``--compare-only``), compare, write and print; the exit code."""
    from sim2real.eval.sim2sim.write import totals_table, write_sim2sim

    engines = _engines(args.engines)
    _check_args(args, rest)
    if not args.compare_only:
        for engine in engines:
            report = args.out / engine / "report.json"
            code = _run_soak(soak_command(args, engine, rest), report)
            if code is not None:
                print(
                    f"sim2sim: soak-test on {engine} wrote no report ({report}; exit code "
                    f"{code}); nothing compared",
                    file=sys.stderr,
                )
                return code
    result = compare({e: args.out / e for e in engines})
    paths = write_sim2sim(args.out, result)
    print(totals_table(result))
    for f in result["flagged"]:
        if f["where"] != "totals":
            print(f"  {f['label']} ({f['where']}): {f['reason']}")
    for w in result["warnings"]:
        print(f"  warning: {w}")
    print(f"sim2sim: {result['verdict']}")
    print(f"  reports      {', '.join(str(p) for p in paths.values())}")
    return EXIT_ENGINE_DEPENDENT if result["engine_dependent"] else EXIT_SAME


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``sim2sim``; returns the exit code (see the module docstring)."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    own, rest = split_passthrough(argv)
    try:
        args = _parser().parse_args(own)
        return run(args, rest)
    except (Sim2SimError, BadInput) as exc:
        print(f"sim2sim: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        print(f"sim2sim: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("sim2sim: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    raise SystemExit(main())
