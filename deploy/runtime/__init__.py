"""The runtime: the fixed-rate loop between a neural network and a motor.

The tick (:meth:`Runtime.tick`) reads top to bottom as DESIGN.md draws it::

    frame  = backend.read()                        # encoders, temperatures
    state  = estimator.update(frame, u)            # Kalman filter: q, dq (predict-only on
                                                   # dropouts); u: acceleration last commanded
    obs    = spec.observation(state, goal)         # normalized by physical maxima
    action = policy(obs)                           # ONNX Runtime; non-finite -> hold, count
    target = spec.action_to_target(action, state)  # physical units of the control mode
    target = guard.filter(target, state)           # Pinocchio: clamp or reject, count
    cmd    = smoother.step(target)                 # Ruckig: velocity, acceleration, jerk limits
    cmd    = guard.check_motion(smoother, state)   # the step and its brake clear of contact
                                                   # and the workspace faces, or brake instead
    backend.write(cmd)

State machine (one per env): ``IDLE -> RAMP_IN -> RUNNING -> SAFE_STOP -> FAULTED``. RAMP_IN brings
the robot from its measured pose to the home pose before the policy takes over (at rest, within
``HOME_TOLERANCE`` of home: the estimate, or for a legged robot in position mode the commanded
position, as its soft PD holds its weight short of home). A recurrent
policy's state is reset (``policy.reset(envs)``) for the envs that enter RAMP_IN (start, operator
reset, cool-down resume) and again for those whose RAMP_IN ends: the policy takes control from its
initial state, as in a fresh episode. SAFE_STOP brings
every joint to rest within the smoother's limits and holds; a safe stop for over-temperature resumes
(RAMP_IN) once every winding has cooled below its derating start, any other cause ends in FAULTED,
latched until :meth:`Runtime.reset_faults`. A safe stop ends when every joint is at rest
(``REST_SPEED``) or, at the latest, ``SAFE_STOP_TIMEOUT`` after it began (a joint still moving:
pushed, dragged, or an estimate that drifts), counted in ``counters.safe_stop_timeouts``: FAULTED,
or for over-temperature, RAMP_IN as soon as it is cool, at rest or not (FAULTED if a drive has
latched an error). Only an over-temperature stop stays in SAFE_STOP longer: until cool.

Faults and responses (DESIGN.md): non-finite policy output holds the last valid action, and
``NAN_ACTION_LIMIT`` consecutive ones make a safe stop; sensor data stale longer than
``safety.stale_limit`` makes a safe stop; a hard-limit violation makes a safe stop; a winding above
its maximum makes a safe stop latched until cool, and the effort limit is derated linearly in the
derating band down to the continuous torque, as the drives derate theirs
(:class:`robots.thermal.EffortDerating`); a wall-clock overrun rate above ``OVERRUN_RATE_LIMIT``
makes a safe stop; a hardware error a drive reports (``backend.drive_errors()``: a servo's
overload, overheating or voltage bits) makes a safe stop (cause ``servo_error``), the bits latched
per joint in :attr:`Runtime.drive_errors`.

The backend is any :class:`deploy.backends.base.Backend`: the simulated plant, or a servo bus
(:mod:`deploy.backends.servo.feetech`, :mod:`deploy.backends.servo.dynamixel`) with the wall clock.

Clocks (:mod:`deploy.runtime.clock`): :class:`SimClock` runs in lockstep with a simulated plant as
fast as the CPU allows; :class:`WallClock` waits for absolute deadlines (sleep, hybrid or spin),
skips missed periods instead of bursting, and counts overruns and jitter. The process settings of
a real-time loop (SCHED_FIFO priority, CPU affinity, locked memory) are in
:mod:`deploy.runtime.realtime`.

The garbage collector is frozen and disabled while :meth:`Runtime.run` loops.

The package, one module per concept (each module's docstring says what it holds):

========================  ====================================================================
module                    what it holds
========================  ====================================================================
:mod:`~.loop`             :class:`Runtime`: its stages, start / restart / reset of faults, the
                          tick, the run; ``STAGES``
:mod:`~.state`            :class:`~.state.RuntimeState`: the runtime's state dict
:mod:`~.reference`        :class:`ReferenceRuntime`: the tick's numpy references (guard,
                          smoother, observation, supervision, screen, latency histograms)
:mod:`~.modes`            the state machine's vocabulary: :class:`Mode`, ``FAULT_CAUSES``, the
                          constants of its transitions, :class:`RuntimeCounters`
:mod:`~.supervision`      the state machine (:class:`Supervision`): its arrays, its transitions
                          in numpy (the reference of the compiled supervision and screen)
:mod:`~.compiled`         the compiled supervision and action screen (the kernels of
                          :mod:`deploy.runtime.supervision_kernel`, bound to the runtime's arrays)
:mod:`~.anchoring`        :func:`reanchor`: the smoother re-anchored at the measured state
:mod:`~.clock`            :class:`SimClock`, :class:`WallClock` and its wait strategies
:mod:`~.realtime`         :class:`RealtimeSettings`: SCHED_FIFO priority, CPU affinity, locked
                          memory
========================  ====================================================================

The clocks, the real-time settings and the state machine's vocabulary import without MuJoCo:
``deploy-run`` reads its options (``--wait``) before it chooses MuJoCo's OpenGL backend, which
MuJoCo loads when imported (:mod:`deploy.cli.deploy_run`). The names of the other modules
(:class:`Runtime` and the stages that need MuJoCo, Pinocchio, Ruckig and numba) are imported from
here when first used (``from deploy.runtime import Runtime`` as usual; ``_LAZY``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from deploy.runtime.clock import SPIN_MARGIN_NS, WAIT_MODES, SimClock, WallClock
from deploy.runtime.modes import (
    FAULT_CAUSES,
    FAULTED,
    HOME_TOLERANCE,
    IDLE,
    NAN_ACTION_LIMIT,
    OVERRUN_RATE_LIMIT,
    OVERRUN_WINDOW,
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
from deploy.runtime.realtime import (
    RealtimeError,
    RealtimeRequest,
    RealtimeSettings,
    available_cpus,
    parse_cpus,
)

if TYPE_CHECKING:
    from deploy.runtime.anchoring import (
        TRACKING_TOLERANCE,
        VELOCITY_TRACKING_TOLERANCE,
        reanchor,
        tracking_tolerance,
    )
    from deploy.runtime.compiled import CompiledSupervision
    from deploy.runtime.loop import STAGES, Runtime
    from deploy.runtime.reference import ReferenceRuntime
    from deploy.runtime.supervision import Supervision

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
    "OVERRUN_WINDOW",
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
