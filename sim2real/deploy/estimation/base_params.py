"""The base estimator's constants and what it reads from a robot: the filter's tuning (each
constant's source beside it), the feet's contact radii (spheres and wheels), the floating-base check, and the
constants of the compiled tick packed into one array (:func:`packed_constants`, the layout of
:mod:`sim2real.deploy.estimation.base_tick`). The filter itself is
:class:`sim2real.deploy.estimation.base.BaseStateEstimator`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from sim2real.deploy.estimation import base_tick as bt
from sim2real.robots import Robot

#: Leg odometry noise, m/s per foot (our choice): foot roll and micro-slip, and the joint velocity
#: estimate's noise through the leg Jacobian (about 0.3 m/rad). Tried 0.05, 0.15 and 0.2 on the
#: go2, h1 and h1_2 walking (``python -m bench.estimation``).
LEG_VELOCITY_SIGMA = 0.1
#: Unmodelled acceleration, m/s^2, added to the accelerometer's white noise in the prediction
#: (our choice): the lever arm's angular-acceleration term and a reading sampled once a tick
#: (tried 1.5 and 3: the tilt follows the legs' errors).
UNMODELLED_ACCELERATION = 0.5
#: The accelerometer as a gravity measurement, m/s^2 (our choice): a walking base's own
#: acceleration, which averages out over a gait cycle (tried 0.5 and 1: 0.5 deg more tilt error).
ACCEL_MEASUREMENT_SIGMA = 2.0
#: Chi-square bound (3 dof, p about 0.03) past which a foot's velocity reading is a slip (tried
#: 6 and 16 on the go2, h1 and h1_2 over seeds 0-2: 16 let the Go2's sliding rear feet read it 5-7 %
#: slow).
SLIP_GATE = 9.0
#: Readings in a row without an absorbed foot after which the gate opens (our choice: 0.1 s at 50
#: Hz; a prediction that drifted must not lock every foot out).
MAX_REJECTED_READINGS = 5
#: The IMU's own attitude as a measurement: its ``orientation_sigma`` times this factor (our
#: choice: its error is correlated over ``orientation_tau``, so one reading a tick is not
#: independent of the last), at least ``MIN_ATTITUDE_SIGMA`` rad.
ATTITUDE_SIGMA_FACTOR = 3.0
MIN_ATTITUDE_SIGMA = 0.002
#: s a foot's force reading may stay the same before its sensor is taken for dead (our choice:
#: a live sensor's noise changes every reading; a Go2 with a dead foot sensor, and Unitree's
#: simulation bridge, report a constant, often 0). Latched until :meth:`reset`.
DEAD_FOOT_TIME = 1.0
#: m, a foot whose sensor is dead is in contact when it is this close to the lowest foot, by
#: the leg kinematics in the gravity frame (our choice: a trot lifts its swing feet 5-8 cm).
KINEMATIC_CONTACT_BAND = 0.02
#: Initial standard deviations (our choice: a robot reset at rest on level ground): roll and
#: pitch rad, yaw rad (unobserved, kept small), velocity m/s.
INITIAL_TILT_SIGMA = 0.02
INITIAL_YAW_SIGMA = 1e-3
INITIAL_VELOCITY_SIGMA = 0.1
#: An accelerometer reading within this fraction of gravity's magnitude is taken as the robot at
#: rest when the filter starts (our choice: 10 %, about 6 times the seed's largest accelerometer
#: noise, 0.1 m/s^2 x bias). Dropped onto its feet at the start of a soak session, a Go2 read
#: a specific force that put its initial tilt estimate at 0.29 rad (true 0.006): the policy
#: answered a tilt that was not there and fell within 0.5 s.
REST_ACCELERATION_TOLERANCE = 0.1
#: Floor of the gyro bias walk and bias sigma, rad/s (/sqrt(s)): a robot.toml with a perfect
#: gyro still lets the filter learn a bias (our choice).
MIN_GYRO_BIAS_WALK = 1e-5
MIN_GYRO_BIAS_SIGMA = 1e-3
#: The same floors for the accelerometer's bias, m/s^2 (/sqrt(s)) (our choice).
MIN_ACCEL_BIAS_WALK = 1e-4
MIN_ACCEL_BIAS_SIGMA = 0.01


def foot_radii(robot: Robot) -> np.ndarray:
    """(n_feet,) m: each foot's contact radius, the distance from its foot site to the ground
    beneath: a sphere geom centred on the site (the importer's and example-robot-data's point
    feet), or a wheel's rolling radius (:func:`wheel_radius`) where the site's body turns on a
    velocity-driven joint (robot.toml ``drive = "velocity"``, :attr:`Robot.velocity_driven`) about
    an axis through the site; 0 where the foot is neither.

    A foot so described rolls: the estimator takes its contact point, ``radius`` below the
    site along the world's down, as the point at rest (the wheel's spin is in the site's angular
    velocity; a wheel leaning by a camber angle has its contact point in its own plane, so its
    rolling speed is read short by the camber's cosine), and the fall check measures the base's
    height to it.
    """
    m = robot.mj_model
    driven = robot.velocity_driven
    out = np.zeros(len(robot.foot_site_ids))
    for i, s in enumerate(robot.foot_site_ids):
        body = m.site_bodyid[s]
        for j in range(m.body_jntadr[body], m.body_jntadr[body] + m.body_jntnum[body]):
            name = m.joint(j).name
            if name in robot.joint_names and driven[robot.joint_names.index(name)]:
                out[i] = wheel_radius(robot, j, s)
        for g in range(m.ngeom):
            if (
                m.geom_bodyid[g] == body
                and m.geom_type[g] == 2  # mjGEOM_SPHERE
                and np.allclose(m.geom_pos[g], m.site_pos[s], atol=1e-6)
            ):
                out[i] = float(m.geom_size[g, 0])
    return out


def wheel_radius(robot: Robot, joint: int, site: int) -> float:
    """m: the rolling radius of the wheel that MuJoCo joint ``joint`` turns, the farthest point
    of its body's collision geoms (mesh vertices, a sphere's, a cylinder's or a capsule's rim
    with its axis along the joint's) from the joint's axis (MJCF).

    Raises:
        ValueError: the axis does not pass through foot site ``site``, the body has no
            collision geom, or one of another shape (``robot <name>: wheel joint <joint>: ...``).
    """
    m = robot.mj_model
    body, where = m.jnt_bodyid[joint], f"robot {robot.name}: wheel joint {m.joint(joint).name}"
    anchor, axis = m.jnt_pos[joint], m.jnt_axis[joint] / np.linalg.norm(m.jnt_axis[joint])
    off = m.site_pos[site] - anchor
    if np.linalg.norm(off - (off @ axis) * axis) > 1e-6:
        raise ValueError(f"{where}: its axis does not pass through foot site {m.site(site).name}")
    radius = 0.0
    for g in np.flatnonzero((m.geom_bodyid == body) & ((m.geom_contype | m.geom_conaffinity) > 0)):
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, m.geom_quat[g])
        rot = rot.reshape(3, 3)
        kind, size = int(m.geom_type[g]), m.geom_size[g]
        if kind == mujoco.mjtGeom.mjGEOM_MESH:
            v0, n = m.mesh_vertadr[m.geom_dataid[g]], m.mesh_vertnum[m.geom_dataid[g]]
            points, rim = m.geom_pos[g] + m.mesh_vert[v0 : v0 + n] @ rot.T, 0.0
        elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
            points, rim = m.geom_pos[g][None], float(size[0])
        elif kind in (mujoco.mjtGeom.mjGEOM_CYLINDER, mujoco.mjtGeom.mjGEOM_CAPSULE) and (
            abs(abs(rot[:, 2] @ axis) - 1.0) < 1e-6
        ):
            points, rim = m.geom_pos[g][None], float(size[0])
        else:
            raise ValueError(
                f"{where}: collision geom {m.geom(g).name} is no mesh, sphere or "
                "cylinder about the axis"
            )
        rel = points - anchor
        radial = rel - np.outer(rel @ axis, axis)
        radius = max(radius, float(np.linalg.norm(radial, axis=1).max()) + rim)
    if radius == 0.0:
        raise ValueError(f"{where}: its body has no collision geom")
    return radius


def require_floating_base(robot: Robot, stage: str) -> None:
    """Refuse a fixed-base ``robot`` for a base stage (the runtime builds them for a legged robot
    kind only, :meth:`sim2real.deploy.robot_kind.RobotKind.base_stages`); ``stage`` names what the
    stage does, for the message.

    Raises:
        ValueError: ``robot`` has no floating base (``robot <name>: <stage> needs a floating
            base``).
    """
    if not robot.floating_base:
        raise ValueError(f"robot {robot.name}: {stage} needs a floating base")


def packed_constants(est) -> np.ndarray:
    """(``base_tick.P_RADII`` + n_feet,) float64: the constants of ``est`` (a
    :class:`~sim2real.deploy.estimation.base.BaseStateEstimator`) in the layout of
    :mod:`sim2real.deploy.estimation.base_tick` (``P_*``); the attitude variance NaN where the
    IMU sends no attitude."""
    p = np.empty(bt.P_RADII + len(est.radii))
    p[bt.P_GYRO], p[bt.P_ACCEL] = est.gyro_variance, est.accel_variance
    p[bt.P_WALK], p[bt.P_ACCEL_WALK] = est.bias_walk_variance, est.accel_bias_walk_variance
    p[bt.P_ACCEL_MEAS], p[bt.P_REST] = est.accel_meas_variance, 3 * REST_ACCELERATION_TOLERANCE
    p[bt.P_LEG], p[bt.P_GATE] = est.leg_variance, est.slip_gate
    p[bt.P_ATTITUDE] = np.nan if est.attitude_variance is None else est.attitude_variance
    p[bt.P_GAP] = 2.5 * est.robot.control_period
    p[bt.P_DEAD_TIME], p[bt.P_BAND] = DEAD_FOOT_TIME, KINEMATIC_CONTACT_BAND
    p[bt.P_RESTART], p[bt.P_MAX_RUN] = INITIAL_VELOCITY_SIGMA**2, MAX_REJECTED_READINGS
    p[bt.P_LEVER : bt.P_GRAVITY] = est.lever_arm
    p[bt.P_GRAVITY : bt.P_IMU] = est.gravity
    p[bt.P_IMU : bt.P_RADII] = est.imu_to_base.ravel()
    p[bt.P_RADII :] = est.radii
    return p
