"""Python's garbage collector around a wall-clock loop that must not pause.

CPython's cyclic collector runs when enough container objects were allocated since the last
collection; a collection of the oldest generation walks every tracked object of the process. In a
process that imported MuJoCo, Cyclone DDS, numba and Pinocchio that takes tens of milliseconds
(docs/measurements.md: the Unitree emulator's one full collection a few seconds after its start
stopped ``rt/lowstate`` for longer than the Go2's stale limit, every run, and the Go2's runtime
stopped on ``stale_sensor``). The runtime's own loop pauses the collector
(:meth:`sim2real.deploy.runtime.loop.Runtime.run`); an emulator's loop, the robot's stand-in, must
do the same or it makes the robot look dead.

:func:`collector_paused` is that pause for any loop: one full collection of the set-up's garbage
first (before the first deadline, where it costs nothing), every surviving object moved to the
permanent generation (:func:`gc.freeze`), the collector disabled while the loop runs, then the
process's previous state restored.

A loop under the pause must not make reference cycles per step: nothing would reclaim them until
it ends.

The freeze nests (:func:`heap_frozen`): a pause that finds the heap already frozen (an outer pause,
a runtime's run beside an emulator's loop in one process, a test harness that runs each test over
a frozen heap) leaves it frozen at its end; the last of them to end unfreezes it. Unfreezing there
would hand every object of the process back to the collector while the outer loop still runs,
and the next full collection would walk them all.
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from contextlib import contextmanager

#: The :func:`heap_frozen` bodies running in this process, and whether the heap was frozen by
#: someone else when the first of them began (then none of them unfreezes it).
_holders = {"count": 0, "outer": False}
_holders_lock = threading.Lock()


@contextmanager
def heap_frozen() -> Iterator[None]:
    """Run the body with every object that exists at its start in the permanent generation
    (:func:`gc.freeze`: collections skip it). The last of the bodies running at once (nested,
    or in other threads) to end calls :func:`gc.unfreeze`, unless the heap was already frozen
    when the first began (an outer freeze owns it).

    Whether the heap is frozen is read once, when no body runs: ``gc.get_freeze_count()`` walks
    every frozen object (docs/measurements.md, the garbage collector), so a freeze held by this
    function is counted here instead, and a caller that holds one over many runs (a test
    harness) uses this function.
    """
    with _holders_lock:
        if _holders["count"] == 0:
            _holders["outer"] = gc.get_freeze_count() > 0  # 0 objects to walk when unfrozen
        _holders["count"] += 1
        gc.freeze()
    try:
        yield
    finally:
        with _holders_lock:
            _holders["count"] -= 1
            if _holders["count"] == 0 and not _holders["outer"]:
                gc.unfreeze()


@contextmanager
def collector_paused() -> Iterator[None]:
    """Run the body with the garbage collector frozen and disabled (module docstring).

    On entry: ``gc.collect()`` (every generation), ``gc.freeze()``, ``gc.disable()``. On exit,
    however the body ends: the collector enabled again if it was, and ``gc.unfreeze()`` unless
    the heap was frozen at entry (:func:`heap_frozen`). Nested or concurrent uses (an emulator's
    thread beside a runtime in one test process) leave the collector enabled once the last of
    them whose entry found it enabled exits, and the heap unfrozen by the last of them to end.
    """
    gc.collect()
    with heap_frozen():
        was_enabled = gc.isenabled()
        gc.disable()
        try:
            yield
        finally:
            if was_enabled:
                gc.enable()
