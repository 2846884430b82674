"""The angular rate a legged policy reads is the gyro's reading of the same tick, its bias
estimate taken off: not smoothed over ticks. At one reading a control tick a legged robot's
turn rate changes between readings by more than the gyro's white noise (a push, a foot
strike), so a filter that averaged readings would lag the turn it is meant to report."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.core.attitude import quaternion_to_matrix
from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.estimation.base import BaseStateEstimator
from sim2real.deploy.estimation.reference import ReferenceBaseStateEstimator
from sim2real.robots import load_robot


@pytest.mark.parametrize("estimator", [BaseStateEstimator, ReferenceBaseStateEstimator])
def test_a_step_in_the_gyros_rate_shows_in_full_in_the_same_tick(estimator):
    """The H1 at rest, exact readings, no foot contact; at tick 50 its base starts pitching
    and rolling at (0.6, -0.8, 0) rad/s, as a push turns it: that tick's angular velocity
    estimate is the new rate to 1 %, and so is every later tick's (the bias estimate does not
    take a steady turn for a bias)."""
    robot = load_robot("h1")
    base = estimator(robot, 1)
    imu_to_base = quaternion_to_matrix(robot.mj_model.site_quat[robot.imu_site_id])
    dt = robot.control_period
    base.reset(0.0)
    frame = SensorFrame.empty(1, robot.n_joints, len(robot.foot_frame_ids))
    frame.imu_acceleration[0] = imu_to_base.T @ np.array([0.0, 0.0, 9.81])
    q, dq = robot.home[None].copy(), np.zeros((1, robot.n_joints))
    turn = np.array([0.6, -0.8, 0.0])
    seen = []
    for k in range(1, 60):
        rate = turn if k >= 50 else np.zeros(3)
        frame.time[0] = frame.imu_stamp[0] = k * dt
        frame.imu_angular_velocity[0] = imu_to_base.T @ rate
        est = base.update(frame, q, dq)
        seen.append(est.angular_velocity[0].copy())
    np.testing.assert_allclose(seen[48], np.zeros(3), atol=1e-3)
    for w in seen[49:]:
        np.testing.assert_allclose(w, turn, atol=0.01)
