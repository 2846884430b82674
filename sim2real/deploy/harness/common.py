"""The skeleton the hardware-in-the-loop harnesses share.

Each harness (:mod:`.servo_hil`, :mod:`.unitree_hil`, :mod:`.ros2_hil`) parses its command line
(:func:`hil_parser`: ``--robot``, ``--seed`` and its own options; :func:`parse_hil`: what follows
``--`` goes to deploy-run), starts its emulator in a process of its own and waits for its first
line (:func:`spawn_emulator`), runs deploy-run against it in a second process and stops the
emulator (:func:`run_beside`, :func:`stop_emulator`); the harness adds only its emulator's and
deploy-run's arguments and what it prints afterwards.
"""

from __future__ import annotations

import argparse
import os
import selectors
import signal
import subprocess
import sys
from collections.abc import Sequence
from typing import Any

from sim2real.deploy.cli.run_parser import split_passthrough

#: s to wait for an emulator's first line: loading the robot and its plant, joining the bus.
START_TIMEOUT = 60.0
#: The exit code when the emulator does not start (deploy-run's for bad input).
EXIT_BAD_INPUT = 3
#: SCHED_FIFO priority of an emulator's process (our choice: above every normal task, below the
#: kernel's interrupt threads at 50). An emulator stands in for a robot's own processors (a
#: Unitree board, a servo's microcontroller), which no job on the host computer delays; at normal
#: priority a CPU-bound process per core delays its states and replies as no robot would.
EMULATOR_PRIORITY = 40
#: deploy-run's ``--rt-priority`` in a harness, unless given after ``--``: the loop of a robot's
#: controller at SCHED_FIFO, below its emulated robot (:data:`EMULATOR_PRIORITY`), as on a robot's
#: computer (docs/deploy-run.md). At normal priority, beside a CPU-bound process per core, the
#: SO-101's replies timed out and the run stopped on ``stale_sensor``; at SCHED_FIFO none did
#: (docs/measurements.md). Refused (no CAP_SYS_NICE, no rtprio limit), deploy-run says so in one
#: line and runs at normal priority.
LOOP_PRIORITY = 30


def hil_parser(
    name: str,
    description: str,
    fault_help: str | None = None,
    domain: tuple[int, str] | None = None,
) -> argparse.ArgumentParser:
    """The command line of ``python -m sim2real.deploy.harness.<name>``: ``--robot``, ``--seed`` (the
    emulator plant's), with ``domain`` = (default, what) a ``--domain-id``, with ``fault_help``
    a repeatable ``--fault``; the harness adds its own options."""
    p = argparse.ArgumentParser(
        prog=f"python -m sim2real.deploy.harness.{name}", description=description
    )
    p.add_argument("--robot", required=True, help="shipped robot name or robot.toml path")
    if domain is not None:
        default, what = domain
        p.add_argument("--domain-id", type=int, default=default, help=f"{what} (default {default})")
    p.add_argument("--seed", type=int, default=0, help="the emulator plant's seed")
    if fault_help is not None:
        p.add_argument("--fault", action="append", default=[], metavar="FAULT", help=fault_help)
    return p


def parse_hil(p: argparse.ArgumentParser, argv: Sequence[str] | None) -> tuple[Any, list[str]]:
    """``(args, rest)``: the harness's own arguments (before ``--``) parsed by ``p``, and those
    after ``--`` for deploy-run; ``argv`` None: ``sys.argv[1:]``. Exits (code 2) on a bad
    argument, as argparse does."""
    own, rest = split_passthrough(argv)
    return p.parse_args(own), rest


def spawn_emulator(
    module: str,
    args: Sequence[str],
    faults: Sequence[str] = (),
    stderr=subprocess.DEVNULL,
    env: dict[str, str] | None = None,
) -> tuple[subprocess.Popen, str | None]:
    """``python -m <module> <args> [--fault F ...]`` in its own process, and its first line of
    stdout, stripped (None when it exits or says nothing within ``START_TIMEOUT`` s).
    ``stderr``: where its messages go (None: inherited; ``subprocess.PIPE``: read them after
    :func:`stop_emulator`). ``env``: its environment (None: this one's)."""
    cmd = [sys.executable, "-m", module, *args]
    for fault in faults:
        cmd += ["--fault", fault]
    refused = fifo_refused(EMULATOR_PRIORITY)
    if refused:
        print(
            f"hil: the emulator runs at normal priority ({refused}); beside CPU-bound work it "
            "answers late, as no robot would",
            file=sys.stderr,
        )
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=stderr,
        text=True,
        env=env,
        preexec_fn=None if refused else _emulator_priority,
    )
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    if not sel.select(timeout=START_TIMEOUT):
        return proc, None
    return proc, proc.stdout.readline().strip() or None


def fifo_refused(priority: int) -> str | None:
    """None when this process may start a child at SCHED_FIFO ``priority`` (tried on this
    thread and undone at once), else why not, in a few words."""
    if not hasattr(os, "sched_setscheduler") or not hasattr(os, "SCHED_FIFO"):
        return "SCHED_FIFO is not available on this platform"
    old = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except OSError:
        return (
            f"SCHED_FIFO {priority} refused: needs CAP_SYS_NICE or an rtprio limit of at least "
            f"{priority}, ulimit -r"
        )
    os.sched_setscheduler(0, old[0], os.sched_param(old[1]))
    return None


def _emulator_priority() -> None:  # pragma: no cover - runs in the child between fork and exec
    """The emulator's process at SCHED_FIFO ``EMULATOR_PRIORITY``, every thread it starts with
    it (in the child, before exec; :func:`fifo_refused` checked it is permitted)."""
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(EMULATOR_PRIORITY))


def stop_emulator(proc: subprocess.Popen) -> None:
    """SIGTERM (the emulator prints its counters and exits), then kill after 10 s."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def deploy_run_command(backend: str, *args: str) -> list[str]:
    """``deploy-run --backend <backend> <args>`` as this interpreter runs it."""
    return [sys.executable, "-m", "sim2real.deploy.cli.deploy_run", "--backend", backend, *args]


def run_beside(
    emulator: subprocess.Popen,
    ready: str | None,
    what: str,
    run: list[str],
    env: dict[str, str] | None = None,
) -> int:
    """Run deploy-run ``run`` (:func:`deploy_run_command`) beside the started ``emulator``,
    announced as ``hil: <what>; deploy-run ...``, and stop the emulator however it ends. The
    loop runs at ``--rt-priority`` :data:`LOOP_PRIORITY` unless ``run`` gives one.

    Returns:
        deploy-run's exit code, or ``EXIT_BAD_INPUT`` when the emulator did not start
        (``ready`` empty or None; said on stderr).
    """
    try:
        if not ready:
            said = "; its error is above" if emulator.stderr is None else ""
            print(
                f"hil: the emulator did not start (exit code {emulator.poll()}){said}",
                file=sys.stderr,
            )
            return EXIT_BAD_INPUT
        if "--rt-priority" not in run:
            run = [*run, "--rt-priority", str(LOOP_PRIORITY)]
        print(f"hil: {what}; deploy-run {' '.join(run[3:])}", flush=True)
        return subprocess.call(run, env=env)
    finally:
        stop_emulator(emulator)
