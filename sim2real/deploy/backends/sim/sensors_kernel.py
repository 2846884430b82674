"""Kernels of the plant's joint sensor model (``JointSensorModel``).

:func:`encoder_sample` turns the noise and dropout draws of one encoder sample into readings, and
:func:`encoder_read` delivers the readings due at a tick, each with the arithmetic of the numpy
references (:class:`sim2real.deploy.backends.sim.reference.ReferenceJointSensorModel`) in their order, so
both give the same readings bit for bit (``tests/test_sim_plant.py``). The random draws stay in
numpy's ``Generator`` (the soak's seeded streams), made before the kernel is called.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, _nrt=False)
def encoder_sample(
    sample: np.ndarray,
    uniform: np.ndarray,
    q: np.ndarray,
    noise_sigma: np.ndarray,
    quantum: float,
    dropout_probability: np.ndarray,
) -> None:
    """One encoder sample of every (env, joint), in place.

    Args:
        sample: (envs, n) standard normal draws on entry; the readings (rad, quantized to
            ``quantum``, NaN where lost) on return.
        uniform: (envs, n) uniform draws in [0, 1): a reading is lost where below
            ``dropout_probability``.
        q: (envs, n) true joint angles, rad.
        noise_sigma: (envs,) rad. dropout_probability: (envs,).
        quantum: rad, the encoder resolution.
    """
    envs, n = sample.shape
    for e in range(envs):
        sigma, p = noise_sigma[e], dropout_probability[e]
        for j in range(n):
            s = sample[e, j] * sigma
            s += q[e, j]
            s = np.rint(s / quantum)
            s *= quantum
            if uniform[e, j] < p:
                s = np.nan
            sample[e, j] = s


@numba.njit(cache=True, nogil=True, _nrt=False)
def encoder_read(
    tick: int,
    latency_ticks: np.ndarray,
    buffer_position: np.ndarray,
    buffer_stamp: np.ndarray,
    position: np.ndarray,
    position_stamp: np.ndarray,
) -> None:
    """The readings arriving at control tick ``tick`` into ``position`` (rad) and
    ``position_stamp`` (s), (envs, n) each: env ``e``'s reading sampled ``latency_ticks[e]`` ticks
    earlier, from the ring buffers ``buffer_position`` (slots, envs, n) and ``buffer_stamp``
    (slots, envs); NaN (both) where no reading arrives."""
    slots = buffer_stamp.shape[0]
    envs, n = position.shape
    for e in range(envs):
        origin = tick - latency_ticks[e]
        if origin < 0:  # sampled before the clock started
            for j in range(n):
                position[e, j] = np.nan
                position_stamp[e, j] = np.nan
            continue
        slot = origin % slots
        stamp = buffer_stamp[slot, e]
        for j in range(n):
            p = buffer_position[slot, e, j]
            position[e, j] = p
            position_stamp[e, j] = np.nan if np.isnan(p) else stamp


@numba.njit(cache=True, nogil=True, _nrt=False)
def velocity_read_at(
    latency_ticks: np.ndarray, buffer_velocity: np.ndarray, velocity: np.ndarray, tick: int
) -> None:
    """The joint velocities the drives reported with the angles arriving at control tick
    ``tick`` into ``velocity`` (envs, n) rad/s: env ``e``'s row of the ring buffer
    ``buffer_velocity`` (slots, envs, n) sampled ``latency_ticks[e]`` ticks earlier, NaN where
    that is before the clock started (the numpy reference's ``origin % slots`` row, then NaN)."""
    slots = buffer_velocity.shape[0]
    envs, n = velocity.shape
    for e in range(envs):
        origin = tick - latency_ticks[e]
        slot = origin % slots
        for j in range(n):
            velocity[e, j] = np.nan if origin < 0 else buffer_velocity[slot, e, j]


@numba.njit(cache=True, nogil=True, _nrt=False)
def temperature_report(
    winding_temperature: np.ndarray,
    out: np.ndarray,
    stamp: np.ndarray,
    resolution: float,
    time: float,
) -> None:
    """The drives' temperature report: ``winding_temperature`` (envs, n) degC rounded to
    ``resolution`` degC (half to even) into ``out`` (envs, n), ``stamp`` (envs,) set to
    ``time`` s; the arithmetic of ``np.round(winding_temperature / resolution) * resolution``."""
    envs, n = out.shape
    for e in range(envs):
        for j in range(n):
            out[e, j] = np.rint(winding_temperature[e, j] / resolution) * resolution
        stamp[e] = time


@numba.njit(cache=True, nogil=True, _nrt=False)
def encoder_read_at(
    latency_ticks: np.ndarray,
    buffer_position: np.ndarray,
    buffer_stamp: np.ndarray,
    position: np.ndarray,
    position_stamp: np.ndarray,
    tick: int,
) -> None:
    """:func:`encoder_read` with the tick last (arguments as there): the arrays bound once
    (:func:`sim2real.deploy.kernels.calls.bind`), the tick given at each call."""
    encoder_read(tick, latency_ticks, buffer_position, buffer_stamp, position, position_stamp)
