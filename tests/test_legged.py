"""Floating-base robots: go2 loads with its free joint, the plant's IMU
and foot contacts behave as configured, and the base estimator follows the true base."""

from __future__ import annotations

import shutil

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.core.attitude import projected_gravity, quaternion_to_matrix, tilt_of
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.estimation.base import BaseStateEstimator
from sim2real.deploy.estimation.joints import JointStateEstimator
from sim2real.deploy.estimation.reference import ReferenceBaseStateEstimator
from sim2real.robots import RobotSpecError, load_robot
from sim2real.robots.loading import ROBOTS_DIR

#: Gains that hold go2 standing without a policy: Unitree's unitree_sdk2
#: example/go2/go2_stand_example.cpp (kp 60, kd 5). The robot's own kp 20 / kd 0.5 (the walking
#: policy's, unitree_rl_gym) lets it sit down on its rear thighs when nothing corrects it.
STAND_KP, STAND_KD = 60.0, 5.0
#: Ticks (50 Hz) for the robot to settle on the floor after a reset.
SETTLE = 100


def stand_plant(robot, envs=1, seed=0, gravity=None) -> SimBackend:
    """A position-mode plant whose PD servos hold go2 standing (``STAND_KP``, ``STAND_KD``);
    ``gravity``: the model's gravity vector (m/s^2; a tilted floor)."""
    model = robot.plant_model("position")
    model.actuator_gainprm[:, 0] = STAND_KP
    model.actuator_biasprm[:, 1] = -STAND_KP
    model.actuator_biasprm[:, 2] = -STAND_KD
    if gravity is not None:
        model.opt.gravity[:] = gravity
    return SimBackend(robot, "position", envs=envs, seed=seed, models=[model] * envs)


def run(plant, ticks, command=None, each=None):
    """Hold the home pose (or ``command``) for ``ticks`` control ticks; ``each(k, frame)`` is
    called with every frame read."""
    target = np.tile(plant.robot.home if command is None else command, (plant.envs, 1))
    for k in range(ticks):
        frame = plant.read()
        if each is not None:
            each(k, frame)
        plant.write(target)
        plant.advance()


def angle_between(a, b) -> np.ndarray:
    """Angle (rad) between unit vectors, (...,)."""
    return np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0))


# ---------------------------------------------------------------- part 1: the floating base
def test_go2_loads_with_a_free_flyer_base_and_feet_that_agree_with_mujoco(go2):
    assert go2.floating_base and go2.n_joints == 12 and go2.n_feet == 4
    assert go2.foot_sites == ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
    assert go2.pin_model.joints[1].shortname() == "JointModelFreeFlyer"
    assert go2.mj_model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    np.testing.assert_allclose(go2.effort_limit[:3], [23.7, 23.7, 45.43])  # GO-M8010-6, knee
    # random base poses: feet (world) and joint gravity torques as the loader checks them
    rng = np.random.default_rng(5)
    m, d = go2.mj_model, mujoco.MjData(go2.mj_model)
    pdata = go2.pin_model.createData()
    for _ in range(20):
        q = rng.uniform(go2.position_lower, go2.position_upper)
        pos, quat = rng.uniform(-2, 2, 3), rng.standard_normal(4)
        quat /= np.linalg.norm(quat)
        d.qpos[:] = np.concatenate([pos, quat, q])
        mujoco.mj_forward(m, d)
        feet = go2.foot_positions(q, pos, quat)
        np.testing.assert_allclose(feet, d.site_xpos[list(go2.foot_site_ids)], atol=1e-9)
        g = pin.computeGeneralizedGravity(go2.pin_model, pdata, go2.pin_configuration(q, pos, quat))
        np.testing.assert_allclose(g[6:], d.qfrc_bias[6:], atol=1e-9)
    # arms keep a fixed base
    arm = load_robot("arm3")
    assert not arm.floating_base and arm.n_feet == 0 and arm.qpos_offset == 0


