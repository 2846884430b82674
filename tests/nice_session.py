"""Run the test suite in a session of its own whose scheduling group is niced, not only its
processes.

``make test`` runs the serial-bus servo tests (mark ``alone``) beside the suite. They talk to the
bus emulator through a pseudo-terminal, and Linux moves a pty's bytes from the writer to the
reader on a kernel worker thread (the tty layer's flip-buffer work on a kworker), not in the
writer's own system call as a pipe does. Where the kernel groups the processes of a session
for scheduling (``CONFIG_SCHED_AUTOGROUP``, ``/proc/sys/kernel/sched_autogroup_enabled`` = 1,
the default of desktop and many server kernels), a session's group weighs as much as one
nice-0 process against that kworker however niced its processes are: ``nice`` (and
``SCHED_IDLE``) only orders the processes inside the group. Measured on a 2-CPU machine, a pty
round trip between two processes (``os.write`` at one end, ``select`` and ``os.read`` at the
other; 2,000 of them, 2 ms apart) beside two busy loops of the same session at nice 19: p99
12.1-14.0 ms, max 22.5-25.1 ms, 194-532 round trips over 5 ms (three runs); beside the same
loops in a session of their own whose group is niced to 19: p99 3.4-3.8 ms, max 5.9-7.7 ms,
1-5 over 5 ms, as with no loop at all (p99 2.4-3.6 ms, max 6.5-12.2 ms, 2-5 over 5 ms, at the
same background load). A pipe beside the same-session loops stayed under 11.1 ms. A servo's
reply later than the robot's stale limit (50 ms) safe-stops deploy-run: the 20 servo tests
beside two same-session nice-19 loops, 6 failed (the emulator silent 55-90 ms, "our ticks on
time"); beside two loops in a niced group of their own, 20 passed, twice. (Those figures were
taken on a machine shared with other sessions, load 5-9: a group niced to 19 then gets little
CPU, 0.4-7.7 % per loop against 25-45 % for the same-session loops, so they show the group's
weight at work, not a quiet machine.)

Usage: ``python tests/nice_session.py NICE -- CMD ...``: run CMD in a new session (a new
scheduling group) with the group's niceness (``/proc/self/autogroup``, where the kernel has
one) and the process's set to NICE; wait for it and exit with its exit code (128 + the signal
when a signal ended it). SIGINT, SIGTERM and SIGHUP are passed on to the command's process
group, so that Ctrl-C on ``make test`` still stops the suite (a new session has no controlling
terminal).
"""

from __future__ import annotations

import os
import signal
import sys


def _child(nice: int, argv: list[str]) -> None:
    """In the forked child: a new session, its group and the process niced, then ``argv``."""
    os.setsid()
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # passed on by the parent
        signal.signal(signum, signal.SIG_DFL)
    try:
        with open("/proc/self/autogroup", "w", encoding="ascii") as f:
            f.write(f"{nice}\n")
    except OSError:  # no autogroup: nice orders the processes, as before
        pass
    os.nice(nice)
    os.execvp(argv[0], argv)


def run(nice: int, argv: list[str]) -> int:
    """Fork, run ``argv`` in the child (:func:`_child`), pass on signals, return its exit code."""
    pid = os.fork()
    if pid == 0:
        try:
            _child(nice, argv)
        finally:
            os._exit(127)  # exec failed

    def forward(signum, _frame):
        try:
            os.killpg(pid, signum)
        except OSError:
            pass

    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, forward)
    _, status = os.waitpid(pid, 0)
    code = os.waitstatus_to_exitcode(status)
    return 128 - code if code < 0 else code


def main(argv: list[str]) -> int:
    if len(argv) < 3 or argv[1] != "--" or not argv[0].lstrip("-").isdigit():
        print(__doc__, file=sys.stderr)
        return 2
    return run(int(argv[0]), argv[2:])


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
