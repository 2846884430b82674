"""The longest ticks of a run and where their time went (:class:`LongTicks`).

A latency histogram says how long ticks took, not why the longest did. :class:`LongTicks` keeps the
``capacity`` longest *periods* of a run, each with its parts, so that a long tick names its cause:

- ``wake_late``: how late the clock woke the loop for this tick (the scheduler's wake-up latency,
  or the previous tick's overrun);
- one duration per stage of the tick (``sim2real.deploy.runtime.loop.STAGES``: read ... physics);
- ``outside_stages``: the rest of the period's work, from the wake-up to the next wait, outside
  the stages (telemetry, the caller's ``on_tick``, the bookkeeping);
- ``on_cpu``: the loop thread's CPU time over the period (``time.thread_time_ns``; wall clock
  only). A period whose wall time is mostly *off* the CPU was preempted or blocked (another
  process or thread ran, the GIL was held elsewhere, a call waited on I/O); one mostly *on* the
  CPU did work (a collection, a compile, a slow call).

Recording is one compiled call per tick, nothing allocated: :func:`record`, or :func:`record_tick`
(the runtime's), which adds the tick to the latency histograms first.
"""

from __future__ import annotations

from inspect import signature

import numba
import numpy as np

from sim2real.deploy.core.latency_kernel import add_stages
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.kernels.tables import Table

#: Columns of the table before the stages: tick index, period (ns: wake-up lateness + work),
#: wake-up lateness (ns), work from the wake-up to the next wait (ns), the thread's CPU time over
#: it (ns; -1 where not measured). Then one column per stage and ``outside_stages`` (ns).
TICK, TOTAL, WAKE_LATE, SPAN, ON_CPU = range(5)
HEAD = 5
#: The period's timing stamps the runtime writes (:func:`record`'s ``period``): the previous
#: wake-up (ns, 0: none yet), its lateness (ns), the thread's CPU time at it (ns, -1: not
#: measured), this tick's end before the wait (ns) and the CPU time then.
PREV_WAKE, PREV_LATE, PREV_CPU, END, END_CPU = range(5)


@numba.njit(cache=True, nogil=True, _nrt=False)
def record(table: np.ndarray, stamps: np.ndarray, period: np.ndarray, tick: int) -> None:
    """Keep the tick if its period is among the longest.

    Args:
        table: (capacity, HEAD + stages + 1) int64, the longest periods so far (rows with
            ``TOTAL`` 0 are free).
        stamps: (stages + 1,) int64 ns, the tick's stage boundaries.
        period: (5,) int64, the stamps named by ``PREV_WAKE`` ... ``END_CPU``.
        tick: The tick's index.
    """
    stages = stamps.shape[0] - 1
    work = stamps[stages] - stamps[0]
    span = period[END] - period[PREV_WAKE] if period[PREV_WAKE] > 0 else work
    late = period[PREV_LATE] if period[PREV_LATE] > 0 else 0
    total = late + span
    low = 0
    for r in range(table.shape[0]):
        if table[r, TOTAL] < table[low, TOTAL]:
            low = r
    if total <= table[low, TOTAL]:
        return
    row = table[low]
    row[TICK] = tick
    row[TOTAL] = total
    row[WAKE_LATE] = late
    row[SPAN] = span
    row[ON_CPU] = period[END_CPU] - period[PREV_CPU] if period[PREV_CPU] >= 0 else -1
    for i in range(stages):
        row[HEAD + i] = stamps[i + 1] - stamps[i]
    row[HEAD + stages] = span - work


@numba.njit(cache=True, nogil=True, _nrt=False)
def record_tick(
    stamps: np.ndarray,
    period: np.ndarray,
    bins: np.ndarray,
    counts: np.ndarray,
    max_ns: np.ndarray,
    cost_counts: np.ndarray,
    cost_max_ns: np.ndarray,
    table: np.ndarray,
    tick: int,
) -> None:
    """The runtime's bookkeeping of one tick in one call: the stage durations and the cost
    without physics into the latency histograms
    (:func:`sim2real.deploy.core.latency_kernel.add_stages`: ``stamps``, ``bins``, ``counts``,
    ``max_ns``, ``cost_counts``, ``cost_max_ns``), then :func:`record` (``table``, ``stamps``,
    ``period``, ``tick``); the arguments' shapes and units are theirs."""
    add_stages(stamps, bins, counts, max_ns, cost_counts, cost_max_ns)
    record(table, stamps, period, tick)


