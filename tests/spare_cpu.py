"""Keep one CPU free of the test suite while the serial-bus servo tests run beside it.

The servo tests (mark ``alone``) talk to the bus emulator through a pseudo-terminal. Linux moves
a pty's bytes from the writer to the reader on a kernel worker thread (the tty layer's
flip-buffer work on a kworker), not in the writer's own system call as a pipe does, and with
every CPU busy that worker waits its turn: beside two busy loops on a 2-CPU machine a
pty round trip (``os.write`` on one end, ``select`` and ``os.read`` on the other, in two
processes) took 12-24 ms at the 99th percentile and up to 72 ms (2,000 round trips), whether
the loops ran at nice 19 or under ``SCHED_IDLE``; a pipe between the same processes beside the
same loops stayed under 4.1 ms; with both loops pinned to one CPU the pty's round trips were as
with no loop (p99 3.8 ms, at the same background load). A servo's reply later than the robot's
stale limit (50 ms) safe-stops deploy-run: so the suite's niceness alone does not protect the
servo tests, and the suite may not use the CPU they need.

``make test`` runs the suite under ``run`` (every CPU but one of this process's set), the servo
tests beside it, then ``release`` (the suite's processes and threads back on every CPU) and the
other wall-clock tests.

Usage:
    ``python tests/spare_cpu.py run PIDFILE -- CMD ...``: write this process's id to PIDFILE,
    leave the last CPU of its affinity set out of it, then replace itself by CMD (its children
    inherit the set). Nothing is pinned where there is one CPU or no ``os.sched_setaffinity``.

    ``python tests/spare_cpu.py release PIDFILE``: the process named in PIDFILE and all its
    descendants, every thread, back on this process's CPUs (waits up to 30 s for the file to name one;
    processes gone meanwhile are skipped).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path


def _children() -> dict[int, list[int]]:
    """{parent pid: [child pids]} of every process in /proc."""
    tree: dict[int, list[int]] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            stat = Path(entry.path, "stat").read_text()
        except OSError:
            continue
        # "pid (comm) state ppid ...": comm may hold spaces or parentheses
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        tree.setdefault(ppid, []).append(int(entry.name))
    return tree


def _descendants(pid: int) -> list[int]:
    """``pid`` and every process below it."""
    tree, out, todo = _children(), [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(tree.get(p, ()))
    return out


def run(pidfile: str, argv: list[str]) -> None:
    """Write our pid, drop the last CPU from our affinity, exec ``argv``."""
    Path(pidfile).write_text(f"{os.getpid()}\n")
    if hasattr(os, "sched_setaffinity"):
        cpus = sorted(os.sched_getaffinity(0))
        if len(cpus) > 1:
            os.sched_setaffinity(0, cpus[:-1])
    os.execvp(argv[0], argv)


def release(pidfile: str) -> int:
    """Every thread of the pidfile's process tree on our CPUs; the number of threads moved."""
    if not hasattr(os, "sched_setaffinity"):
        return 0
    path = Path(pidfile)
    deadline = time.monotonic() + 30.0
    text = ""
    while time.monotonic() < deadline:
        text = path.read_text().strip() if path.exists() else ""
        if text:
            break
        time.sleep(0.1)
    if not text:
        return 0
    cpus = os.sched_getaffinity(0)
    moved: set[int] = set()
    for _ in range(2):  # again: a process forked while the first pass walked kept the old set
        for pid in _descendants(int(text)):
            try:
                tids = [int(t) for t in os.listdir(f"/proc/{pid}/task")]
            except OSError:
                continue
            for tid in tids:
                try:
                    if os.sched_getaffinity(tid) != cpus:
                        os.sched_setaffinity(tid, cpus)
                    moved.add(tid)
                except OSError:  # gone meanwhile
                    pass
    return len(moved)


def main(argv: list[str]) -> int:
    if len(argv) >= 4 and argv[0] == "run" and argv[2] == "--":
        run(argv[1], argv[3:])
    if len(argv) == 2 and argv[0] == "release":
        moved = release(argv[1])
        print(f"spare_cpu: the suite's {moved} threads back on every CPU", flush=True)
        return 0
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
