"""Command smoothing: jerk-limited commands with Ruckig (community edition), batched over ``envs``.


One ``ruckig.Ruckig`` instance serves the whole batch: its degrees of freedom are the ``envs * n``
joints (DoF ``e * n + j``), ``Synchronization.No`` makes them independent, ``delta_time`` is the
robot's control period and the limits are the robot's per-joint soft velocity limit (the margin
to the hard velocity limit absorbs the servo's overshoot), acceleration and jerk limits, tiled over
the envs. The result equals one instance per env to rounding (~1e-16), not bit
for bit: Ruckig recalculates only when its input changed, otherwise it samples the trajectory it
has, and a batch's input changes whenever any env's target does.

"Starts from the measured state". :meth:`CommandSmoother.sync` (and :meth:`~CommandSmoother.reset`)
writes the *measured* joint position and velocity into Ruckig's current state, with zero
acceleration. Between syncs Ruckig's own output is passed back as its next input
(``OutputParameter.pass_to_input``), so consecutive commands are continuous in position, velocity
and acceleration and never jump to follow sensor noise. The runtime syncs at start, on every
state-machine transition, and when :meth:`~CommandSmoother.tracking_error` (commanded against
measured position) exceeds its tolerance.

Modes (the robot's control modes):
    position: ``ControlInterface.Position``; target position clamped to the hard position limits
        (the community edition has no position limits), target velocity 0; the command is Ruckig's
        ``new_position``, clipped to the hard limits. Where the trajectory's position extrema leave
        the limits (a joint too fast to stop in time, typically right after a sync) the clip bites
        and ``extrema_violations`` counts it.
    velocity: ``ControlInterface.Velocity``; target velocity clamped to +-soft_velocity_limit and
        to the speed from which the joint can still stop before its *soft* limits
        (:func:`stopping_speed` of the distance left, counted in ``stopping_distance_clamps``);
        and set to 0 (Ruckig's time-optimal, hence shortest, brake) where one more period of the
        worst acceleration the jerk limit allows would leave too little room to stop. Ruckig's
        integrated position thus never passes a soft limit (unless a sync put the joint beyond
        saving), the velocity-mode analogue of the guard clamping position targets to the soft
        limits; the margin to the hard limits is left to the drive's tracking error and the
        estimator's noise. The command is Ruckig's ``new_velocity``.
    torque: no Ruckig; the command is the target clamped to +-effort_limit and rate limited to
        ``effort_limit / TORQUE_RISE_TIME`` (N m/s).

Safe stop. :meth:`CommandSmoother.safe_stop` switches the chosen envs to
``ControlInterface.Velocity`` with target velocity 0 (also in position mode) and returns the time
Ruckig predicts to reach rest;
:meth:`~CommandSmoother.step` then ignores their targets, brings them to zero velocity within the
acceleration and jerk limits and holds them there (position mode: the command settles at the
stopping position) until the next :meth:`~CommandSmoother.sync`.

The package, one module per concept (each module's docstring says what it holds):

========================  ====================================================================
module                    what it holds
========================  ====================================================================
:mod:`~.smoother`         :class:`CommandSmoother`: its limits and work arrays, sync, safe stop,
                          the step (the compiled kernels around Ruckig), tracking error and
                          anchor; ``TORQUE_RISE_TIME``, ``EXTREMA_SCREEN_FACTOR``
:mod:`~.ruckig_state`     Ruckig inside the smoother: the call and its errors
                          (:class:`SmoothingError`), the control interfaces, the extrema of its
                          trajectories, and the state dict that restores Ruckig's input
                          (``RUCKIG_INPUT_FIELDS``, ``EXTREMA_TOLERANCE``)
:mod:`~.reference`        :class:`~.reference.ReferenceSmoother`, the numpy reference of the step:
                          the clamps, counters and velocity-mode stopping guards
:mod:`~.braking`          the stopping math of a jerk-limited joint: :func:`stopping_distance`,
                          :func:`stopping_speed`
========================  ====================================================================
"""

from deploy.smoothing.braking import stopping_distance, stopping_speed
from deploy.smoothing.ruckig_state import (
    EXTREMA_TOLERANCE,
    RUCKIG_INPUT_FIELDS,
    SmoothingError,
)
from deploy.smoothing.smoother import EXTREMA_SCREEN_FACTOR, TORQUE_RISE_TIME, CommandSmoother

__all__ = [
    "EXTREMA_SCREEN_FACTOR",
    "EXTREMA_TOLERANCE",
    "RUCKIG_INPUT_FIELDS",
    "TORQUE_RISE_TIME",
    "CommandSmoother",
    "SmoothingError",
    "stopping_distance",
    "stopping_speed",
]
