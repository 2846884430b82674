"""The base estimator's tick for every env at once, compiled: two calls around Pinocchio's.

:func:`absorb_imu` runs, per env, what :class:`~sim2real.deploy.estimation.base_steps.BaseSteps`
runs in Python before the leg kinematics: the IMU reading's freshness and counters, the encoder
rate, the dead-foot watch, the sensor's contacts, the prediction (the lever arm's acceleration
from the change of the angular velocity since the last reading, column ``OMEGA``) and the
accelerometer's and the IMU attitude's corrections
(:mod:`sim2real.deploy.estimation.base_kernel`). It marks the envs
whose legs are to be read. Pinocchio then gives those envs' foot velocities (and placements, with
a dead foot); :func:`absorb_legs` runs the contacts, the slip gate and the feet's corrections,
then predicts every env's output to ``frame.time``. Same expressions, same order as the Python
steps: the same numbers (``tests/test_base_tick.py``). A foot's placement is not needed for its
velocity (Pinocchio's ``getFrameVelocity`` reads the joint's): it is updated with a dead foot only.

The filter's state is packed so that a call takes few arrays (numba's dispatch unboxes each
array argument): ``x`` (envs, ``NX``) floats (columns ``ORIENTATION`` ... ``AGE``), ``n``
(envs, 5) int64 counters (``MISSING`` ... ``RUN``), ``feet`` (2, envs, n_feet) bool (contact, dead),
``force`` (2, envs, n_feet) (last force, its stamp), ``encoder`` (2, envs, n_joints) (last
position, its stamp), and ``p`` the constants (``P_*`` indices, the feet's radii from ``P_RADII``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim2real.deploy.estimation.base_kernel import (
    _quat_to_mat,
    attitude_step_in,
    fma,
    imu_step_in,
    leg_step_in,
    workspace,
)
from sim2real.deploy.kernels.tables import Table

#: Columns of the packed float state ``x``: quaternion (4), velocity (3), biases (6), angular
#: velocity (3), filter time, time since fresh.
ORIENTATION, VELOCITY, BIAS, OMEGA, TIME, AGE = 0, 4, 7, 13, 16, 17
NX = 18
#: Columns of the packed counters ``n``.
MISSING, STALE, UPDATES, REJECTED, RUN = 0, 1, 2, 3, 4
#: Indices of the constants ``p``: the filter's variances, the rest band, the slip gate, the
#: attitude variance (NaN: no IMU attitude), the encoder's longest gap (s), the dead-foot time (s),
#: the kinematic contact band (m), the velocity's restart variance, the readings before the gate
#: opens; the lever arm (3), gravity (3), the IMU-to-base rotation (9, row-major), the radii.
P_GYRO, P_ACCEL, P_WALK, P_ACCEL_WALK, P_ACCEL_MEAS, P_REST, P_LEG, P_GATE = range(8)
P_ATTITUDE, P_GAP, P_DEAD_TIME, P_BAND, P_RESTART, P_MAX_RUN = range(8, 14)
P_LEVER, P_GRAVITY, P_IMU, P_RADII = 14, 17, 20, 29
#: ``legs`` flags of :func:`absorb_imu`: read the legs; with a dead foot (placements needed).
LEGS, DEAD = 1, 2


@numba.njit(cache=True, nogil=True)
def _all_finite(a) -> bool:
    for i in range(a.shape[0]):
        if not math.isfinite(a[i]):
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _rotate(p, at: int, a, out) -> None:
    """``out`` (3,) = ``M a``, ``M`` the (3, 3) row-major rotation at ``p[at:at + 9]`` (rounded
    as numpy's ``M @ a``: BLAS's gemv, :func:`~sim2real.deploy.estimation.base_kernel.mv`)."""
    for i in range(3):
        r = p[at + 3 * i : at + 3 * i + 3]
        out[i] = fma(r[2], a[2], fma(r[0], a[0], r[1] * a[1]))


@numba.njit(cache=True, nogil=True)
def absorb_imu(
    x, P, n, feet, force, encoder, p, time, imu_stamp, gyro, acc, onboard, foot_force,
    foot_contact, contact_stamp, position, position_stamp, velocity, q, dq, rate, legs,
):  # fmt: skip
    """Every env's tick before the leg kinematics (module docstring); ``x``, ``P``, ``n``,
    ``feet``, ``force``, ``encoder`` in place.

    The frame's fields: ``time``, ``imu_stamp``, ``contact_stamp`` (envs,) s; ``gyro``
    (envs, 3) rad/s; ``acc`` (envs, 3) m/s^2; ``onboard`` (envs, 4) the IMU's attitude;
    ``foot_force``, ``foot_contact`` (envs, n_feet); ``position`` (rad), ``position_stamp`` (s),
    ``velocity`` (rad/s, NaN where the drive reported none) (envs, n_joints). ``q``, ``dq``
    (envs, n_joints): the joint estimate. Out: ``rate`` (envs, n_joints) rad/s, the odometry's
    joint velocities; ``legs`` (envs,) int64, ``LEGS | DEAD`` flags."""
    envs, n_feet, n_joints = x.shape[0], feet.shape[2], q.shape[1]
    gyro_b, acc_b = np.empty(3), np.empty(3)
    rot, measured = np.empty((3, 3)), np.empty((3, 3))
    work = workspace()
    for e in range(envs):
        now, stamp = time[e], imu_stamp[e]
        finite = math.isfinite(stamp) and _all_finite(gyro[e]) and _all_finite(acc[e])
        fresh = finite and x[e, TIME] < stamp and stamp <= now  # NaN compares False
        n[e, MISSING] += not finite
        n[e, STALE] += finite and not fresh
        # the encoder rate (BaseSteps._encoder_rate)
        legs_ok = True
        for j in range(n_joints):
            pos, pst = position[e, j], position_stamp[e, j]
            gap = pst - encoder[1, e, j]
            r = dq[e, j]
            if gap > 0 and gap <= p[P_GAP]:
                d = (pos - encoder[0, e, j]) / gap
                if math.isfinite(d):
                    r = d
            if math.isfinite(velocity[e, j]):
                r = velocity[e, j]
            rate[e, j] = r
            legs_ok = legs_ok and math.isfinite(r) and math.isfinite(q[e, j])
            if math.isfinite(pos) and math.isfinite(pst):
                encoder[0, e, j], encoder[1, e, j] = pos, pst
        # the dead-foot watch (BaseSteps._watch_feet) and the sensor's contacts
        contact_fresh = math.isfinite(contact_stamp[e])
        any_dead = False
        for i in range(n_feet):
            value = foot_force[e, i]
            if math.isnan(value) and contact_fresh:
                feet[1, e, i] = True
            if math.isfinite(value) and value != force[0, e, i]:
                force[1, e, i] = now
                force[0, e, i] = value
            if now - force[1, e, i] >= p[P_DEAD_TIME]:  # NaN compares False
                feet[1, e, i] = True
            feet[0, e, i] = foot_contact[e, i] != 0 and not feet[1, e, i]
            any_dead = any_dead or feet[1, e, i]
        legs[e] = 0
        if not fresh:
            continue
        # the prediction and the accelerometer's correction (BaseSteps._imu_step)
        _rotate(p, P_IMU, gyro[e], gyro_b)
        _rotate(p, P_IMU, acc[e], acc_b)
        imu_step_in(
            x[e, ORIENTATION:VELOCITY], x[e, VELOCITY:BIAS], x[e, BIAS:OMEGA], P[e],
            gyro_b, acc_b, stamp - x[e, TIME], p[P_LEVER:P_GRAVITY], p[P_GRAVITY:P_IMU],
            p[P_GYRO], p[P_ACCEL], p[P_WALK], p[P_ACCEL_WALK], p[P_ACCEL_MEAS], p[P_REST],
            x[e, OMEGA:TIME], work,
        )  # fmt: skip
        x[e, TIME] = stamp
        if not math.isnan(p[P_ATTITUDE]) and _all_finite(onboard[e]):
            # BaseSteps._attitude_step: measured = R(quaternion) imu_to_base^T (BLAS's gemm)
            _quat_to_mat(onboard[e], rot)
            for i in range(3):
                for j in range(3):
                    b = p[P_IMU + 3 * j : P_IMU + 3 * j + 3]
                    measured[i, j] = fma(rot[i, 2], b[2], fma(rot[i, 1], b[1], rot[i, 0] * b[0]))
            attitude_step_in(
                x[e, ORIENTATION:VELOCITY], x[e, VELOCITY:BIAS], x[e, BIAS:OMEGA], P[e],
                measured, p[P_ATTITUDE], work,
            )  # fmt: skip
        if legs_ok:
            legs[e] = LEGS | (DEAD if any_dead else 0)


@numba.njit(cache=True, nogil=True)
def absorb_legs(
    x, P, n, feet, p, time, contact_stamp, legs, foot_motion, foot_position,
    out_q, out_g, out_v, out_w, out_vw,
):  # fmt: skip
    """Every marked env's leg odometry, then every env's output (module docstring); ``x``,
    ``P``, ``n``, ``feet`` in place.

    ``legs``: (envs,) flags of :func:`absorb_imu`; ``foot_motion``: (envs, n_feet, 6) each foot's
    velocity, linear (m/s) and angular (rad/s), base frame, the base at the origin turning at
    the estimate; ``foot_position``: (envs, n_feet, 3) m, their placements (read only with a dead
    foot); ``time``, ``contact_stamp``: the frame's (envs,) s. Out, the estimate at ``time``
    (:class:`~sim2real.deploy.core.state.BaseState`'s fields): ``out_q`` (envs, 4) quaternion,
    ``out_g`` (envs, 3) projected gravity, ``out_v`` (envs, 3) m/s base-frame velocity,
    ``out_w`` (envs, 3) rad/s angular velocity, ``out_vw`` (envs, 3) m/s world velocity."""
    envs, n_feet = x.shape[0], feet.shape[2]
    rot = np.empty((3, 3))
    height = np.empty(n_feet)
    work = workspace()
    for e in range(envs):
        if legs[e] == 0:
            continue
        # the feet in contact (BaseSteps._contacts)
        fresh = math.isfinite(contact_stamp[e])
        if legs[e] & DEAD:
            if not fresh:
                for i in range(n_feet):
                    feet[0, e, i] = False
            _quat_to_mat(x[e, ORIENTATION:VELOCITY], rot)
            lowest = np.inf
            for i in range(n_feet):
                r = foot_position[e, i]
                height[i] = fma(rot[2, 2], r[2], fma(rot[2, 0], r[0], rot[2, 1] * r[1]))
                height[i] -= p[P_RADII + i]
                lowest = min(lowest, height[i])
            for i in range(n_feet):
                if feet[1, e, i] and height[i] - lowest < p[P_BAND]:
                    feet[0, e, i] = True
        elif not fresh:
            continue
        touching = False
        for i in range(n_feet):
            touching = touching or feet[0, e, i]
        if not touching:
            continue
        # the slip gate (BaseSteps._gate)
        gate = p[P_GATE]
        Pe = P[e]
        if n[e, RUN] >= p[P_MAX_RUN]:
            gate = np.inf
            for i in range(3):
                for j in range(3):
                    Pe[3 + i, j] = Pe[j, 3 + i] = 0.0
                for j in range(6, 12):
                    Pe[3 + i, j] = Pe[j, 3 + i] = 0.0
            for i in range(3):
                for j in range(3):
                    Pe[3 + i, 3 + j] += p[P_RESTART] if i == j else 0.0
        # the feet's corrections (BaseSteps._absorb_feet)
        absorbed = False
        for i in range(n_feet):
            if not feet[0, e, i]:
                continue
            ok = leg_step_in(
                x[e, ORIENTATION:VELOCITY], x[e, VELOCITY:BIAS], x[e, BIAS:OMEGA], Pe,
                foot_motion[e, i, 0:3], foot_motion[e, i, 3:6], p[P_RADII + i], p[P_LEG], gate,
                work,
            )  # fmt: skip
            n[e, UPDATES] += ok
            n[e, REJECTED] += not ok
            absorbed = absorbed or ok
        n[e, RUN] = 0 if absorbed else n[e, RUN] + 1
    # the output, predicted from filter_time to now (BaseSteps._output)
    for e in range(envs):
        age = time[e] - x[e, TIME]
        x[e, AGE] = age
        if age < 0.0:  # np.maximum(age, 0): NaN stays NaN
            age = 0.0
        r0, r1, r2 = x[e, OMEGA] * age, x[e, OMEGA + 1] * age, x[e, OMEGA + 2] * age
        angle = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
        if angle < 1e-12:
            half, bw = 0.5, 1.0
        else:
            half, bw = math.sin(angle / 2) / angle, math.cos(angle / 2)
        bx, by, bz = r0 * half, r1 * half, r2 * half
        aw, ax, ay, az = x[e, 0], x[e, 1], x[e, 2], x[e, 3]
        o = out_q[e]
        o[0] = aw * bw - ax * bx - ay * by - az * bz
        o[1] = aw * bx + ax * bw + ay * bz - az * by
        o[2] = aw * by - ax * bz + ay * bw + az * bx
        o[3] = aw * bz + ax * by - ay * bx + az * bw
        _quat_to_mat(o, rot)
        v0, v1, v2 = x[e, VELOCITY], x[e, VELOCITY + 1], x[e, VELOCITY + 2]
        for i in range(3):
            out_g[e, i] = -rot[2, i]
            out_v[e, i] = fma(rot[2, i], v2, fma(rot[1, i], v1, rot[0, i] * v0))  # gemm's
            out_w[e, i] = x[e, OMEGA + i]
            out_vw[e, i] = x[e, VELOCITY + i]


#: The arguments of :func:`absorb_imu` and :func:`absorb_legs` (their names, ``p`` the
#: estimator's (``time`` its own (envs,) s), the frame's and the output's fields), one table.
TICK = Table(
    "sim2real.deploy.estimation.base_tick:TICK",
    x="f8[envs,*]", P="f8[envs,*,*]", n="i8[envs,*]", feet="b1[*,envs,*]",
    force="f8[*,envs,*]", encoder="f8[*,envs,*]", p="f8[*]", time="f8[envs]",
    imu_stamp="f8[envs]", gyro="f8[envs,3]", acc="f8[envs,3]", onboard="f8[envs,4]",
    foot_force="f8[envs,*]", foot_contact="b1[envs,*]", contact_stamp="f8[envs]",
    position="f8[envs,*]", position_stamp="f8[envs,*]", velocity="f8[envs,*]",
    q="f8[envs,*]", dq="f8[envs,*]", rate="f8[envs,*]", legs="i8[envs]",
    foot_motion="f8[envs,*,*]", foot_position="f8[envs,*,*]", out_q="f8[envs,4]",
    out_g="f8[envs,3]", out_v="f8[envs,3]", out_w="f8[envs,3]", out_vw="f8[envs,3]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def tick_stage(t, stage):
    """:func:`absorb_imu` (``stage`` 0) or :func:`absorb_legs` (1) on the packed table ``t``
    (:data:`TICK`): one array to unbox, not twenty."""
    if stage == 0:
        absorb_imu(
            t.x, t.P, t.n, t.feet, t.force, t.encoder, t.p, t.time, t.imu_stamp, t.gyro, t.acc,
            t.onboard, t.foot_force, t.foot_contact, t.contact_stamp, t.position,
            t.position_stamp, t.velocity, t.q, t.dq, t.rate, t.legs,
        )  # fmt: skip
    else:
        absorb_legs(
            t.x, t.P, t.n, t.feet, t.p, t.time, t.contact_stamp, t.legs, t.foot_motion,
            t.foot_position, t.out_q, t.out_g, t.out_v, t.out_w, t.out_vw,
        )  # fmt: skip
