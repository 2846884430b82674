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
from sim2real.deploy.kernels.calls import pointer
from sim2real.deploy.kernels.tables import Table

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


#: The arrays and constants of :func:`base_sample` (``touch`` the feet's ``sensordata`` index,
#: ``nf`` of them; ``window`` the latency buffers' rows).
SAMPLE = Table(
    "sim2real.deploy.backends.sim.legged_sensors_kernel:SAMPLE",
    nsensor="i8", nq="i8", gyro="i8", acc="i8", has_orientation="b1", dt="f8",
    has_heading="b1", heading_rate="f8[envs]", heading_walk="f8[envs]",
    heading_error="f8[envs]", noise1="f8[envs,1]",
    streams="i8[envs,3]", data="i8[envs,2]", touch="i8[nf]", a="f8[envs]",
    gyro_bias="f8[envs,3]", accel_bias="f8[envs,3]", gyro_bias_walk="f8[envs]",
    accel_bias_walk="f8[envs]", gyro_noise_sigma="f8[envs]", accel_noise_sigma="f8[envs]",
    orientation_error="f8[envs,2]", orientation_sigma="f8[envs]", site_quat="f8[4]",
    gravity_frame="f8[4]", dropout="f8[envs]", force_noise_sigma="f8[envs]",
    noise6="f8[envs,6]", noise2="f8[envs,2]", noise_f="f8[envs,nf]",
    buf_imu="f8[window,envs,10]", buf_imu_stamp="f8[window,envs]",
    buf_force="f8[window,envs,nf]", buf_contact_stamp="f8[window,envs]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def base_sample(t, imu_due, contact_due, slot, time):
    """The readings due at a tick into row ``slot`` of the latency buffers, every env
    (:meth:`BaseSensorModel.sample` with ``force`` False and ``envs`` None), from the packed
    table ``t`` (:data:`SAMPLE`): the IMU where ``imu_due`` (its period ``dt`` s; ``a`` (envs,)
    = ``exp(-dt / orientation_tau)``), else the row NaN; the foot forces where ``contact_due``,
    else NaN. ``streams`` (envs, 3): each env's sensor stream (``plant_kernel.STREAMS``);
    ``data`` (envs, 2): each env's ``sensordata`` (``nsensor``) and ``qpos`` (``nq``)
    addresses; ``gyro``, ``acc``: the sensors' first ``sensordata`` index, ``touch`` the
    feet's; ``noise6``, ``noise2``, ``noise_f``: the model's draw arrays, left holding the last
    draws as numpy's path leaves them; ``time`` s, the stamp."""
    streams, data, touch, dt, a = t.streams, t.data, t.touch, t.dt, t.a
    nsensor, nq, gyro, acc = t.nsensor, t.nq, t.gyro, t.acc
    gyro_bias, accel_bias = t.gyro_bias, t.accel_bias
    gyro_bias_walk, accel_bias_walk = t.gyro_bias_walk, t.accel_bias_walk
    gyro_noise_sigma, accel_noise_sigma = t.gyro_noise_sigma, t.accel_noise_sigma
    has_orientation, orientation_error = t.has_orientation, t.orientation_error
    orientation_sigma, site_quat, gravity_frame = t.orientation_sigma, t.site_quat, t.gravity_frame
    dropout, force_noise_sigma = t.dropout, t.force_noise_sigma
    noise6, noise2, noise_f = t.noise6, t.noise2, t.noise_f
    has_heading, heading_rate, heading_walk = t.has_heading, t.heading_rate, t.heading_walk
    heading_error, noise1 = t.heading_error, t.noise1
    buf_imu, buf_imu_stamp = t.buf_imu, t.buf_imu_stamp
    buf_force, buf_contact_stamp = t.buf_force, t.buf_contact_stamp
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
            if has_heading:  # numpy's path: all envs' draws, then each env's turn
                for e in range(envs):
                    noise1[e, 0] = _standard_normal(streams[e])
                for e in range(envs):
                    heading_error[e] = heading_error[e] + (
                        heading_rate[e] * dt + heading_walk[e] * root * noise1[e, 0]
                    )
                    h = heading_error[e]
                    angle = math.sqrt(0.0 * 0.0 + 0.0 * 0.0 + h * h)  # rotation_rows' norm
                    if angle < 1e-12:
                        half, w = 0.5, 1.0
                    else:
                        half, w = math.sin(angle / 2) / angle, math.cos(angle / 2)
                    row = buf_imu[slot, e]
                    q = _quat_mul(
                        w, 0.0 * half, 0.0 * half, h * half, row[6], row[7], row[8], row[9]
                    )
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


#: The arrays of :func:`base_read`: the latency buffers (:data:`SAMPLE`'s), each env's latency
#: in ticks and contact threshold (N), and the frame's IMU and contact fields it fills.
READ = Table(
    "sim2real.deploy.backends.sim.legged_sensors_kernel:READ",
    buf_imu="f8[window,envs,10]", buf_imu_stamp="f8[window,envs]",
    buf_force="f8[window,envs,nf]", buf_contact_stamp="f8[window,envs]",
    imu_latency="i8[envs]", contact_latency="i8[envs]", threshold="f8[envs]",
    angular="f8[envs,3]", acceleration="f8[envs,3]", orientation="f8[envs,4]",
    imu_stamp="f8[envs]", foot_force="f8[envs,nf]", foot_contact="b1[envs,nf]",
    contact_stamp="f8[envs]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def base_read(t, tick):
    """:meth:`BaseSensorModel.read` over the packed table ``t`` (:data:`READ`): the readings
    arriving at ``tick`` (each env's latency in ticks) into the frame's IMU and contact fields
    (NaN before the first reading's origin), ``foot_contact`` the forces above each env's
    ``threshold`` (a NaN force: False)."""
    buf_imu, buf_imu_stamp = t.buf_imu, t.buf_imu_stamp
    buf_force, buf_contact_stamp = t.buf_force, t.buf_contact_stamp
    imu_latency, contact_latency, threshold = t.imu_latency, t.contact_latency, t.threshold
    angular, acceleration, orientation = t.angular, t.acceleration, t.orientation
    imu_stamp, foot_force, foot_contact = t.imu_stamp, t.foot_force, t.foot_contact
    contact_stamp = t.contact_stamp
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
