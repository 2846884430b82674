"""The compiled tick of a floating base's IMU and foot-contact model
(:class:`sim2real.deploy.backends.sim.legged_sensors.BaseSensorModel`).

:func:`base_sample` is :meth:`BaseSensorModel.sample` of every env at a tick (the readings due
into the latency buffers), its draws made from each env's sensor stream as the plant's compiled
step makes the encoder's (:func:`sim2real.deploy.backends.sim.plant_kernel._standard_normal`,
numpy's ``Generator.standard_normal`` and ``random``), in the numpy path's order: the bias walk,
the white noise, the onboard attitude's, the dropout, the foot forces. :func:`base_read` is
:meth:`BaseSensorModel.read`. The true readings come straight from each env's ``MjData``
(``sensordata`` and the free joint's ``qpos``), whose addresses the model keeps in a table of
``(envs, 2)`` int64. Each expression is numpy's in numpy's order; the one transcendental
function numpy computes in its own way, ``exp`` of the attitude error's correlation, stays
numpy's (the caller passes ``a = exp(-dt / tau)``). The numpy path stays the reference
(``tests/test_legged_sensors_kernel.py``: bit for bit).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim2real.deploy.backends.sim.plant_kernel import (
    NEXT_DOUBLE,
    STATE,
    _next_double,
    _standard_normal,
)
from sim2real.deploy.kernels.calls import SLOT, pointer, view1, view2, view3

#: columns of the data table: each env's ``MjData.sensordata`` and ``qpos`` addresses
SENSORDATA, QPOS = 0, 1


@numba.njit(inline="always", cache=True, nogil=True)
def _quat_mul(aw, ax, ay, az, bw, bx, by, bz):
    """The Hamilton product (``attitude.quat_multiply``'s expressions)."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@numba.njit(cache=True, nogil=True)
def base_sample(
    streams, data, nsensor, nq, gyro, acc, touch, dt, a, gyro_bias, accel_bias, gyro_bias_walk,
    accel_bias_walk, gyro_noise_sigma, accel_noise_sigma, has_orientation, orientation_error,
    orientation_sigma, site_quat, gravity_frame, dropout, force_noise_sigma, noise6, noise2,
    noise_f, buf_imu, buf_imu_stamp, buf_force, buf_contact_stamp, imu_due, contact_due, slot,
    time,
):  # fmt: skip
    """The readings due at a tick into row ``slot`` of the latency buffers, every env
    (:meth:`BaseSensorModel.sample` with ``force`` False and ``envs`` None): the IMU where
    ``imu_due`` (its period ``dt`` s; ``a`` (envs,) = ``exp(-dt / orientation_tau)``), else
    the row NaN; the foot forces where ``contact_due``, else NaN. ``streams`` (envs, 3): each
    env's sensor stream (``plant_kernel.STREAMS``); ``data`` (envs, 2): each env's
    ``sensordata`` (``nsensor``) and ``qpos`` (``nq``) addresses; ``gyro``, ``acc``: the
    sensors' first ``sensordata`` index, ``touch`` (n_feet,) the feet's; ``noise6``,
    ``noise2``, ``noise_f``: the model's draw arrays, left holding the last draws as numpy's
    path leaves them; ``time`` s, the stamp."""
    envs = streams.shape[0]
    nf = touch.shape[0]
    if imu_due:
        root = math.sqrt(dt)
        for e in range(envs):
            for j in range(6):
                noise6[e, j] = _standard_normal(streams[e])
        for e in range(envs):
            gw, aw = gyro_bias_walk[e] * root, accel_bias_walk[e] * root
            for j in range(3):
                gyro_bias[e, j] += noise6[e, j] * gw
                accel_bias[e, j] += noise6[e, 3 + j] * aw
        for e in range(envs):
            for j in range(6):
                noise6[e, j] = _standard_normal(streams[e])
        for e in range(envs):
            sensordata = numba.carray(pointer(data[e, SENSORDATA]), (nsensor,), np.float64)
            row = buf_imu[slot, e]
            gs, ac = gyro_noise_sigma[e], accel_noise_sigma[e]
            for j in range(3):
                row[j] = sensordata[gyro + j] + (gyro_bias[e, j] + noise6[e, j] * gs)
                row[3 + j] = sensordata[acc + j] + (accel_bias[e, j] + noise6[e, 3 + j] * ac)
        if has_orientation:
            for e in range(envs):
                for j in range(2):
                    noise2[e, j] = _standard_normal(streams[e])
            for e in range(envs):
                ae = a[e]
                scale = math.sqrt(1 - ae * ae)
                for j in range(2):
                    orientation_error[e, j] = ae * orientation_error[e, j] + scale * (
                        noise2[e, j] * orientation_sigma[e]
                    )
                qpos = numba.carray(pointer(data[e, QPOS]), (nq,), np.float64)
                s = _quat_mul(
                    qpos[3], qpos[4], qpos[5], qpos[6],
                    site_quat[0], site_quat[1], site_quat[2], site_quat[3],
                )  # fmt: skip
                s = _quat_mul(
                    gravity_frame[0], gravity_frame[1], gravity_frame[2], gravity_frame[3],
                    s[0], s[1], s[2], s[3],
                )  # fmt: skip
                r0, r1 = orientation_error[e, 0], orientation_error[e, 1]
                angle = math.sqrt(r0 * r0 + r1 * r1 + 0.0 * 0.0)  # rotation_rows' norm
                if angle < 1e-12:
                    half, w = 0.5, 1.0
                else:
                    half, w = math.sin(angle / 2) / angle, math.cos(angle / 2)
                q = _quat_mul(w, r0 * half, r1 * half, 0.0 * half, s[0], s[1], s[2], s[3])
                row = buf_imu[slot, e]
                for j in range(4):
                    row[6 + j] = q[j]
        else:
            for e in range(envs):
                for j in range(4):
                    buf_imu[slot, e, 6 + j] = np.nan
        for e in range(envs):
            lost = _next_double(streams[e, NEXT_DOUBLE], streams[e, STATE]) < dropout[e]
            buf_imu_stamp[slot, e] = np.nan if lost else time
            if lost:
                for j in range(10):
                    buf_imu[slot, e, j] = np.nan
    else:
        for e in range(envs):
            buf_imu_stamp[slot, e] = np.nan
            for j in range(10):
                buf_imu[slot, e, j] = np.nan
    if contact_due:
        for e in range(envs):
            for j in range(nf):
                noise_f[e, j] = _standard_normal(streams[e])
        for e in range(envs):
            sensordata = numba.carray(pointer(data[e, SENSORDATA]), (nsensor,), np.float64)
            sigma = force_noise_sigma[e]
            for j in range(nf):
                buf_force[slot, e, j] = sensordata[touch[j]] + noise_f[e, j] * sigma
            buf_contact_stamp[slot, e] = time
    else:
        for e in range(envs):
            buf_contact_stamp[slot, e] = np.nan
            for j in range(nf):
                buf_force[slot, e, j] = np.nan


@numba.njit(cache=True, nogil=True)
def base_read(
    buf_imu, buf_imu_stamp, buf_force, buf_contact_stamp, imu_latency, contact_latency,
    threshold, angular, acceleration, orientation, imu_stamp, foot_force, foot_contact,
    contact_stamp, tick,
):  # fmt: skip
    """:meth:`BaseSensorModel.read`: the readings arriving at ``tick`` (each env's latency in
    ticks) into the frame's IMU and contact fields (NaN before the first reading's origin),
    ``foot_contact`` the forces above each env's ``threshold`` (a NaN force: False)."""
    size = buf_imu_stamp.shape[0]
    envs, nf = foot_force.shape[0], foot_force.shape[1]
    for e in range(envs):
        origin = tick - imu_latency[e]
        row = buf_imu[origin % size, e]
        early = origin < 0
        for j in range(3):
            angular[e, j] = np.nan if early else row[j]
            acceleration[e, j] = np.nan if early else row[3 + j]
        for j in range(4):
            orientation[e, j] = np.nan if early else row[6 + j]
        imu_stamp[e] = np.nan if early else buf_imu_stamp[origin % size, e]
        origin = tick - contact_latency[e]
        early = origin < 0
        for j in range(nf):
            f = np.nan if early else buf_force[origin % size, e, j]
            foot_force[e, j] = f
            foot_contact[e, j] = f > threshold[e]
        contact_stamp[e] = np.nan if early else buf_contact_stamp[origin % size, e]


#: The arrays of :func:`base_sample` as slots of one table (after ``SAMPLE_HEADER`` ints:
#: ``nsensor``, ``nq``, ``gyro``, ``acc``, ``has_orientation``; ``dt`` is ``params[0]``): each
#: name's dtype and dimensions, in the kernel's order.
SAMPLE_SLOTS = (
    ("streams", "i8", 2), ("data", "i8", 2), ("touch", "i8", 1), ("params", "f8", 1),
    ("a", "f8", 1), ("gyro_bias", "f8", 2), ("accel_bias", "f8", 2), ("gyro_bias_walk", "f8", 1),
    ("accel_bias_walk", "f8", 1), ("gyro_noise_sigma", "f8", 1), ("accel_noise_sigma", "f8", 1),
    ("orientation_error", "f8", 2), ("orientation_sigma", "f8", 1), ("site_quat", "f8", 1),
    ("gravity_frame", "f8", 1), ("dropout", "f8", 1), ("force_noise_sigma", "f8", 1),
    ("noise6", "f8", 2), ("noise2", "f8", 2), ("noise_f", "f8", 2), ("buf_imu", "f8", 3),
    ("buf_imu_stamp", "f8", 2), ("buf_force", "f8", 3), ("buf_contact_stamp", "f8", 2),
)  # fmt: skip
SAMPLE_HEADER = 5


@numba.njit(cache=True, nogil=True, inline="always")
def _at(k):
    """The table index of slot ``k`` of :data:`SAMPLE_SLOTS`."""
    return SAMPLE_HEADER + SLOT * k


@numba.njit(cache=True, nogil=True)
def sample_table(table, imu_due, contact_due, slot, time):
    """:func:`base_sample` on the arrays of ``table`` (:data:`SAMPLE_SLOTS`): one array to
    unbox a call, not twenty-three."""
    f8, i8 = np.float64, np.int64
    params = view1(table, _at(3), f8)
    base_sample(
        view2(table, _at(0), i8), view2(table, _at(1), i8), table[0], table[1], table[2],
        table[3], view1(table, _at(2), i8), params[0], view1(table, _at(4), f8),
        view2(table, _at(5), f8), view2(table, _at(6), f8), view1(table, _at(7), f8),
        view1(table, _at(8), f8), view1(table, _at(9), f8), view1(table, _at(10), f8),
        table[4] != 0, view2(table, _at(11), f8), view1(table, _at(12), f8),
        view1(table, _at(13), f8), view1(table, _at(14), f8), view1(table, _at(15), f8),
        view1(table, _at(16), f8), view2(table, _at(17), f8), view2(table, _at(18), f8),
        view2(table, _at(19), f8), view3(table, _at(20), f8), view2(table, _at(21), f8),
        view3(table, _at(22), f8), view2(table, _at(23), f8), imu_due, contact_due, slot, time,
    )  # fmt: skip


#: The arrays of :func:`base_read` as slots of one table, in the kernel's order.
READ_SLOTS = (
    ("buf_imu", "f8", 3), ("buf_imu_stamp", "f8", 2), ("buf_force", "f8", 3),
    ("buf_contact_stamp", "f8", 2), ("imu_latency", "i8", 1), ("contact_latency", "i8", 1),
    ("threshold", "f8", 1), ("angular", "f8", 2), ("acceleration", "f8", 2),
    ("orientation", "f8", 2), ("imu_stamp", "f8", 1), ("foot_force", "f8", 2),
    ("foot_contact", "b1", 2), ("contact_stamp", "f8", 1),
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def read_table(table, tick):
    """:func:`base_read` on the arrays of ``table`` (:data:`READ_SLOTS`, from index 0)."""
    f8, i8 = np.float64, np.int64
    base_read(
        view3(table, 0, f8), view2(table, SLOT, f8), view3(table, 2 * SLOT, f8),
        view2(table, 3 * SLOT, f8), view1(table, 4 * SLOT, i8), view1(table, 5 * SLOT, i8),
        view1(table, 6 * SLOT, f8), view2(table, 7 * SLOT, f8), view2(table, 8 * SLOT, f8),
        view2(table, 9 * SLOT, f8), view1(table, 10 * SLOT, f8), view2(table, 11 * SLOT, f8),
        view2(table, 12 * SLOT, np.bool_), view1(table, 13 * SLOT, f8), tick,
    )  # fmt: skip