@pytest.mark.parametrize(
    "edit,what",
    [
        (lambda spec: setattr(spec.body("FL_calf"), "mass", 0.3), r"gravity torque [1-9]"),
        (
            lambda spec: setattr(spec.site("RR_foot"), "pos", [0.0, 0.0, -0.2]),
            r"positions 0\.0[1-9]",
        ),
    ],
    ids=["calf-mass", "foot-site"],
)
def test_the_agreement_check_covers_the_feet_and_the_base(go2, edit, what):
    """A MuJoCo model that differs from Pinocchio's in one leg (a calf's mass, a foot site) is
    caught at random base poses: the check the loader runs on every floating-base robot."""
    from sim2real.robots.crosscheck import check_agreement

    spec = mujoco.MjSpec.from_file(str(go2.mjcf_path))
    edit(spec)
    sites, frames = list(go2.foot_site_ids), list(go2.foot_frame_ids)
    args = (go2.pin_model, sites, frames, go2.position_lower, go2.position_upper, True)
    check_agreement(go2.mjcf_path, go2.mj_model, *args)  # the shipped model agrees
    with pytest.raises(RobotSpecError, match=r"disagree \(end-effector and foot .*" + what):
        check_agreement(go2.mjcf_path, spec.compile(), *args)


def test_free_joint_without_base_table_is_refused(tmp_path):
    shutil.copytree(ROBOTS_DIR / "go2", tmp_path / "go2")
    toml = tmp_path / "go2" / "robot.toml"
    toml.write_text(toml.read_text().split("[base]")[0])
    with pytest.raises(RobotSpecError, match=r"safety\.end_effector_site is required"):
        load_robot(toml)


# ---------------------------------------------------------------- part 3: IMU and contacts
def test_imu_white_noise_and_bias_walk_match_their_settings(go2):
    """On a standing robot, reading - true value = bias + white noise: the noise's sigma from
    successive differences (var = 2 sigma^2 + walk^2 dt) and the walk from 1 s differences
    (var = 2 sigma^2 + walk^2 50 dt) match the configured values within 3 standard errors."""
    envs = 2
    plant = stand_plant(go2, envs=envs, seed=11)
    sensors = plant.base_sensors
    sigma = {"gyro": 0.05, "accel": 0.3}
    walk = {"gyro": 0.05, "accel": 0.3}  # larger than the default, to be measured in 60 s
    sensors.gyro_noise_sigma[:], sensors.accel_noise_sigma[:] = sigma["gyro"], sigma["accel"]
    sensors.gyro_bias_walk[:], sensors.accel_bias_walk[:] = walk["gyro"], walk["accel"]
    plant.reset()
    run(plant, SETTLE)
    ticks, errors = 3000, []

    def record(k, frame):
        truth = sensors.true_imu()  # the sensors MuJoCo computed for this frame's reading
        errors.append(
            np.concatenate([frame.imu_angular_velocity, frame.imu_acceleration], axis=1) - truth
        )

    run(plant, ticks, each=record)
    err = np.array(errors)  # (ticks, envs, 6)
    dt = go2.control_period
    for name, axes in (("gyro", slice(0, 3)), ("accel", slice(3, 6))):
        e = err[:, :, axes].reshape(ticks, -1)
        d1 = np.diff(e, axis=0).ravel()
        d50 = (e[50::50] - e[:-50:50]).ravel()
        s2, w2 = sigma[name] ** 2, walk[name] ** 2
        var1 = 2 * s2 + w2 * dt
        var50 = 2 * s2 + w2 * 50 * dt
        assert abs(np.var(d1) / var1 - 1) < 3 * np.sqrt(2 / d1.size), name
        assert abs(np.var(d50) / var50 - 1) < 3 * np.sqrt(2 / d50.size), name


def test_the_imus_own_attitude_and_the_drives_velocity_have_their_configured_errors(
    go2_true_heading,
):
    """The IMU's own attitude (``orientation_sigma``, ``orientation_tau``) errs from the true
    attitude by roll and pitch errors of that spread and correlation time (a Gauss-Markov
    process: its 1 s autocorrelation exp(-1 / tau)), never in yaw without a heading drift
    (``heading_rate_sigma``: tests/test_imu_attitude_anchor.py); the drives' joint velocity
    reading errs by white noise of ``velocity_noise_sigma``. An arm's frame has neither."""
    from sim2real.deploy.core.attitude import quat_multiply

    go2 = go2_true_heading

    envs = 4
    plant = stand_plant(go2, envs=envs, seed=12)
    sensors = plant.base_sensors
    sigma, tau = go2.config.sensors.imu.orientation_sigma, go2.config.sensors.imu.orientation_tau
    run(plant, SETTLE)
    site = go2.mj_model.site_quat[go2.imu_site_id]
    errors, velocity = [], []

    def record(k, frame):
        true = quat_multiply(plant.true_base_state()[:, 3:7], np.tile(site, (envs, 1)))
        # the reading's rotation from the truth, world frame: R_read R_true^T
        rel = quaternion_to_matrix(frame.imu_orientation) @ quaternion_to_matrix(true).transpose(
            0, 2, 1
        )
        errors.append(np.stack([rel[:, 2, 1], rel[:, 0, 2], rel[:, 1, 0]], axis=1))  # small
        velocity.append(frame.velocity - plant.true_velocity())

    run(plant, 3000, each=record)
    err = np.array(errors)  # (ticks, envs, 3): roll, pitch, yaw about the world's axes
    assert np.abs(err[:, :, 2]).max() < 0.05 * sigma  # no yaw (second order of roll x pitch)
    spread = err[:, :, :2].std()
    assert abs(spread / sigma - 1) < 0.2, spread
    lag = int(round(1.0 / go2.control_period))
    a, b = err[:-lag, :, :2].ravel(), err[lag:, :, :2].ravel()
    assert abs(np.corrcoef(a, b)[0, 1] - np.exp(-1.0 / tau)) < 0.12
    noise = np.array(velocity)
    assert abs(noise.std() / go2.config.sensors.velocity_noise_sigma - 1) < 0.05
    assert sensors.has_orientation
    arm = SimBackend(load_robot("arm3"), "position")
    assert arm.read().imu_orientation is None and np.isnan(arm.read().velocity).all()


