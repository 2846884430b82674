"""Clocks of the control loop: lockstep with a simulated plant, or absolute wall-clock deadlines.

:class:`SimClock` runs in lockstep with a simulated plant as fast as the CPU allows (it never
waits). :class:`WallClock` waits for absolute deadlines ``t0 + k * period``, skips missed periods
instead of bursting, and counts overruns and the wake-up jitter. How it waits is its wait
strategy (``WAIT_MODES``):

- ``sleep``: ``time.sleep`` until the deadline. The CPU is free between ticks, and the loop goes
  cold while it sleeps: the core may clock down or enter an idle state, other work evicts the
  loop's caches, and the scheduler's wake-up latency adds to the jitter.
- ``hybrid`` (default): sleep until ``spin_margin`` before the deadline, then busy-wait. The
  wake-up latency is absorbed by the margin; the CPU is mostly free.
- ``spin``: busy-wait the whole period (no sleep): the core stays hot and the wake-up is as
  exact as reading the clock, at the price of one whole core.

The runtime's safe stop on overruns (``sim2real.deploy.runtime.OVERRUN_RATE_LIMIT``) is the same whatever
the strategy. The process settings a real-time loop also wants (SCHED_FIFO priority, CPU
affinity, locked memory) are in :mod:`sim2real.deploy.runtime.realtime`.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from sim2real.deploy.core.latency import LatencyHistogram

#: Wait strategies of :class:`WallClock` (module docstring).
WAIT_MODES = ("sleep", "hybrid", "spin")
#: ``hybrid``: busy-wait this long before each deadline, ns. Our choice: above the wake-up
#: latency of ``time.sleep`` on an idle Linux machine (timer slack 50 us plus the scheduler's
#: wake-up, typically under 100 us), so that the sleep rarely ends past the deadline.
SPIN_MARGIN_NS = 150_000


class SimClock:
    """Lockstep clock: the plant's own time; never waits.

    Args:
        period: Control period, s.
    """

    realtime = False
    wait_mode = None

    #: ns, how late the last wake-up was (never, in lockstep)
    late_ns = 0

    def __init__(self, period: float):
        self.period = period
        self.overruns = 0
        self.missed_periods = 0
        self.jitter = LatencyHistogram()

    def start(self) -> None:
        pass

    def wait(self) -> int:
        """The control periods the last tick missed (none, in lockstep)."""
        return 0


class WallClock:
    """Absolute-deadline clock for real time.

    Each tick has the deadline ``t0 + k * period``. A tick that ends after its deadline counts as
    an overrun; the missed periods are skipped (the next deadline is the next one in the future),
    never run back to back. Jitter is the lateness of each wake-up against its deadline, in ns
    (the histogram ``jitter``).

    Args:
        period: Control period, s (> 0).
        wait: The wait strategy, one of ``WAIT_MODES`` (module docstring; default ``hybrid``).
        spin_margin_ns: ``hybrid``: busy-wait this long before each deadline, ns (>= 0;
            default ``SPIN_MARGIN_NS``).
        now_ns: The monotonic clock, ns (default ``time.perf_counter_ns``; a test passes a fake).
        sleep: The sleep function, s (default ``time.sleep``; a test passes a fake).

    Raises:
        ValueError: ``period`` not positive, ``wait`` not one of ``WAIT_MODES``, a negative
            ``spin_margin_ns``.
    """

    realtime = True

    def __init__(
        self,
        period: float,
        wait: str = "hybrid",
        spin_margin_ns: int = SPIN_MARGIN_NS,
        now_ns: Callable[[], int] = time.perf_counter_ns,
        sleep: Callable[[float], None] = time.sleep,
    ):
        if not period > 0:
            raise ValueError(f"WallClock period: expected > 0 s, got {period}")
        if wait not in WAIT_MODES:
            raise ValueError(
                f"WallClock wait: expected one of {', '.join(WAIT_MODES)}, got {wait!r}"
            )
        if spin_margin_ns < 0:
            raise ValueError(f"WallClock spin_margin_ns: expected >= 0, got {spin_margin_ns}")
        self.period_ns = int(round(period * 1e9))
        self.period = period
        self.wait_mode = wait
        self.spin_margin_ns = int(spin_margin_ns)
        self.overruns = 0
        self.missed_periods = 0
        self.jitter = LatencyHistogram()
        #: ns, how late the last wake-up was against its deadline
        self.late_ns = 0
        self._now = now_ns
        self._sleep = sleep
        self._next = 0
        self.fresh = False

    def start(self) -> None:
        """The first deadline is one period from now. Until the first :meth:`wait`, ``fresh`` is
        True: a caller that did set-up work meanwhile (``Runtime.run`` freezes the garbage
        collector) starts again, so that the set-up does not count as the first tick's overrun."""
        self._next = self._now() + self.period_ns
        self.fresh = True

    def wait(self) -> int:
        """Wait for the next deadline; return the control periods the tick that just ended
        missed: 0 on time; an overrun, 1 + the periods skipped (counted in ``missed_periods``;
        the next deadline is the next one in the future)."""
        self.fresh = False
        now = self._now()
        missed = 0
        if now > self._next:
            self.overruns += 1
            skipped = (now - self._next) // self.period_ns
            self.missed_periods += int(skipped)
            self._next += (skipped + 1) * self.period_ns
            missed = 1 + int(skipped)
        deadline = self._next
        mode = self.wait_mode
        if mode == "spin":
            now = self._now()
            while now < deadline:
                now = self._now()
        else:
            margin = self.spin_margin_ns if mode == "hybrid" else 0
            remaining = deadline - self._now()
            if remaining > margin:
                self._sleep((remaining - margin) / 1e9)
            now = self._now()
            while now < deadline:  # hybrid: the last margin; sleep: never (sleep is not early)
                now = self._now()
        self.late_ns = now - deadline
        self.jitter.add(0, self.late_ns)
        self._next = deadline + self.period_ns
        return missed
