"""The compiled tick of :class:`~sim2real.deploy.estimation.joints.JointStateEstimator` (numba).

One call does, per (env, joint): classify the reading (missing, stale, fresh), check the
filter, absorb a fresh reading (the same closed-form predict + update as
``filterpy.kalman.KalmanFilter``, ``predict()`` then ``update(z)`` with the Joseph form), check
again and write the prediction to the frame's time, in one compiled call per tick (its cost:
``make bench``). It equals the ``"filterpy"`` reference to rounding (~1e-15).

The kernel stops where the estimator must re-initialize a degenerate joint (the rare path, left to
Python) and is called again from the phase after it:

====== ===============================================================================
phase  what runs
====== ===============================================================================
0      classify the readings, update the counters, check (symmetrize P first)
1      absorb the fresh readings, check again (only if any reading was fresh)
2      write the outputs: ``q``, ``dq``, ``time_since_fresh``, winding temperatures
====== ===============================================================================

Returns 0 when the outputs are written, 1 when the check of phase 0 failed (nothing absorbed yet),
2 when the check of phase 1 failed (``good`` marks the joints to re-initialize).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np


class KalmanArgs(NamedTuple):
    """The arguments of :func:`kalman_tick` after ``phase``, in its order (shapes, dtypes and
    units there): the frame's ``z``, ``ts``, ``now``, ``temperature_in``; the control input
    ``u``; the estimator's own ``filt``, ``consts``, ``counts``, ``flags``; the state's
    ``q_out``, ``dq_out``, ``temperature_out``; ``input_extrapolates``. The live arrays (never
    copies): a table of their addresses stays valid while they are the bound ones."""

    z: np.ndarray
    ts: np.ndarray
    now: np.ndarray
    temperature_in: np.ndarray
    u: np.ndarray
    filt: np.ndarray
    consts: np.ndarray
    counts: np.ndarray
    flags: np.ndarray
    q_out: np.ndarray
    dq_out: np.ndarray
    temperature_out: np.ndarray
    input_extrapolates: bool


@numba.njit(cache=True, nogil=True, _nrt=False)
def _check(x, p, b0, b1, good) -> bool:
    envs, n = good.shape
    ok = True
    for e in range(envs):
        for j in range(n):
            s = (p[1, e, j] + p[2, e, j]) * 0.5
            p[1, e, j] = s
            p[2, e, j] = s
            p00, p11 = p[0, e, j], p[3, e, j]
            g = (
                p00 > 0.0
                and p00 <= b0[j]
                and p11 <= b1[j]
                and p00 * p11 - s * s > 0.0
                and math.isfinite(x[0, e, j] + x[1, e, j])
            )
            good[e, j] = g
            ok = ok and g
    return ok


@numba.njit(cache=True, nogil=True, _nrt=False)
def kalman_tick(
    phase: int,
    z: np.ndarray,
    ts: np.ndarray,
    now: np.ndarray,
    temperature_in: np.ndarray,
    u: np.ndarray,
    filt: np.ndarray,
    consts: np.ndarray,
    counts: np.ndarray,
    flags: np.ndarray,
    q_out: np.ndarray,
    dq_out: np.ndarray,
    temperature_out: np.ndarray,
    input_extrapolates: bool,
) -> int:
    """One estimator tick from ``phase`` on (see the module docstring).

    Shapes: ``z``, ``ts``, temperatures, ``q_out``, ``dq_out`` (envs, n); ``now`` (envs,);
    ``u`` (envs, n), the control input (commanded acceleration, rad/s^2); ``filt`` (8, envs, n),
    the filter's state, rows ``x`` (2: position, velocity), ``p`` (4, ``p[k] = P[k // 2,
    k % 2]``), ``filter_time``, ``time_since_fresh``; ``consts`` (5, n) rows process noise
    ``var``, measurement variance ``r``, covariance bounds ``b0``, ``b1``, the angle's rest
    variance ``rx`` (inf: none; else the reading's angle once more into the angle alone); ``counts`` (3, envs,
    n) int64 rows missing, stale (and re-initializations, not written here); ``flags`` (2, envs,
    n) bool rows fresh, good (written); ``input_extrapolates``: whether the output's
    extrapolation past the newest reading uses ``u`` too (else constant velocity). Units as in
    :class:`~sim2real.deploy.estimation.joints.JointStateEstimator`.
    """
    x, p, tf, time_since_fresh = filt[0:2], filt[2:6], filt[6], filt[7]
    var, r, b0, b1, rx = consts[0], consts[1], consts[2], consts[3], consts[4]
    missing, stale, fresh, good = counts[0], counts[1], flags[0], flags[1]
    envs, n = z.shape
    if phase == 0:
        for e in range(envs):
            t = now[e]
            for j in range(n):
                valid = math.isfinite(z[e, j]) and math.isfinite(ts[e, j])
                if not valid:
                    missing[e, j] += 1
                f = valid and ts[e, j] > tf[e, j] and ts[e, j] <= t
                if valid and not f:
                    stale[e, j] += 1
                fresh[e, j] = f
        if not _check(x, p, b0, b1, good):
            return 1
        phase = 1
    if phase == 1:
        any_fresh = False
        for e in range(envs):
            for j in range(n):
                if not fresh[e, j]:
                    continue
                any_fresh = True
                # F = [[1, dt], [0, 1]], Q = var [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]
                dt = ts[e, j] - tf[e, j]
                hdt = dt * 0.5
                q11 = var[j] * (dt * dt)
                q01 = q11 * hdt
                q00 = q01 * hdt
                x0, x1 = x[0, e, j], x[1, e, j]
                p00, p01, p10, p11 = p[0, e, j], p[1, e, j], p[2, e, j], p[3, e, j]
                # prior: x = F x + B u, P = F P F' + Q
                xp0 = x0 + dt * x1 + (hdt * dt) * u[e, j]
                x1 = x1 + dt * u[e, j]
                a01 = p01 + dt * p11
                a00 = p00 + dt * p10
                a00 = a00 + dt * a01
                a00 = a00 + q00
                a01 = a01 + q01
                a11 = p11 + q11
                # posterior, closed form of filterpy's Joseph update for the optimal gain
                s = a00 + r[j]
                k0 = a00 / s
                k1 = a01 / s
                y = z[e, j] - xp0
                x[0, e, j] = xp0 + k0 * y
                x[1, e, j] = x1 + k1 * y
                c = 1.0 - k0
                p[0, e, j] = c * a00
                p[1, e, j] = c * a01
                p[2, e, j] = c * a01
                p[3, e, j] = a11 - k1 * a01
                if math.isfinite(rx[j]):  # the angle's held-back share: K = [k0, 0], Joseph
                    p00, p01 = p[0, e, j], p[1, e, j]
                    k0 = p00 / (p00 + rx[j])
                    c = 1.0 - k0
                    x[0, e, j] = x[0, e, j] + k0 * (z[e, j] - x[0, e, j])
                    p[0, e, j] = c * c * p00 + k0 * k0 * rx[j]
                    p[1, e, j] = c * p01
                    p[2, e, j] = c * p01
                tf[e, j] = ts[e, j]
        if any_fresh and not _check(x, p, b0, b1, good):
            return 2
    for e in range(envs):
        t = now[e]
        for j in range(n):
            age = t - tf[e, j]
            time_since_fresh[e, j] = age
            du = age * u[e, j] if input_extrapolates else 0.0  # B(age) u; 0 for a lost joint
            if not math.isfinite(du):
                du = 0.0
            q_out[e, j] = age * x[1, e, j] + x[0, e, j] + 0.5 * age * du
            dq_out[e, j] = x[1, e, j] + du
            if math.isfinite(temperature_in[e, j]):
                temperature_out[e, j] = temperature_in[e, j]
    return 0


@numba.njit(cache=True, nogil=True, _nrt=False)
def absorb_velocity(
    zv: np.ndarray,
    rv: np.ndarray,
    filt: np.ndarray,
    flags: np.ndarray,
    now: np.ndarray,
    u: np.ndarray,
    q_out: np.ndarray,
    dq_out: np.ndarray,
    input_extrapolates: bool,
) -> None:
    """After :func:`kalman_tick`: the joint velocity the drive reported with a fresh reading,
    ``zv`` (envs, n) rad/s (NaN where none), as a second measurement of that reading's state,
    ``H = [0, 1]``, variance ``rv`` (n,) (rad/s)^2 (filterpy's ``update(zv, R=rv, H=[[0, 1]])``
    after the position's); then those joints' outputs again (``kalman_tick``'s last phase).
    ``filt``, ``flags``, ``now``, ``u``, ``q_out``, ``dq_out``, ``input_extrapolates``:
    :func:`kalman_tick`'s."""
    x, p, tf = filt[0:2], filt[2:6], filt[6]
    fresh = flags[0]
    envs, n = zv.shape
    for e in range(envs):
        t = now[e]
        for j in range(n):
            if not fresh[e, j] or not math.isfinite(zv[e, j]):
                continue
            p00, p01, p11 = p[0, e, j], p[1, e, j], p[3, e, j]
            s = p11 + rv[j]
            k0 = p01 / s
            k1 = p11 / s
            y = zv[e, j] - x[1, e, j]
            x[0, e, j] = x[0, e, j] + k0 * y
            x[1, e, j] = x[1, e, j] + k1 * y
            c = 1.0 - k1
            p[0, e, j] = p00 - k0 * p01
            p[1, e, j] = c * p01
            p[2, e, j] = c * p01
            p[3, e, j] = c * p11
            age = t - tf[e, j]
            du = age * u[e, j] if input_extrapolates else 0.0
            if not math.isfinite(du):
                du = 0.0
            q_out[e, j] = age * x[1, e, j] + x[0, e, j] + 0.5 * age * du
            dq_out[e, j] = x[1, e, j] + du
