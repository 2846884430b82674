"""What the emulators' command lines share: ``python -m sim2real.deploy.backends.emulator`` (a servo bus),
``python -m sim2real.deploy.backends.unitree.emulator`` (a Unitree robot's DDS topics) and ``python -m
sim2real.deploy.ros2.emulator`` (a ros2_control controller manager).

Each parses ``--robot``, ``--seed`` and its own options (:func:`emulator_parser`), reads its
``--fault`` texts into its fault set (:func:`parse_faults`), builds its emulator from the options
named as the emulator's parameters, a bad robot or argument said in one line on stderr
(:func:`open_emulator`), prints where it serves as the first line of stdout, then serves until
SIGTERM or Ctrl-C and stops (:func:`serve`) and prints its counters on stderr.
"""

from __future__ import annotations

import argparse
import inspect
import signal
import sys
from collections.abc import Callable, Iterable
from typing import Any, TypeVar

from sim2real.deploy.backends.sim.options import add_plant_motors_option
from sim2real.deploy.core.collector import collector_paused

T = TypeVar("T")


def emulator_parser(module: str, description: str) -> argparse.ArgumentParser:
    """The command line of ``python -m <module>`` with ``--robot`` and ``--seed`` (the plant's);
    the emulator adds its own options."""
    p = argparse.ArgumentParser(prog=f"python -m {module}", description=description)
    p.add_argument("--robot", required=True, help="shipped robot name or robot.toml path")
    p.add_argument("--seed", type=int, default=0, help="the plant's seed")
    add_plant_motors_option(p)  # the motors as they really are: what sysid must find
    return p


def parse_faults(
    p: argparse.ArgumentParser, texts: Iterable[str], faults: T, parse: Callable[[str, T], Any]
) -> T:
    """``faults`` with every ``--fault`` text read into it by ``parse(text, faults)``; a text
    ``parse`` refuses (ValueError) ends the program through ``p.error`` (exit code 2)."""
    try:
        for text in texts:
            parse(text, faults)
    except ValueError as err:
        p.error(str(err))
    return faults


def open_emulator(name: str, cls: Callable[..., T], args: argparse.Namespace, **given) -> T | None:
    """The emulator ``cls(...)`` with each of the command line's ``args`` whose name is one of
    ``cls``'s parameters (``--robot`` is ``robot``, ``--seed`` is ``seed``, ...), and ``given``
    over them; or None after ``<name> emulator: error: ...`` on stderr when it raises ValueError
    or OSError (a bad robot, argument or interface)."""
    params = inspect.signature(cls).parameters
    options = {k: v for k, v in vars(args).items() if k in params}
    try:
        return cls(**{**options, **given})
    except (ValueError, OSError) as err:
        print(f"{name} emulator: error: {err}", file=sys.stderr)
        return None


def serve(
    emulator,
    close: Callable[[], None],
    counters: Callable[[], dict] | None = None,
    announce: Callable[[], None] | None = None,
):
    """Serve ``emulator`` (its ``serve()``, in this thread) until SIGTERM (its
    ``request_stop()``) or Ctrl-C, then ``close()`` it however serving ends.

    ``announce()`` prints where it serves. It runs after the set-up's full garbage collection
    (:func:`~sim2real.deploy.core.collector.collector_paused`, tens of milliseconds in a process
    that imported MuJoCo): a host that opens the port the moment it is printed gets its first
    reply on time, not after the collection (a servo backend's first PING timed out and its late
    reply broke the next packet).

    Returns:
        ``counters()`` taken before ``close()``, or None without ``counters``.
    """
    signal.signal(signal.SIGTERM, lambda *_: emulator.request_stop())
    out = None
    try:
        with collector_paused():
            if announce is not None:
                announce()
            emulator.serve()
    except KeyboardInterrupt:
        pass
    finally:
        if counters is not None:
            out = counters()
        close()
    return out
