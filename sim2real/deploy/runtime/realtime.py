"""Process settings of a real-time loop: SCHED_FIFO priority, CPU affinity, locked memory.

:class:`RealtimeSettings` applies what a :class:`RealtimeRequest` asks for around the loop (a
context manager) and restores the process's previous settings afterwards:

- **priority**: ``os.sched_setscheduler(0, SCHED_FIFO, N)``: the loop preempts every normal
  (SCHED_OTHER) task on its CPU as soon as its wake-up is due. Permitted with CAP_SYS_NICE (root
  outside a restricting container) or an rtprio resource limit of at least N (``ulimit -r``;
  ``USER - rtprio N`` in ``/etc/security/limits.conf``).
- **affinity**: ``os.sched_setaffinity(0, cpus)``: the loop runs on those CPUs only (an isolated
  core, ``isolcpus=``, keeps other work off it).
- **memory lock**: ``mlockall(MCL_CURRENT | MCL_FUTURE)`` (Linux, through ctypes): no page of the
  process is swapped out or faulted in mid-run. Permitted with CAP_IPC_LOCK or a memlock limit
  above the process's size (``ulimit -l unlimited``; ``USER - memlock unlimited``).

The three apply to the calling thread (the loop's) and to the threads it starts afterwards; the
priority also to every other thread the process already has (Linux: ``/proc/self/task``), the
threads a robot's I/O runs on (a DDS library's receive and event threads, a command re-send
thread), since a loop at SCHED_FIFO whose sensor readings wait on a normal thread is only as
punctual as that thread.
A setting the system refuses is reported in one line saying what would permit it, and the loop
runs without it, unless the request says ``require`` (then :class:`RealtimeError`). An invalid
request (a CPU this process may not use, a priority out of range) is always an error.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import sys
import threading
from dataclasses import dataclass

from sim2real.robots.errors import Sim2RealError

#: ``mlockall`` flags (Linux, <sys/mman.h>).
MCL_CURRENT, MCL_FUTURE = 1, 2


#: The notice for ``--spin`` at SCHED_FIFO. Linux keeps part of each second for normal tasks on a
#: CPU a real-time task never leaves (``kernel.sched_rt_runtime_us``, 950000 of 1000000 us by
#: default; since Linux 6.12 the fair server, 50 ms per 1 s per CPU): a loop that never sleeps
#: is then stalled for 50 ms or more at a time (bench ``wallclock``, ``spin+fifo``).
SPIN_AT_FIFO = (
    "--spin at SCHED_FIFO never sleeps: where normal tasks share its CPU, Linux keeps ~5 % of "
    "each second for them and stalls the loop 50 ms or more at a time (sched_rt_runtime_us, "
    "fair server); give it a CPU of its own (isolcpus= and --cpu) or use --wait hybrid"
)


class RealtimeError(Sim2RealError, ValueError):
    """A real-time setting that is invalid (a CPU out of the allowed set, a priority out of
    range), or refused by the system when the request requires it."""


@dataclass(frozen=True)
class RealtimeRequest:
    """What the loop asks of the operating system.

    Attributes:
        priority: SCHED_FIFO priority (1..99 on Linux), or None for normal scheduling.
        cpus: CPU indices to run on, or None to keep the current affinity.
        lock_memory: Lock the process's memory (``mlockall``).
        require: A refused priority or memory lock is an error instead of a one-line notice.
        spin: The loop busy-waits the whole period (``--spin``): at SCHED_FIFO a one-line notice
            says what a loop that never sleeps costs on a CPU shared with normal tasks.
    """

    priority: int | None = None
    cpus: tuple[int, ...] | None = None
    lock_memory: bool = False
    require: bool = False
    spin: bool = False

    def validate(self) -> None:
        """Check the request against this machine before anything is applied.

        Raises:
            RealtimeError: a CPU index this process may not run on (its current affinity), or a
                priority outside ``os.sched_get_priority_min/max(SCHED_FIFO)``.
        """
        if self.cpus is not None:
            if not self.cpus:
                raise RealtimeError("--cpu: expected at least one CPU index")
            allowed = available_cpus()
            bad = sorted(set(self.cpus) - allowed)
            if bad:
                raise RealtimeError(
                    f"--cpu {','.join(map(str, self.cpus))}: no CPU {','.join(map(str, bad))} for "
                    f"this process; expected some of {_cpu_list(allowed)} (its affinity, "
                    f"os.sched_getaffinity)"
                )
        if self.priority is not None and hasattr(os, "SCHED_FIFO"):
            lo = os.sched_get_priority_min(os.SCHED_FIFO)
            hi = os.sched_get_priority_max(os.SCHED_FIFO)
            if not lo <= self.priority <= hi:
                raise RealtimeError(
                    f"--rt-priority {self.priority}: expected an integer in {lo}..{hi} "
                    "(SCHED_FIFO priorities)"
                )


def parse_cpus(text: str) -> tuple[int, ...]:
    """``"1"`` or ``"0,2"`` -> CPU indices.

    Raises:
        RealtimeError: not a comma list of non-negative integers.
    """
    try:
        cpus = tuple(int(t) for t in text.split(","))
    except ValueError:
        cpus = ()
    if not cpus or min(cpus) < 0:
        raise RealtimeError(f"--cpu {text!r}: expected N or N,M,... (non-negative CPU indices)")
    return cpus


def available_cpus() -> set[int]:
    """The CPUs this process may run on (its affinity; every CPU where affinity is unknown)."""
    if hasattr(os, "sched_getaffinity"):
        return set(os.sched_getaffinity(0))
    return set(range(os.cpu_count() or 1))


def _cpu_list(cpus) -> str:
    return ",".join(str(c) for c in sorted(cpus))


def _libc():
    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name, use_errno=True) if name else None


def _memlock_limit() -> str:
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    except (ImportError, OSError, AttributeError):
        return "unknown"
    return "unlimited" if soft == resource.RLIM_INFINITY else f"{soft // 1024} KiB"


class RealtimeSettings:
    """Apply a :class:`RealtimeRequest` for the duration of a ``with`` block, then restore.

    Args:
        request: What to apply (validated on entry).
        prog: Prefix of the notices, e.g. ``deploy-run``.
        stream: Where the notices go (default stderr).

    Attributes (after entry): ``notes`` (the notices printed), and :meth:`summary`.

    Raises (on entry):
        RealtimeError: an invalid request (:meth:`RealtimeRequest.validate`), or, with
            ``require``, a refused priority or memory lock (the settings already applied are
            restored first).
    """

    def __init__(self, request: RealtimeRequest, prog: str = "deploy-run", stream=None):
        self.request = request
        self.prog = prog
        self.stream = stream
        self.notes: list[str] = []
        self._old_affinity = None
        self._old_scheduler = None
        self._old_threads: dict[int, tuple[int, int]] = {}  # tid -> (policy, priority)
        self._locked = False
        self._summary: dict = {}

    # ------------------------------------------------------------------ context manager
    def __enter__(self) -> RealtimeSettings:
        req = self.request
        req.validate()
        refused = []
        try:
            if req.cpus is not None:
                self._set_affinity(req.cpus)
            if req.lock_memory and not self._lock_memory():
                refused.append("memory lock")
            if req.priority is not None:
                if not self._set_priority(req.priority):
                    refused.append("SCHED_FIFO priority")
                elif req.spin:
                    self._note(SPIN_AT_FIFO)
            self._summary = self._read_back()
            if refused and req.require:
                raise RealtimeError(
                    f"--require-rt: {' and '.join(refused)} refused (see the notes above)"
                )
        except BaseException:
            self.restore()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.restore()

    def restore(self) -> None:
        """Give back the scheduler, affinity and memory lock the process had before."""
        if self._old_scheduler is not None:
            policy, priority = self._old_scheduler
            self._old_scheduler = None
            try:
                os.sched_setscheduler(0, policy, os.sched_param(priority))
            except OSError:
                pass  # lowering one's own priority is always permitted; nothing to do otherwise
        threads, self._old_threads = self._old_threads, {}
        for tid, (policy, priority) in threads.items():
            try:
                os.sched_setscheduler(tid, policy, os.sched_param(priority))
            except OSError:
                pass  # the thread ended
        if self._locked:
            self._locked = False
            libc = _libc()
            if libc is not None:
                libc.munlockall()
        if self._old_affinity is not None:
            cpus, self._old_affinity = self._old_affinity, None
            os.sched_setaffinity(0, cpus)

    # ------------------------------------------------------------------ settings
    def _note(self, text: str) -> None:
        line = f"{self.prog}: note: {text}"
        self.notes.append(line)
        print(line, file=self.stream or sys.stderr, flush=True)

    def _set_affinity(self, cpus: tuple[int, ...]) -> None:
        if not hasattr(os, "sched_setaffinity"):
            self._note(
                "CPU affinity is not available on this platform (os.sched_setaffinity): "
                "--cpu ignored"
            )
            return
        old = os.sched_getaffinity(0)
        try:
            os.sched_setaffinity(0, set(cpus))
        except OSError as exc:  # a CPU offline or outside the cgroup's cpuset
            raise RealtimeError(
                f"--cpu {_cpu_list(cpus)}: the system refused the affinity ({exc.strerror}); "
                f"expected some of {_cpu_list(old)}"
            ) from None
        self._old_affinity = old

    def _lock_memory(self) -> bool:
        libc = _libc() if sys.platform.startswith("linux") else None
        if libc is None or not hasattr(libc, "mlockall"):
            self._note(
                "memory lock is not available on this platform (mlockall): pages may be "
                "swapped out mid-run"
            )
            return False
        if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
            err = ctypes.get_errno()
            self._note(
                f"memory lock refused (mlockall: {os.strerror(err)}; RLIMIT_MEMLOCK "
                f"{_memlock_limit()}): running with pageable memory; permit it with "
                "CAP_IPC_LOCK, `ulimit -l unlimited` or 'USER - memlock unlimited' in "
                "/etc/security/limits.conf"
            )
            return False
        self._locked = True
        return True

    def _set_priority(self, priority: int) -> bool:
        if not hasattr(os, "sched_setscheduler") or not hasattr(os, "SCHED_FIFO"):
            self._note(
                "SCHED_FIFO is not available on this platform (os.sched_setscheduler): "
                "running at normal priority"
            )
            return False
        old = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except OSError as exc:
            why = os.strerror(exc.errno) if exc.errno else str(exc)
            hint = (
                "permit it with CAP_SYS_NICE (root, or `setcap cap_sys_nice+ep` on the "
                f"python binary), `ulimit -r {priority}` or 'USER - rtprio {priority}' in "
                "/etc/security/limits.conf"
            )
            if exc.errno == errno.EPERM:
                hint += "; in a container, also --cap-add SYS_NICE and a real-time cgroup budget"
            self._note(
                f"SCHED_FIFO priority {priority} refused ({why}): running at normal priority; "
                + hint
            )
            return False
        self._old_scheduler = old
        self._raise_threads(priority)
        return True

    def _raise_threads(self, priority: int) -> None:
        """Every other thread of the process at SCHED_FIFO ``priority`` (module docstring),
        each one's old setting kept for :meth:`restore`; a thread that ended meanwhile is
        skipped. No-op where ``/proc/self/task`` does not exist."""
        try:
            tids = [int(t) for t in os.listdir("/proc/self/task")]
        except OSError:
            return
        me = threading.get_native_id()
        for tid in tids:
            if tid == me:
                continue
            try:
                old = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            except OSError:
                continue  # ended since the listing
            self._old_threads[tid] = old

    # ------------------------------------------------------------------ report
    def _read_back(self) -> dict:
        out: dict = {
            "requested": {
                "priority": self.request.priority,
                "cpus": list(self.request.cpus) if self.request.cpus is not None else None,
                "lock_memory": self.request.lock_memory,
                "require": self.request.require,
                "spin": self.request.spin,
            },
            "scheduler": None,
            "priority": None,
            "cpus": sorted(available_cpus()),
            "memory_locked": self._locked,
        }
        if hasattr(os, "sched_getscheduler"):
            policy = os.sched_getscheduler(0)
            names = {
                getattr(os, n): n
                for n in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR")
                if hasattr(os, n)
            }
            out["scheduler"] = names.get(policy, str(policy))
            out["priority"] = os.sched_getparam(0).sched_priority
        out["other_threads_raised"] = len(self._old_threads)
        return out

    def summary(self) -> dict:
        """The settings read back while applied: ``requested`` (the request), ``scheduler``
        (``SCHED_FIFO``, ``SCHED_OTHER``, ...; None where unknown), ``priority``,
        ``other_threads_raised`` (the process's other threads put at the priority), ``cpus`` (the
        affinity, sorted), ``memory_locked`` (bool) and ``notes`` (the notices printed)."""
        return {**self._summary, "notes": list(self.notes)}