def test_foot_contacts_on_the_floor_and_in_the_air(go2):
    plant = stand_plant(go2, seed=2)
    run(plant, SETTLE)
    frame = plant.read()
    assert frame.foot_contact.all()
    assert np.allclose(frame.foot_force.sum(), 9.81 * go2.mj_model.body_subtreemass[0], rtol=0.2)
    # lift the robot 0.3 m: no contact while it falls (about 0.25 s), all four after landing
    d = plant.datas[0]
    d.qpos[2] += 0.3
    d.qvel[:] = 0.0
    mujoco.mj_forward(plant.models[0], d)
    seen = []
    run(plant, 60, each=lambda k, f: seen.append(f.foot_contact[0].copy()))
    seen = np.array(seen)
    assert not seen[1:8].any()
    assert seen[-10:].all()


def test_imu_settings_are_randomized_per_session(go2):
    from sim2real.eval.world.sensors import ImuRanges, apply_imu, sample_imu
    from sim2real.eval.world.session_draw import session_rng

    plant = stand_plant(go2, envs=2)
    draws = [sample_imu(go2, session_rng(s, "imu")) for s in (1, 2)]
    ranges = ImuRanges()
    for e, draw in enumerate(draws):
        assert ranges.gyro_noise_sigma[0] <= draw.gyro_noise_sigma <= ranges.gyro_noise_sigma[1]
        apply_imu(plant, e, draw)
        assert plant.base_sensors.accel_noise_sigma[e] == draw.accel_noise_sigma
    assert draws[0] != draws[1]
    with pytest.raises(ValueError, match="no IMU"):
        sample_imu(load_robot("arm3"), session_rng(1, "imu"))


# ---------------------------------------------------------------- part 4: base estimation
def estimate(plant, ticks, push=None, estimator=BaseStateEstimator, envs_check=None):
    """Run the joint and base estimators on ``plant`` (already settled) for ``ticks`` ticks;
    ``push(k) -> force`` (N, world) on the base. Returns per tick: estimated and true projected
    gravity, estimated and true base velocity (base frame), and the estimator."""
    robot = plant.robot
    joints = JointStateEstimator(robot, plant.envs)
    base = estimator(robot, plant.envs)
    frame = plant.read()
    joints.reset(plant.true_position(), frame.time)
    base.reset(frame.time, frame.imu_acceleration, orientation=frame.imu_orientation)
    state = RobotState.zeros(plant.envs, robot.n_joints)
    rows = []

    def each(k, f):
        joints.update(f, state)
        est = base.update(f, state.q, state.dq)
        truth = plant.true_base_state()
        rot = quaternion_to_matrix(truth[:, 3:7])
        v_true = np.einsum("eji,ej->ei", rot, truth[:, 7:10])
        rows.append(
            (
                est.projected_gravity.copy(),
                projected_gravity(truth[:, 3:7]),
                est.linear_velocity.copy(),
                v_true,
                est.tilt.copy(),
            )
        )
        if push is not None:
            plant.set_external_force(0, push(k))

    run(plant, ticks, each=each)
    return [np.array(x) for x in zip(*rows, strict=True)], base


