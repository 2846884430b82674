"""The base estimator's steps of one env, in Python: the tick of
:class:`~sim2real.deploy.estimation.reference.ReferenceBaseStateEstimator` (which overrides the
algebra's hooks ``_imu_step``, ``_attitude_step`` and ``_absorb_feet`` with filterpy's) and the
readable form of the compiled tick (:mod:`sim2real.deploy.estimation.base_tick`, the same
expressions in the same order for every env at once). :class:`BaseSteps` is a mixin of
:class:`~sim2real.deploy.estimation.base.BaseStateEstimator`: it reads and writes that class's
attributes.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from sim2real.deploy.core.attitude import quat_multiply, quaternion_to_matrix, rotation_quaternions
from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import BaseState
from sim2real.deploy.estimation.base_kernel import attitude_step, imu_step, leg_step
from sim2real.deploy.estimation.base_params import (
    DEAD_FOOT_TIME,
    INITIAL_VELOCITY_SIGMA,
    KINEMATIC_CONTACT_BAND,
    MAX_REJECTED_READINGS,
    REST_ACCELERATION_TOLERANCE,
)


class BaseSteps:
    """The per-env steps of the base estimator's tick (module docstring)."""

    def _tick_per_env(self, frame: SensorFrame, q: np.ndarray, dq: np.ndarray, out: BaseState):
        """The tick of :meth:`BaseStateEstimator.update` after its checks, one env at a time."""
        now, stamp = frame.time, frame.imu_stamp
        gyro, acc = frame.imu_angular_velocity, frame.imu_acceleration
        finite = np.isfinite(stamp) & np.isfinite(gyro).all(axis=1) & np.isfinite(acc).all(axis=1)
        with np.errstate(invalid="ignore"):  # NaN stamps are not fresh
            fresh = finite & (self.filter_time < stamp) & (stamp <= now)
        self.missing_readings += ~finite
        self.stale_readings += finite & ~fresh
        onboard = frame.imu_orientation
        rate = self._encoder_rate(frame, dq)
        self._watch_feet(frame)
        np.logical_and(frame.foot_contact, ~self.dead_feet, out=self.contact)  # the sensors'
        for e in np.flatnonzero(fresh):
            self._imu_step(e, float(stamp[e]), gyro[e], acc[e])
            if self.attitude_variance is not None and np.isfinite(onboard[e]).all():
                self._attitude_step(e, onboard[e])
            self._legs_step(e, frame, q[e], rate[e])
        # output: predicted from filter_time to now (orientation turned by omega; v held), every
        # env at once (an env not behind turns by a zero rotation: its quaternion unchanged)
        np.subtract(now, self.filter_time, out=self.time_since_fresh)
        age = np.maximum(self.time_since_fresh, 0.0)[:, None]
        quat = quat_multiply(self.orientation, rotation_quaternions(self.angular_velocity * age))
        rot = quaternion_to_matrix(quat)
        out.orientation[:] = quat
        out.projected_gravity[:] = -rot[:, 2]
        out.linear_velocity[:] = np.matmul(rot.transpose(0, 2, 1), self.velocity[:, :, None])[
            :, :, 0
        ]
        out.angular_velocity[:] = self.angular_velocity
        out.linear_velocity_world[:] = self.velocity
        return out

    def _imu_step(self, e: int, stamp: float, gyro: np.ndarray, acc: np.ndarray) -> None:
        """Env ``e``'s prediction to ``stamp`` and the accelerometer's gravity correction
        (:func:`sim2real.deploy.estimation.base_kernel.imu_step`)."""
        imu_step(
            self.orientation[e],
            self.velocity[e],
            self.bias[e],
            self.covariance[e],
            self._imu_to_base @ gyro,
            self._imu_to_base @ acc,
            stamp - self.filter_time[e],
            self.lever_arm,
            self.gravity,
            self.gyro_variance,
            self.accel_variance,
            self.bias_walk_variance,
            self.accel_bias_walk_variance,
            self.accel_meas_variance,
            3 * REST_ACCELERATION_TOLERANCE,
            self.angular_velocity[e],
        )
        self.filter_time[e] = stamp

    def _encoder_rate(self, frame: SensorFrame, dq: np.ndarray) -> np.ndarray:
        """(envs, n_joints) rad/s, the joint velocities the leg odometry uses: the velocity the
        drive reported (``frame.velocity``) where it did; else each encoder's reading differenced
        against its previous one over their stamps (half a reading's period behind; the joint
        filter's constant-velocity estimate lags a stepping leg by two to three control periods);
        else the joint estimate ``dq``."""
        pos, stamp = frame.position, frame.position_stamp
        with np.errstate(invalid="ignore", divide="ignore"):
            gap = stamp - self._encoder_stamp
            rate = (pos - self._encoder_position) / gap
            ok = np.isfinite(rate) & (gap > 0) & (gap <= 2.5 * self.robot.control_period)
        out = np.where(ok, rate, dq)
        if frame.velocity is not None:
            reported = np.isfinite(frame.velocity)
            out[reported] = frame.velocity[reported]
        fresh = np.isfinite(pos) & np.isfinite(stamp)
        self._encoder_position[fresh] = pos[fresh]
        self._encoder_stamp[fresh] = stamp[fresh]
        return out

    def _attitude_step(self, e: int, quaternion: np.ndarray) -> None:
        """Env ``e``'s correction by the IMU's own attitude (``quaternion``: the IMU site to
        the world; :func:`sim2real.deploy.estimation.base_kernel.attitude_step`)."""
        measured = quaternion_to_matrix(quaternion) @ self._imu_to_base.T  # base to world
        attitude_step(
            self.orientation[e],
            self.velocity[e],
            self.bias[e],
            self.covariance[e],
            measured,
            self.attitude_variance,
        )

    def _foot_velocities(self, e: int, q, dq):
        """Env ``e``'s feet's velocities, linear and angular, (n_feet, 3) each (m/s, rad/s, base
        frame, the base at the origin turning at ``angular_velocity[e]``: Pinocchio)."""
        model, data = self.robot.pin_model, self._pin
        self._q[7:] = q
        self._v[3:6] = self.angular_velocity[e]
        self._v[6:] = dq
        pin.forwardKinematics(model, data, self._q, self._v)
        for f in self.robot.foot_frame_ids:  # placements too: the kinematic contact
            pin.updateFramePlacement(model, data, f)
        frames = [
            pin.getFrameVelocity(model, data, f, pin.LOCAL_WORLD_ALIGNED)
            for f in self.robot.foot_frame_ids
        ]
        return [m.linear for m in frames], [m.angular for m in frames]

    def _gate(self, e: int) -> float:
        """Env ``e``'s slip gate for this reading: ``slip_gate``, or ``inf`` after
        ``MAX_REJECTED_READINGS`` readings without an absorbed foot. Opening it, the velocity
        restarts from the legs: its block of the covariance is widened (``INITIAL_VELOCITY_SIGMA``
        added) and its correlation with the attitude and bias dropped, so that a base whose
        velocity jumped (a push, a landing) is not read as a tilt."""
        if self._rejected_run[e] < MAX_REJECTED_READINGS:
            return self.slip_gate
        P = self.covariance[e]
        P[3:6, :3] = P[:3, 3:6] = P[3:6, 6:] = P[6:, 3:6] = 0.0
        P[3:6, 3:6] += np.eye(3) * INITIAL_VELOCITY_SIGMA**2
        return np.inf

    def _watch_feet(self, frame: SensorFrame) -> None:
        """Latch ``dead_feet``: a foot whose force reading (finite) has not changed for
        ``DEAD_FOOT_TIME`` s of the frame's time, and at once a foot with no force reading in a
        fresh contact frame (a robot without foot sensors: the G1 and H1-2's ``unitree_hg``
        LowState carries none)."""
        force = frame.foot_force
        with np.errstate(invalid="ignore"):
            self.dead_feet |= np.isnan(force) & np.isfinite(frame.contact_stamp)[:, None]
        with np.errstate(invalid="ignore"):
            changed = np.isfinite(force) & (force != self._force_last)
        now = np.broadcast_to(frame.time[:, None], force.shape)
        self._force_since[changed] = now[changed]
        self._force_last[changed] = force[changed]
        with np.errstate(invalid="ignore"):
            self.dead_feet |= (now - self._force_since) >= DEAD_FOOT_TIME

    def _contacts(self, e: int, frame: SensorFrame) -> np.ndarray | None:
        """Env ``e``'s feet in contact for the leg odometry, (n_feet,) bool, into
        ``contact[e]``: the sensor's where it is alive and fresh, the kinematics' (within
        ``KINEMATIC_CONTACT_BAND`` of the lowest foot, gravity frame; Pinocchio's placements of
        the last :meth:`_foot_velocities`) for a dead foot; None without either."""
        dead = self.dead_feet[e]
        fresh = np.isfinite(frame.contact_stamp[e])
        contact = self.contact[e] if fresh else np.zeros_like(dead)
        if dead.any():
            rot = quaternion_to_matrix(self.orientation[e])
            data = self._pin
            height = np.array(
                [(rot @ data.oMf[f].translation)[2] for f in self.robot.foot_frame_ids]
            )
            height -= self.radii
            contact = contact | (dead & (height - height.min() < KINEMATIC_CONTACT_BAND))
        elif not fresh:
            return None
        self.contact[e] = contact
        return contact

    def _legs_step(self, e: int, frame: SensorFrame, q, dq) -> None:
        """Env ``e``'s leg odometry: one gated velocity correction per foot in contact
        (:meth:`_contacts`; :func:`sim2real.deploy.estimation.base_kernel.leg_step`)."""
        if not (np.isfinite(q).all() and np.isfinite(dq).all()):
            return
        linear, angular = self._foot_velocities(e, q, dq)
        contact = self._contacts(e, frame)
        if contact is None or not contact.any():
            return
        self._absorb_feet(e, contact, linear, angular, self._gate(e))

    def _absorb_feet(self, e: int, contact, linear, angular, gate: float) -> None:
        """Env ``e``'s velocity corrections by its feet in ``contact`` ((n_feet,) bool; their
        velocities ``linear``, ``angular``), each gated at ``gate`` (chi-square)."""
        absorbed = False
        for i in np.flatnonzero(contact):
            ok = leg_step(
                self.orientation[e],
                self.velocity[e],
                self.bias[e],
                self.covariance[e],
                linear[i],
                angular[i],
                float(self.radii[i]),
                self.leg_variance,
                gate,
            )
            self.velocity_updates[e] += ok
            self.rejected_contacts[e] += not ok
            absorbed |= ok
        self._rejected_run[e] = 0 if absorbed else self._rejected_run[e] + 1
