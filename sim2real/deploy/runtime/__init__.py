"""The runtime: the fixed-rate loop between a neural network and a motor.

The tick (:meth:`Runtime.tick`, read top to bottom in one function), the state machine
(``IDLE -> RAMP_IN -> RUNNING -> SAFE_STOP -> FAULTED``, one per env) and the faults it answers
are described in docs/architecture.md ("The tick"). The backend is any
:class:`sim2real.deploy.core.backend.Backend`; the garbage collector is off while :meth:`Runtime.run`
loops. One module per concept:

========================  ====================================================================
module                    what it holds
========================  ====================================================================
:mod:`~.loop`             :class:`Runtime`: its stages, start / restart / reset of faults, the
                          tick, the run; ``STAGES``
:mod:`~.state`            :class:`~.state.RuntimeState`: the runtime's state dict
:mod:`~.reference`        :class:`ReferenceRuntime`: the tick's numpy references (guard,
                          smoother, observation, supervision, screen, latency histograms)
:mod:`~.supervision`      the state machine (:class:`Supervision`): its arrays, its transitions
                          in numpy (the reference of the compiled supervision and screen)
:mod:`~.compiled`         the compiled supervision and action screen (the kernels of
                          :mod:`sim2real.deploy.runtime.supervision_kernel`, bound to the runtime's arrays)
:mod:`~.anchoring`        :func:`reanchor`: the smoother re-anchored at the measured state
:mod:`~.clock`            :class:`SimClock`, :class:`WallClock` and its wait strategies
:mod:`~.realtime`         :class:`RealtimeSettings`: SCHED_FIFO priority, CPU affinity, locked
                          memory
========================  ====================================================================

The state machine's vocabulary (:class:`Mode`, ``FAULT_CAUSES``, the constants of its
transitions, :class:`RuntimeCounters`) lives on the ground floor, :mod:`sim2real.deploy.core.modes`, and is
re-exported here. The clocks, real-time settings and modes import without MuJoCo;
:class:`Runtime` and the rest are imported when first used (``_LAZY``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from sim2real.deploy.core.modes import (
    FAULT_CAUSES,
    FAULTED,
    HOME_TOLERANCE,
    IDLE,
    NAN_ACTION_LIMIT,
    OVERRUN_RATE_LIMIT,
    OVERRUN_WINDOW_S,
    RAMP_GAIN,
    RAMP_IN,
    REST_SPEED,
    RUNNING,
    SAFE_STOP,
    SAFE_STOP_TIMEOUT,
    START_TIMEOUT,
    STOP_DAMPING,
    Mode,
    RuntimeCounters,
)
from sim2real.deploy.runtime.clock import SPIN_MARGIN_NS, WAIT_MODES, SimClock, WallClock
from sim2real.deploy.runtime.realtime import (
    RealtimeError,
    RealtimeRequest,
    RealtimeSettings,
    available_cpus,
    parse_cpus,
)

if TYPE_CHECKING:
    from sim2real.deploy.runtime.anchoring import (
        TRACKING_TOLERANCE,
        VELOCITY_TRACKING_TOLERANCE,
        reanchor,
        tracking_tolerance,
    )
    from sim2real.deploy.runtime.compiled import CompiledSupervision
    from sim2real.deploy.runtime.loop import STAGES, Runtime
    from sim2real.deploy.runtime.reference import ReferenceRuntime
    from sim2real.deploy.runtime.supervision import Supervision

#: The names imported when first used, and their modules.
_LAZY = {
    "TRACKING_TOLERANCE": "anchoring",
    "VELOCITY_TRACKING_TOLERANCE": "anchoring",
    "reanchor": "anchoring",
    "tracking_tolerance": "anchoring",
    "CompiledSupervision": "compiled",
    "STAGES": "loop",
    "Runtime": "loop",
    "ReferenceRuntime": "reference",
    "Supervision": "supervision",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "FAULTED",
    "FAULT_CAUSES",
    "HOME_TOLERANCE",
    "IDLE",
    "NAN_ACTION_LIMIT",
    "OVERRUN_RATE_LIMIT",
    "OVERRUN_WINDOW_S",
    "RAMP_GAIN",
    "RAMP_IN",
    "REST_SPEED",
    "RUNNING",
    "SAFE_STOP",
    "SAFE_STOP_TIMEOUT",
    "SPIN_MARGIN_NS",
    "STAGES",
    "START_TIMEOUT",
    "STOP_DAMPING",
    "TRACKING_TOLERANCE",
    "VELOCITY_TRACKING_TOLERANCE",
    "WAIT_MODES",
    "CompiledSupervision",
    "Mode",
    "RealtimeError",
    "RealtimeRequest",
    "RealtimeSettings",
    "ReferenceRuntime",
    "Runtime",
    "RuntimeCounters",
    "SimClock",
    "Supervision",
    "WallClock",
    "available_cpus",
    "parse_cpus",
    "reanchor",
    "tracking_tolerance",
]