@pytest.mark.parametrize("tilt_deg", [0.0, 15.0])
def test_projected_gravity_within_2_5_degrees_standing_and_tilted(go2, tilt_deg):
    """Under the default noise model (bias included); tilted: standing on a 15 degree slope
    (gravity turned about the x axis). Mostly the turn-on gyro bias over ``MAHONY_K_P`` until the
    integral term learns it: 1.7-1.8 degrees with ahrs's gains (1, 0.3), 2.1-2.2 with ours
    (0.3, 0.03), within legged_gym's noise on the projected gravity (+-0.05, about 2.9 deg)."""
    a = np.radians(tilt_deg)
    plant = stand_plant(go2, seed=4, gravity=9.81 * np.array([0.0, np.sin(a), -np.cos(a)]))
    run(plant, SETTLE)
    (g_est, _, _, _, tilt), base = estimate(plant, 500)
    g_slope = np.array([0.0, np.sin(a), -np.cos(a)])  # gravity's direction, world frame
    rot = quaternion_to_matrix(plant.true_base_state()[0, 3:7])  # at rest: the last pose
    expected = rot.T @ g_slope
    errors = np.degrees(angle_between(g_est[100:, 0], expected))
    assert errors.max() < 2.5, errors.max()
    assert abs(np.degrees(tilt[-1, 0]) - np.degrees(np.arccos(-expected[2]))) < 2.5
    assert base.missing_readings[0] == 0


def test_base_velocity_follows_a_pushed_base(go2):
    """A 100 N sideways push for 0.2 s sways the standing robot (up to about 0.3 m/s): the
    kinematic-inertial filter tracks the base velocity within 0.1 m/s RMS."""
    plant = stand_plant(go2, seed=6)
    run(plant, SETTLE)
    force = np.array([0.0, 100.0, 0.0])
    (_, _, v_est, v_true, _), base = estimate(
        plant, 150, push=lambda k: force if 20 <= k < 30 else np.zeros(3)
    )
    assert np.abs(v_true[:, 0, 1]).max() > 0.15
    rms = np.sqrt(np.mean((v_est - v_true)[:, 0, :2] ** 2))
    assert rms < 0.1, rms
    assert base.velocity_updates[0] > 100


def test_pushed_over_robot_shows_the_fall_in_its_tilt(go2):
    plant = stand_plant(go2, seed=8)
    run(plant, SETTLE)
    force = np.array([0.0, 300.0, 0.0])
    (_, _, _, _, tilt), _ = estimate(
        plant, 150, push=lambda k: force if 10 <= k < 30 else np.zeros(3)
    )
    assert np.degrees(tilt[:10, 0]).max() < 5.0
    assert np.degrees(tilt[-1, 0]) > 60.0  # on its side or back


def test_velocity_filter_equals_filterpy_reference_with_imu_dropout(go2):
    results = []
    for estimator in (BaseStateEstimator, ReferenceBaseStateEstimator):
        plant = stand_plant(go2, seed=9)
        plant.base_sensors.imu_dropout[:] = 0.2
        run(plant, 20)
        force = np.array([60.0, 0.0, 0.0])
        (g, _, v, _, _), base = estimate(
            plant,
            100,
            push=lambda k, force=force: force if k < 10 else np.zeros(3),
            estimator=estimator,
        )
        results.append((g, v, base.velocity_variance.copy(), base.missing_readings.copy()))
    (g0, v0, p0, m0), (g1, v1, p1, m1) = results
    assert m0[0] > 10 and m0[0] == m1[0]  # dropouts happened, identically
    np.testing.assert_allclose(v0, v1, atol=1e-9)
    np.testing.assert_allclose(p0, p1, atol=1e-12)
    np.testing.assert_allclose(g0, g1, atol=1e-12)


def test_the_attitude_starts_from_the_accelerometer_only_at_rest(go2):
    """At rest the accelerometer reads gravity: the initial roll and pitch follow it. A robot
    dropped onto its feet reads something else (here 0.6 g, 17 degrees off): it starts upright
    instead of at a tilt that is not there."""
    base = BaseStateEstimator(go2, 2)
    a = np.radians(10.0)
    at_rest = 9.81 * np.array([0.0, np.sin(a), np.cos(a)])  # tilted 10 degrees, at rest
    dropped = 0.6 * 9.81 * np.array([0.0, np.sin(0.3), np.cos(0.3)])
    # the readings are in the IMU frame: turn the base-frame vectors into it
    imu_to_base = quaternion_to_matrix(go2.mj_model.site_quat[go2.imu_site_id])
    base.reset(0.0, np.stack([imu_to_base.T @ at_rest, imu_to_base.T @ dropped]))
    tilt = tilt_of(projected_gravity(base.orientation))
    assert np.degrees(tilt[0]) == pytest.approx(10.0, abs=1e-6)
    assert tilt[1] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("estimator", [BaseStateEstimator, ReferenceBaseStateEstimator])
