"""The runtime's run (:class:`RunLoop`): ``ticks`` control periods with the garbage collector
frozen and disabled, a wall clock started at the first run.

:class:`RunLoop` is a stage of :class:`~sim2real.deploy.runtime.loop.Runtime`, which delegates
``run`` and ``gc_collections`` to it: it is given the runtime's tick and wake-up calls and its
clock, and counts the collections inside its loops.
"""

from __future__ import annotations

import gc
import time

from sim2real.deploy.core.collector import heap_frozen


def _gc_collections() -> int:
    """Collections of the garbage collector so far in this process, every generation."""
    return sum(g["collections"] for g in gc.get_stats())


class RunLoop:
    """The run of a runtime (module docstring).

    Args:
        runtime: What ``on_tick`` is called with (the runtime).
        tick: ``() -> None``, one control period (the runtime's ``tick``).
        woke: ``(now_ns) -> None``, the period's stamps at a wake-up (the runtime's).
        clock: The runtime's clock (:class:`~sim2real.deploy.runtime.clock.SimClock` or a wall
            clock).

    Attributes:
        gc_collections: Collections of the garbage collector inside :meth:`run`'s loop, where it
            is disabled (an explicit ``gc.collect`` or a re-enabled collector in a callback); 0
            in a clean run.
    """

    def __init__(self, runtime, tick, woke, clock):
        self.runtime, self.tick, self.woke, self.clock = runtime, tick, woke, clock
        self.gc_collections = 0

    def run(self, ticks: int, on_tick=None) -> None:
        """Run ``ticks`` control periods with the garbage collector frozen and disabled (the
        freeze nests: :func:`~sim2real.deploy.core.collector.heap_frozen`).

        Before the loop the collector runs over the young generations (0 and 1). The set-up's
        garbage was collected over every generation once, when the runtime was built: a full
        collection of a process with torch loaded takes 0.1-0.5 s, which a caller running the
        loop in short pieces (a film's replay to each frame, single ticks) paid on every call,
        on a wall clock as missed periods between the pieces, and a session at its start. The
        old generation is collected by Python itself while the collector is enabled between runs.

        ``on_tick(runtime)``, if given, runs after each tick (goal scheduling, evaluation); when
        it returns True the run ends early (e.g. a latched fault on real hardware).
        """
        fresh = getattr(self.clock, "fresh", False)  # a wall clock's first run: start() collected
        if not fresh:
            gc.collect(1)
        with heap_frozen():  # unfrozen after, unless an outer freeze owns it (core.collector)
            was_enabled = gc.isenabled()
            gc.disable()
            if fresh:  # a wall clock not yet waited on: the set-up since start() is not the first
                self.clock.start()  # tick's overrun
            self.woke(time.perf_counter_ns())
            collections = _gc_collections()
            tick, runtime = self.tick, self.runtime
            try:
                for _ in range(ticks):
                    tick()
                    if on_tick is not None and on_tick(runtime):
                        break
            finally:
                self.gc_collections += _gc_collections() - collections
                if was_enabled:
                    gc.enable()
