"""The tick's re-anchoring of the smoother at the measured state (:func:`reanchor`) and its
tolerances: the runtime's and the training env's (:class:`sim2real.policies.envs.ReachTask`).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import FAULTED, SAFE_STOP
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.smoothing import CommandSmoother

#: Position mode: a command this far (rad) from the measured pose (the arm was pushed or blocked)
#: is re-anchored at the measured state, so that the servo does not yank the arm back; counted.
TRACKING_TOLERANCE = 0.6  # arm3's servo lags up to 0.45 rad at full speed
#: Velocity mode: Ruckig's integrated position is kept within this distance (rad) of the measured
#: pose (:meth:`~sim2real.deploy.smoothing.CommandSmoother.anchor`); moves are counted as anchors. Our
#: choice: twice the position lag of a PI velocity drive at its effort limit, 2 x 22.5 N m /
#: kp 400 N m/rad = 0.11 rad on arm3 (robot.toml), rounded to 0.1; a drive that lags further
#: saturates, and its own anti-windup lets go of the gap too.
VELOCITY_TRACKING_TOLERANCE = 0.1


def tracking_tolerance(targets, mode: str) -> float:
    """The runtime's re-anchoring tolerance for a robot whose drives take ``targets`` (its kind's
    :class:`~sim2real.deploy.kinds.targets.DriveTargets`) in control mode ``mode``, rad:
    ``VELOCITY_TRACKING_TOLERANCE`` or ``TRACKING_TOLERANCE``. A legged robot's low-gain PD lags
    its targets by design (they act as torques through kp), so it has none (inf)."""
    return targets.tracking_tolerance(TRACKING_TOLERANCE, VELOCITY_TRACKING_TOLERANCE, mode)


def reanchor(
    smoother: CommandSmoother,
    state: RobotState,
    tracking: np.ndarray,
    anchored: np.ndarray,
    mode: np.ndarray | None = None,
    tolerance: float | None = None,
) -> np.ndarray | None:
    """The tick's re-anchoring of the smoother at the measured state (the runtime's and the
    training env's, :class:`sim2real.policies.envs.ReachTask`).

    Velocity mode: Ruckig's integrated position is kept within ``VELOCITY_TRACKING_TOLERANCE``
    of ``state.q`` in every env (:meth:`~sim2real.deploy.smoothing.CommandSmoother.anchor`). Position
    mode: an env whose command is more than ``TRACKING_TOLERANCE`` from ``state.q`` is re-synced
    at ``state.q``, ``state.dq``. Torque mode: nothing.

    Args:
        smoother: The smoother to re-anchor.
        state: Estimated state (``q`` rad, ``dq`` rad/s, (envs, n)).
        tracking: (envs,) float work array (position mode's tracking error, rad).
        anchored: (envs,) int64 work array (velocity mode's anchored envs).
        mode: Optional (envs,) state-machine modes: envs in SAFE_STOP or FAULTED are not
            re-synced (position mode) and not counted (velocity mode).
        tolerance: The mode's tolerance, rad (default ``TRACKING_TOLERANCE`` or
            ``VELOCITY_TRACKING_TOLERANCE``); ``inf`` turns the re-anchoring off.

    Returns:
        None when nothing moved, else an (envs,) mask (int64 or bool) of the counted envs.
    """
    if smoother.mode == "velocity":
        tol = VELOCITY_TRACKING_TOLERANCE if tolerance is None else tolerance
        moved = smoother.anchor(state.q, tol, out=anchored)
    elif smoother.mode == "position":
        tol = TRACKING_TOLERANCE if tolerance is None else tolerance
        moved = smoother.tracking_error(state.q, out=tracking) > tol
    else:
        return None
    if not moved.any():
        return None
    if mode is not None:
        moved &= (mode != SAFE_STOP) & (mode != FAULTED)
    if smoother.mode == "position" and moved.any():
        smoother.sync(state.q, state.dq, envs=moved)
    return moved
