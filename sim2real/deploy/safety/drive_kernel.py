"""Kernel of :class:`sim2real.deploy.safety.drive.VelocityDrive`: one tick of the guard's model of the
velocity drives, compiled (the model and its constants: :mod:`sim2real.deploy.safety.drive`).

:func:`velocity_drive_motion` takes the gravity torque and the mass matrix Pinocchio computed at
the estimate and gives, per env and joint, the anti-windup of the integrator, the path of the
drive's equilibrium over the step, its slack, the lead of a brake and whether the drive may run
past its velocity limit, in one call.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def _sign(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


@numba.njit(cache=True, nogil=True, _nrt=False)
def velocity_drive_motion(
    setpoint: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    velocity: np.ndarray,
    acceleration: np.ndarray,
    gravity: np.ndarray,
    mass: np.ndarray,
    effort_scale: np.ndarray,
    joint: np.ndarray,
    limits: np.ndarray,
    variance: np.ndarray,
    uncertainty: np.ndarray,
    dt: float,
    start: np.ndarray,
    end: np.ndarray,
    slack: np.ndarray,
    lead: np.ndarray,
    beyond: np.ndarray,
    stopping: np.ndarray,
) -> bool:
    """One tick of the velocity drives' model, for ``envs`` envs of ``n`` joints.

    Args:
        setpoint: (envs, n) rad, the integrators ``s``; clamped in place within the (derated)
            ``effort_limit / kp`` of ``q`` (the anti-windup of the period just ended).
        q: (envs, n) rad, dq: (envs, n) rad/s, the estimate.
        velocity, acceleration: (envs, n) rad/s, rad/s^2, the smoother's state after its step.
        gravity: (envs, n) N m, the gravity torque at ``q`` (Pinocchio, nominal masses).
        mass: (envs, n, n) kg m^2, the mass matrix at ``q`` (Pinocchio's CRBA: only its upper
            triangle is read).
        effort_scale: (envs, n), the drives' thermal derating.
        joint: (10, n) per joint: ``kp`` N m/rad, ``kd`` N m s/rad, ``unwind`` 1/s, dry friction
            N m (times its factor), effort limit N m, lower and upper position limits rad,
            jerk limit rad/s^3, acceleration limit rad/s^2, hard velocity limit rad/s.
        limits: (4, n) the motion envelope's: rows 2 and 3 the worst gravity load's share of the
            effort limit and the brake's headroom floor
            (:func:`sim2real.deploy.safety.envelope_kernel.brake_headroom`).
        variance: (envs, n) rad^2/s^2, the variance of the estimated speed.
        uncertainty: (3,) the gravity's and the inertia's untrusted shares and the runaway's
            standard deviations.
        dt: s, the control period.
        start, end: (envs, n) rad, out: the equilibrium now and after the step's command.
        slack, lead: (envs, n) rad, out: how far a joint may stray either way from that path, and
            (signed, along the motion) how far past the brake's rest it runs ahead.
        beyond: (envs,) bool, out: a joint may run past its hard velocity limit, or runs past it;
            False for the envs ``stopping``.
        stopping: (envs,) bool, the envs braking to a stop already (not checked).

    Returns:
        Whether ``beyond`` has an env set.
    """
    envs, n = q.shape
    anyone = False
    g_unc, i_unc, sigmas = uncertainty[0], uncertainty[1], uncertainty[2]
    for e in range(envs):
        over = False
        for i in range(n):
            kp, kd = joint[0, i], joint[1, i]
            bound = effort_scale[e, i] * joint[4, i] / kp
            s = min(max(setpoint[e, i], q[e, i] - bound), q[e, i] + bound)
            setpoint[e, i] = s
            sag = gravity[e, i] / kp
            start[e, i] = s - sag
            end[e, i] = min(max(s - sag + velocity[e, i] * dt, joint[5, i]), joint[6, i])
            v, a = velocity[e, i], acceleration[e, i]
            slack[e, i] = g_unc * abs(sag) + joint[3, i] / kp + abs(v) * dt
            # the lead: the mass matrix's diagonal (and its uncertainty) over kp at the brake's
            # peak deceleration, never past the anti-windup's bound
            vs = _sign(v)
            sign = vs if v != 0.0 else _sign(a)  # the motion's direction, or the push's at rest
            jerk = joint[7, i]
            toward = max(a * sign, 0.0)
            v_eff = abs(v) + toward * toward / (2.0 * jerk)
            g, floor = limits[2, i], limits[3, i]
            share = effort_scale[e, i] - g
            share = share / (1.0 - g) if g < 1.0 else share
            share = min(max(share, floor), 1.0)
            peak = min(joint[8, i] * share, math.sqrt(v_eff * jerk))
            lead[e, i] = sign * min((1.0 + i_unc) * mass[e, i, i] * peak / kp, bound)
            # overspeed: the lag that unwinds, and the coupling pushes along the motion
            lag = (s - q[e, i] - sag) * vs + g_unc * abs(sag)
            excess = abs(v) + joint[2, i] * max(lag, 0.0)
            push = 0.0
            for j in range(n):
                if j != i:
                    m_ij = mass[e, i, j] if i < j else mass[e, j, i]
                    push += max(-m_ij * acceleration[e, j] * vs, 0.0)
            excess += (1.0 + i_unc) * push / kd
            if excess > joint[9, i]:
                over = True
            sigma = math.sqrt(max(variance[e, i], 0.0))
            if abs(dq[e, i]) - sigmas * sigma > joint[9, i]:
                over = True
        beyond[e] = over and not stopping[e]
        anyone |= beyond[e]
    return anyone


@numba.njit(cache=True, nogil=True, _nrt=False)
def integrate(
    setpoint: np.ndarray, command: np.ndarray, dt: float, lower: np.ndarray, upper: np.ndarray
) -> None:
    """In place: ``setpoint`` (envs, n) rad plus ``command`` (envs, n) rad/s times ``dt`` s,
    within ``[lower, upper]`` (n,) rad, the arithmetic of ``setpoint += command * dt`` and
    ``np.clip`` in one call. Bit for bit the same, but for the sign of a zero at a limit of
    exactly 0 (none of the shipped robots has one): a tie keeps ``x`` here, as ``np.clip`` does
    on one element, while its vectorized path over several elements takes the bound."""
    envs, n = setpoint.shape
    for e in range(envs):
        for j in range(n):
            x = setpoint[e, j] + command[e, j] * dt
            if x < lower[j]:  # a tie keeps x (its zero's sign), a NaN stays, as np.clip
                x = lower[j]
            if x > upper[j]:
                x = upper[j]
            setpoint[e, j] = x


def warm_up(variance: np.ndarray | None = None) -> None:
    """Compile (or load numba's cache of) the kernel outside any tick, for the speed's
    ``variance`` (envs, n) the drive model will pass (its layout, contiguous or a strided view
    of the estimator's covariance, picks the kernel's specialization); default a strided view."""
    v = np.zeros((1, 2, 2))[..., 1] if variance is None else variance
    envs, n = v.shape
    z = np.zeros((envs, n))
    velocity_drive_motion(
        z.copy(), z, z, z, z, z, np.zeros((envs, n, n)), np.ones((envs, n)), np.ones((10, n)),
        np.ones((4, n)), v, np.zeros(3), 0.01, z.copy(), z.copy(),
        z.copy(), z.copy(), np.zeros(envs, dtype=bool), np.zeros(envs, dtype=bool),
    )  # fmt: skip