def test_a_steady_turn_at_speed_is_not_taken_for_a_tilt(go2, estimator):
    """An upright base driving a circle (1 m/s, turning 0.5 rad/s) feels a steady sideways
    specific force ``omega x v`` of 0.5 m/s^2. Taken for gravity it puts the roll estimate
    0.05 rad off, and the gyro bias estimate with it (a turning walk threw a G1's policy); the
    estimator takes the term off and stays upright. Readings exact, no foot contact."""
    from sim2real.deploy.core.backend import SensorFrame

    base = estimator(go2, 1)
    imu_to_base = quaternion_to_matrix(go2.mj_model.site_quat[go2.imu_site_id])
    omega, speed, dt = 0.5, 1.0, go2.control_period
    gyro_b = np.array([0.0, 0.0, omega])
    acc_b = np.array([0.0, omega * speed, 9.81])  # omega x v, less gravity, in the base frame
    base.reset(0.0)
    state = base.state_dict()
    state["velocity"] = np.array([[speed, 0.0, 0.0]])  # heading along x at the start
    base.load_state_dict(state)
    frame = SensorFrame.empty(1, go2.n_joints, len(go2.foot_frame_ids))
    frame.imu_angular_velocity[0] = imu_to_base.T @ gyro_b
    frame.imu_acceleration[0] = imu_to_base.T @ acc_b
    q, dq = go2.home[None].copy(), np.zeros((1, go2.n_joints))
    for k in range(1, int(20.0 / dt) + 1):
        frame.time[0] = frame.imu_stamp[0] = k * dt
        est = base.update(frame, q, dq)
    np.testing.assert_allclose(est.projected_gravity[0], [0.0, 0.0, -1.0], atol=0.01)
    np.testing.assert_allclose(est.angular_velocity[0], gyro_b, atol=5e-3)


@pytest.mark.parametrize("estimator", [BaseStateEstimator, ReferenceBaseStateEstimator])
def test_a_base_rocking_about_its_origin_does_not_move_an_imu_above_it(estimator):
    """The H1-2's IMU is 0.28 m above its base's origin: a base pitching about that origin
    from rest (0 to 0.2 rad at 1 Hz, as a humanoid rocks catching a push) carries the IMU back
    and forth, its tangential acceleration ``alpha x r`` up to 1.1 m/s^2. The origin does not move: the
    estimate stays within 0.05 m/s of rest. Taking off only the centripetal term, the estimate
    swung with the IMU's own velocity change, ``(omega - omega_0) x r``, 0.17 m/s. Readings
    exact, no foot contact, no attitude from the IMU."""
    from sim2real.deploy.core.backend import SensorFrame

    robot = load_robot("h1_2")
    base = estimator(robot, 1)
    r = base.lever_arm
    assert np.linalg.norm(r) > 0.25
    imu_to_base = quaternion_to_matrix(robot.mj_model.site_quat[robot.imu_site_id])
    amplitude, w, dt = 0.1, 2 * np.pi, robot.control_period
    base.reset(0.0)
    frame = SensorFrame.empty(1, robot.n_joints, len(robot.foot_frame_ids))
    q, dq = robot.home[None].copy(), np.zeros((1, robot.n_joints))
    speeds = []
    for k in range(1, int(3.0 / dt) + 1):
        t = k * dt
        pitch = amplitude * (1.0 - np.cos(w * t))
        omega = np.array([0.0, amplitude * w * np.sin(w * t), 0.0])
        alpha = np.array([0.0, amplitude * w * w * np.cos(w * t), 0.0])
        rot = np.array(
            [[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]]
        )
        specific = np.cross(alpha, r) + np.cross(omega, np.cross(omega, r)) + rot.T @ [0, 0, 9.81]
        frame.time[0] = frame.imu_stamp[0] = t
        frame.imu_angular_velocity[0] = imu_to_base.T @ omega
        frame.imu_acceleration[0] = imu_to_base.T @ specific
        est = base.update(frame, q, dq)
        speeds.append(np.linalg.norm(est.linear_velocity_world[0]))
    assert max(speeds) < 0.05, max(speeds)
