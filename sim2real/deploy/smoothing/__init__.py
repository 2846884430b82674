"""Command smoothing: jerk-limited commands with Ruckig (community edition), batched over ``envs``.

One ``ruckig.Ruckig`` instance serves the whole batch: its degrees of freedom are the ``envs * n``
joints (DoF ``e * n + j``), ``Synchronization.No`` makes them independent, ``delta_time`` is the
robot's control period and the limits are the robot's per-joint soft velocity limit (the margin
to the hard velocity limit absorbs the servo's overshoot), acceleration and jerk limits, tiled over
the envs. The result equals one instance per env to rounding, not bit for bit: Ruckig
recalculates only when its input changed, otherwise it samples the trajectory it has, and a
batch's input changes whenever any env's target does.

Its start from the measured state, modes, safe stop: :class:`~.smoother.CommandSmoother`.

The package, one module per concept (each module's docstring says what it holds):

========================  ====================================================================
module                    what it holds
========================  ====================================================================
:mod:`~.smoother`         :class:`CommandSmoother`: limits, work arrays, sync, safe stop, the step
                          (the compiled kernels around Ruckig), tracking error;
                          ``TORQUE_RISE_TIME``, ``EXTREMA_SCREEN_FACTOR``
:mod:`~.ruckig_state`     Ruckig inside the smoother: the call and its errors
                          (:class:`SmoothingError`), the control interfaces, the extrema of its
                          trajectories, the anchor, the brake, and the state dict that restores
                          Ruckig's input (``RUCKIG_INPUT_FIELDS``, ``EXTREMA_TOLERANCE``)
:mod:`~.reference`        :class:`~.reference.ReferenceSmoother`, the numpy reference of the step:
                          the clamps, counters and velocity-mode stopping guards
:mod:`~.braking`          the stopping math of a jerk-limited joint: :func:`stopping_distance`,
                          :func:`stopping_speed`
========================  ====================================================================
"""

from sim2real.deploy.smoothing.braking import stopping_distance, stopping_speed
from sim2real.deploy.smoothing.ruckig_state import (
    EXTREMA_TOLERANCE,
    RUCKIG_INPUT_FIELDS,
    SmoothingError,
)
from sim2real.deploy.smoothing.smoother import (
    EXTREMA_SCREEN_FACTOR,
    TORQUE_RISE_TIME,
    CommandSmoother,
)

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