class LongTicks:
    """The ``capacity`` longest control periods of a run and their parts (module docstring).

    Args:
        stages: The tick's stage names (``sim2real.deploy.runtime.loop.STAGES``).
        capacity: Periods kept (default 16).
    """

    def __init__(self, stages: tuple[str, ...], capacity: int = 16):
        self.stages = tuple(stages)
        #: (capacity, HEAD + stages + 1) int64 ns (columns: module constants)
        self.table = np.zeros((capacity, HEAD + len(stages) + 1), dtype=np.int64)

    def clear(self) -> None:
        """Forget every period (e.g. after a warm-up)."""
        self.table[:] = 0

    def rows(self, period_s: float, deadline: bool = True) -> list[dict]:
        """The kept periods, longest first, with their cause.

        Args:
            period_s: The control period, s (a period longer than it overran).
            deadline: Whether the run kept deadlines (a wall clock). False (lockstep, simulated
                time): nothing overran, whatever a period took (a long one only made the run
                slower than real time), as the clock counts no overrun either.

        Returns:
            One dict per kept period: ``tick``, ``period_us`` (wake-up lateness + work),
            ``overran`` (longer than ``period_s``), ``wake_late_us``, ``stages_us`` (stage ->
            us), ``outside_stages_us``, ``on_cpu_us`` (None where not measured), ``largest``
            (the part that took longest: ``wake_late``, a stage or ``outside_stages``) and
            ``cause``: ``"off CPU in <part>"`` where less than half the work's wall time was
            the loop thread's CPU time (preempted or blocked), else ``"on CPU in <part>"``
            (``"in <part>"`` without a CPU measurement).
        """
        out = []
        t = self.table[self.table[:, TOTAL] > 0]
        for row in t[np.argsort(-t[:, TOTAL], kind="stable")]:
            parts = {"wake_late": int(row[WAKE_LATE])}
            parts.update({s: int(row[HEAD + i]) for i, s in enumerate(self.stages)})
            parts["outside_stages"] = int(row[HEAD + len(self.stages)])
            largest = max(parts, key=parts.get)
            on_cpu = int(row[ON_CPU])
            if on_cpu < 0:
                cause = f"in {largest}"
            elif on_cpu < 0.5 * row[SPAN] and largest != "wake_late":
                cause = f"off CPU in {largest}"
            elif largest == "wake_late":
                cause = "woken late (scheduler or the previous tick's overrun)"
            else:
                cause = f"on CPU in {largest}"
            out.append(
                {
                    "tick": int(row[TICK]),
                    "period_us": row[TOTAL] / 1e3,
                    "overran": deadline and bool(row[TOTAL] > period_s * 1e9),
                    "wake_late_us": row[WAKE_LATE] / 1e3,
                    "stages_us": {s: row[HEAD + i] / 1e3 for i, s in enumerate(self.stages)},
                    "outside_stages_us": row[HEAD + len(self.stages)] / 1e3,
                    "on_cpu_us": None if on_cpu < 0 else on_cpu / 1e3,
                    "largest": largest,
                    "cause": cause,
                }
            )
        return out


#: :func:`record_tick`'s arrays (its arguments' names but the tick), one table.
RECORD = Table(
    "sim2real.deploy.observe.long_ticks:RECORD",
    stamps="i8[*]", period="i8[*]", bins="i8[*]", counts="i8[*,*]", max_ns="i8[*]",
    cost_counts="i8[*,*]", cost_max_ns="i8[*]", table="i8[*,*]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def record_table(t, tick: int) -> None:
    """:func:`record_tick` on the packed table ``t`` (:data:`RECORD`)."""
    record_tick(
        t.stamps, t.period, t.bins, t.counts, t.max_ns, t.cost_counts, t.cost_max_ns, t.table,
        tick,
    )  # fmt: skip


def bind_record(arrays: tuple):
    """``(tick) -> None``: :func:`record_tick` bound to ``arrays`` (its arguments but the
    tick, in its order, never replaced by their owner) as one table of them, or to the arrays
    themselves where one does not fit its field."""
    names = list(signature(record_tick.py_func).parameters)[:-1]
    table = RECORD.pack_or_none(**dict(zip(names, arrays, strict=True)))
    if table is not None:
        return bind(record_table, table, rest=(0,))
    return bind(record_tick, *arrays, rest=(0,))
