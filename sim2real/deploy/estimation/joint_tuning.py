"""How the joint filter (:class:`sim2real.deploy.estimation.joints.JointStateEstimator`) is fitted
to a joint: its default process and measurement noise, the bounds past which it has lost track,
and the warning a run gives when it re-initializes too often.

The process noise's standard deviation is :data:`PROCESS_NOISE_FRACTION` of the largest
acceleration the motion model expects (:func:`motion_acceleration`); the encoder noise is floored
so that the tracking index stays within :data:`MAX_TRACKING_INDEX`, a reported velocity's noise at
:data:`MIN_VELOCITY_SIGMA`; a velocity standard deviation past :data:`VELOCITY_SIGMA_BOUND`
velocity limits re-initializes the filter, and :func:`reinit_warning` names the joints that did so
more than :data:`REINIT_WARNING_RATE` times per second.
"""

from __future__ import annotations

import numpy as np

from sim2real.robots import Robot

#: Default process noise standard deviation as a fraction of the joint's acceleration limit.
#: Bar-Shalom, Li, Kirubarajan (2001), sec. 6.3.2, give 0.5 a_M <= sigma <= a_M as the practical
#: range for the discrete white noise acceleration model, a_M the largest acceleration; we take the
#: lower end (the smoother keeps commanded accelerations within the limit). On the arm3 plant
#: (sinusoidal motion, default noise) 0.25, 0.5 and 1.0 give position RMS errors of 11, 7.6 and
#: 7.3 mrad against 15.6 mrad raw; 0.1 lags (25 mrad).
PROCESS_NOISE_FRACTION = 0.5


def motion_acceleration(robot: Robot) -> np.ndarray:
    """(n,) rad/s^2, the largest acceleration the filter's motion model expects of each joint:
    the smoother's acceleration limit, but no more than the whole velocity range (from
    ``-velocity_limit`` to ``+velocity_limit``) crossed in one control period. A legged robot's
    PD targets may step far faster than its joints move (``robot-import --target-limits pd``):
    process noise from such a limit would make the filter trust no reading (its measurement
    noise is raised with it by ``MAX_TRACKING_INDEX``), wider than the joint's travel,
    re-initialized every tick."""
    return np.minimum(robot.acceleration_limit, 2.0 * robot.velocity_limit / robot.control_period)


#: Largest tracking index ``sigma_a dt^2 / sigma_r`` the default measurement noise allows (``dt``
#: the control period; P. R. Kalata, "The tracking index: a generalized parameter for alpha-beta
#: and alpha-beta-gamma target trackers", IEEE TAES 20(2), 1984). The filter's steady-state
#: velocity gain beta grows with the index: past beta = 1 the velocity error alternates in sign
#: from one reading to the next, and beta tends to 2, where it no longer decays. At 3, beta is
#: 0.94. A fine encoder read at a slow rate for a joint allowed large accelerations exceeds it:
#: go2 (one count, 3e-5 rad; 500 rad/s^2 of process noise; 50 Hz) had an index of 6,600: its
#: estimate of a calf turning at 2 rad/s alternated between +-40 rad/s, and one dropped reading
#: then extrapolated the calf 0.8 rad past its hard limit (a safe stop).
MAX_TRACKING_INDEX = 3.0

#: Floor of the drives' reported velocity noise as a measurement, rad/s (our choice: a
#: robot.toml with a perfect velocity reading still gives the filter a variance > 0).
MIN_VELOCITY_SIGMA = 1e-3

#: Degeneracy bound of the velocity standard deviation, in velocity limits (our choice): an
#: uncertainty of several times the fastest possible speed means the filter has lost track.
VELOCITY_SIGMA_BOUND = 10.0

#: Re-initializations per joint per second above which a run warns (our choice): a filter that
#: fits the joint never degenerates; injected faults (a stale or non-finite reading) make a few in
#: a run; one that re-initializes every few ticks has process noise, measurement noise or a
#: covariance bound that does not fit the motion (its velocity estimate is then noise).
REINIT_WARNING_RATE = 0.1


def reinit_warning(joint_names, reinitializations: np.ndarray, seconds: float) -> str | None:
    """A one-line warning naming the joints re-initialized more often than
    :data:`REINIT_WARNING_RATE` per second over ``seconds`` s of ``envs`` robots
    (``reinitializations`` (envs, n) counts), or None."""
    if seconds <= 0:
        return None
    counts = np.asarray(reinitializations).sum(axis=0)
    rate = counts / (seconds * np.asarray(reinitializations).shape[0])
    bad = [
        (name, int(c))
        for name, c, r in zip(joint_names, counts, rate, strict=True)
        if r > REINIT_WARNING_RATE
    ]
    if not bad:
        return None
    listed = ", ".join(f"{name} {c}" for name, c in bad)
    return (
        f"the joint estimator re-initialized {listed} times in {seconds:.1f} s (more than "
        f"{REINIT_WARNING_RATE:g} per s): its velocity estimate is unreliable; check the joint's "
        "acceleration_limit (its process noise) and the encoder noise in robot.toml"
    )
