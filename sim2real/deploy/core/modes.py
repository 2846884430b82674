"""The state machine's vocabulary: its modes, the causes of a safe stop, the constants of its
transitions, and the counters it keeps (:class:`RuntimeCounters`).

One state machine per env (:mod:`sim2real.deploy.runtime`): ``IDLE -> RAMP_IN -> RUNNING -> SAFE_STOP ->
FAULTED``. The compiled kernels (:mod:`sim2real.deploy.runtime.supervision_kernel`) know the modes and
causes by number; :mod:`sim2real.deploy.runtime.compiled` checks that both agree when it is imported.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

#: Consecutive non-finite policy outputs before a safe stop (0.05 s at 200 Hz).
NAN_ACTION_LIMIT = 10
#: The wall clock's safe stop on a loop that cannot keep up: the fraction of the control
#: periods of the last ``OVERRUN_WINDOW_S`` seconds that the loop missed (no tick finished in
#: them: an overrun tick and the periods it skipped), by control mode, beyond which the loop
#: stops. A transient stall (a busy computer: a tick preempted for 100 ms) misses a few periods
#: and is ridden through with the drives holding the last command; a loop that misses most of
#: its periods for a second cannot keep up and stops. Our choice: a position drive holds its last
#: target (a fixed point of its PD), so half the periods of a second may be missed; a velocity or
#: a torque drive keeps moving on its last command, beyond the one period the guard certified, so
#: a quarter. The same for an arm and a legged robot: a walking robot whose loop misses more than
#: half its periods for a second no longer walks on its policy.
OVERRUN_RATE_LIMIT = {"position": 0.5, "velocity": 0.25, "torque": 0.25}
OVERRUN_WINDOW_S = 1.0
#: A joint is at rest below this speed, rad/s (ends a safe stop, ends RAMP_IN), or below what
#: its joint filter resolves where that is more (``Supervision.rest_speed``,
#: :func:`sim2real.deploy.estimation.rest.rest_speed`: an arm's encoders' noise).
REST_SPEED = 0.05
#: RAMP_IN of a robot whose drives run a PD law on its targets (a legged robot) ends on its
#: commanded pose at home with every joint slower than this, rad/s (our choice). Its low gains
#: take its weight as they blend in from the bring-up's and its joints sway: the go2 on the
#: Unitree emulator, read through its drives' velocity, at up to 0.7 rad/s, still 0.1-0.2 rad/s
#: 4 s later; at ``REST_SPEED`` the policy waited those 4 s. A legged policy's training episodes
#: start from a robot dropped onto its feet.
PD_RAMP_REST_SPEED = 0.5
#: A safe stop whose joints are not all at rest this long after it began ends FAULTED anyway
#: (latched), counted in ``RuntimeCounters.safe_stop_timeouts``, s. Our choice: the smoother
#: brakes any joint from its velocity limit within ``v / a + a / j`` s (the acceleration ramp,
#: then full deceleration); the longest of the shipped robots is go2's 0.65 s (ur5 0.54, arm6
#: 0.36, so101 0.21, arm3 0.21 s), so 2 s is three times the slowest brake. A stop still moving
#: then is not braking (an estimate that drifts, a joint pushed or dragged): waiting longer
#: would leave the robot in SAFE_STOP for good. Counted in ticks, ``ceil(timeout / period)``.
SAFE_STOP_TIMEOUT = 2.0
#: Runtime.start waits this long for the first reading of every joint, s.
START_TIMEOUT = 0.5
#: RAMP_IN ends within this distance of the home pose, rad (the estimate's; a legged robot's
#: commanded position's in position mode: ``Supervision.home_from_command``).
HOME_TOLERANCE = 0.05
#: Gain of the RAMP_IN approach in velocity and torque mode, 1/s (the smoother bounds the rest).
RAMP_GAIN = 2.0
#: Joint damping of the torque-mode safe stop, N m s/rad per N m of effort limit.
STOP_DAMPING = 0.2


class Mode(IntEnum):
    IDLE = 0
    RAMP_IN = 1
    RUNNING = 2
    SAFE_STOP = 3
    FAULTED = 4


# The modes as plain ints for the hot path (an IntEnum attribute lookup costs ~1 us).
IDLE, RAMP_IN, RUNNING, SAFE_STOP, FAULTED = (int(m) for m in Mode)

#: Causes of a safe stop. ``servo_error``: a drive reported a hardware error (overload,
#: overheating, input voltage, ...; ``Backend.drive_errors``), latched in ``Runtime.drive_errors``.
#: ``operator``: an operator's stop (``deploy-run --ros2``'s ``~/stop`` service), ended by resume.
#: ``smoother``: Ruckig could not plan from an env's state (``SmoothingError``); that env is
#: anchored at its estimate and brakes, the run goes on.
FAULT_CAUSES = (
    "hard_limit",
    "non_finite_action",
    "stale_sensor",
    "overrun",
    "over_temperature",
    "servo_error",
    "fall",
    "operator",
    "smoother",
)


@dataclass
class RuntimeCounters:
    """Counters of one run, arrays shaped (envs,).

    Attributes:
        non_finite_actions: Ticks with a non-finite policy output (the last valid one held).
        safe_stops: Safe stops begun.
        resyncs: Position mode: the command re-anchored at the measured state (the arm was
            pushed or blocked beyond ``TRACKING_TOLERANCE``); the command stream restarts there.
        anchors: Velocity mode: ticks on which the smoother's integrated position was pulled to
            within ``VELOCITY_TRACKING_TOLERANCE`` of the measured pose; the velocity command
            itself stays continuous.
        safe_stop_timeouts: Safe stops whose joints were not all at rest ``SAFE_STOP_TIMEOUT``
            after they began (they end FAULTED; an over-temperature one resumes once cool).
        faults: Safe stops by cause (``FAULT_CAUSES``).
    """

    non_finite_actions: np.ndarray
    safe_stops: np.ndarray
    resyncs: np.ndarray
    anchors: np.ndarray
    safe_stop_timeouts: np.ndarray
    faults: dict[str, np.ndarray] = field(default_factory=dict)
