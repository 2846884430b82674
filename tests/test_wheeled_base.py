"""A wheel-legged robot's base estimate and fall check: a wheel in contact rolls (its contact point,
not its hub, is at rest) and the base's height is measured to the ground beneath the wheel.
Built on unitree_mujoco's Go2-W (sim2real/robots/go2w) with rl_sar's wheel drive (kp 0, kd 0.5:
policy/go2w/robot_lab/config.yaml), its legs held at home by stiffer PD (as tests/test_legged.py
holds the Go2 standing) and its wheels driven at a constant speed."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.attitude import quaternion_to_matrix
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.estimation.base import BaseStateEstimator
from sim2real.deploy.estimation.base_params import foot_radii
from sim2real.deploy.estimation.fall import FallDetector
from sim2real.deploy.estimation.joints import JointStateEstimator
from sim2real.robots import load_robot
from sim2real.robots.drive import with_drive
from tests.test_velocity_drives import position_driven

#: Leg PD that holds the Go2-W on its wheels without a policy, N m/rad and N m s/rad
#: (unitree_sdk2's example/go2/go2_stand_example.cpp, as tests/test_legged.py).
STAND_KP, STAND_KD = 60.0, 5.0
#: Wheel speed target, rad/s: about 1 m/s over the ground on the plant (its wheels creep some).
WHEEL_SPEED = 1.4 / 0.086


@pytest.fixture(scope="module")
def go2w():
    """The Go2-W with rl_sar's drive: legs PD position targets, wheels speed targets."""
    robot = load_robot("go2w")
    wheel = np.array(["wheel" in n for n in robot.joint_names])
    kinds = tuple("velocity" if w else "position" for w in wheel)
    return with_drive(robot, kp=np.where(wheel, 0.0, 20.0), kd=np.full(16, 0.5), kinds=kinds)


@pytest.fixture(scope="module")
def rolled(go2w):
    """The Go2-W settled on its wheels for 2 s, then rolling forward for 5 s (wheel speed
    ramped in over the first second) under the joint and base estimators and the fall check.
    Returns per tick: estimated and true forward speed (m/s, base frame), the fall check's
    height and the true base height above the floor (m), whether it judged a fall."""
    model = go2w.plant_model("position")
    legs = np.flatnonzero(~go2w.velocity_driven)
    model.actuator_gainprm[legs, 0] = STAND_KP
    model.actuator_biasprm[legs, 1] = -STAND_KP
    model.actuator_biasprm[legs, 2] = -STAND_KD
    plant = SimBackend(go2w, "position", envs=1, seed=0, models=[model])
    command = np.array(go2w.home, dtype=float)[None]
    for _ in range(100):
        plant.read()
        plant.write(command)
        plant.advance()
    joints, base, fall = (
        JointStateEstimator(go2w, 1),
        BaseStateEstimator(go2w, 1),
        FallDetector(go2w, 1),
    )
    frame = plant.read()
    joints.reset(plant.true_position(), frame.time)
    base.reset(frame.time, frame.imu_acceleration, orientation=frame.imu_orientation)
    state = RobotState.legged(1, go2w.n_joints, go2w.n_feet)
    rows = []
    for k in range(250):
        frame = plant.read()
        joints.update(frame, state)
        base.update(frame, state.q, state.dq, out=state.base)
        state.foot_contact[:] = base.contact
        fallen = fall.check(state)
        truth = plant.true_base_state()[0]
        forward = (quaternion_to_matrix(truth[3:7]).T @ truth[7:10])[0]
        rows.append(
            (state.base.linear_velocity[0, 0], forward, fall.height[0], truth[2], fallen[0])
        )
        command[0, go2w.velocity_driven] = min(1.0, k / 50) * WHEEL_SPEED
        plant.write(command)
        plant.advance()
    return np.array(rows)


def test_a_wheels_radius_is_its_collision_meshs_from_the_mjcf(go2w):
    """go2w.xml's wheel hull reaches 0.086 m from the axle; a foot on a position-driven joint
    is no wheel."""
    np.testing.assert_allclose(foot_radii(go2w), 0.086, atol=5e-4)
    assert not foot_radii(position_driven(go2w)).any()


def test_a_rolling_go2w_base_speed_is_read_through_its_wheels(rolled):
    """The base estimate's forward speed within 10 % of the truth at about 1 m/s: a wheel's
    contact point, its hub less its radius, is what is at rest (the plant's wheels creep, so
    the estimate reads a few per cent fast)."""
    est, true = rolled[150:, 0], rolled[150:, 1]  # the last 2 s, at speed
    assert true.mean() > 0.9
    assert abs(est.mean() - true.mean()) < 0.1 * true.mean(), (est.mean(), true.mean())


def test_a_rolling_go2w_stands_its_height_above_the_ground_and_never_falls(rolled):
    """The fall check's kinematic height is the base's above the ground beneath the wheels,
    not above their hubs (NaN on the few ticks no wheel's contact reading clears its threshold)."""
    height, true_height, fallen = rolled[:, 2], rolled[:, 3], rolled[:, 4]
    seen = np.isfinite(height)
    assert seen.mean() > 0.9
    np.testing.assert_allclose(height[seen], true_height[seen], atol=0.01)
    assert not fallen.any()
