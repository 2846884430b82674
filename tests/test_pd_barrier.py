"""A PD target judged by its consequence (sim2real/deploy/safety/pd_barrier.py), and a plant whose
drives are the robot's: a legged robot's target past its joint's range passes while the joint's
predicted motion is safe, is changed as little as keeps it off the hard limit when not; the
compiled check equals its numpy reference; the plant's position actuators do not clamp a Unitree
motor's target, and still clamp an arm's servo's."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.safety import pd_barrier as pb
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.deploy.safety.reference import ReferenceGuard
from sim2real.robots import load_robot

GUARDS = pytest.mark.parametrize(
    "guard_type", [SafetyGuard, ReferenceGuard], ids=["compiled", "reference"]
)


def _state(robot, envs, q, dq=None):
    state = RobotState.legged(envs, robot.n_joints, robot.n_feet, 25.0)
    state.q[:] = q
    if dq is not None:
        state.dq[:] = dq
    return state


@GUARDS
def test_a_pd_target_past_the_range_passes_when_its_motion_is_safe(go2, guard_type):
    """legged_gym-style: the hip roll at home, at rest, asked for a target 0.4 rad past its range
    (a torque request, ``kp (target - q)``): its motion over the next period stays far from the
    stop, so the target reaches the drive unchanged and nothing is counted."""
    guard = guard_type(go2, 1, "position")
    state = _state(go2, 1, go2.home)
    guard.reset(state.q)
    target = np.tile(go2.home, (1, 1))
    hip = go2.joint_names.index("FL_hip_joint")
    target[0, hip] = go2.position_upper[hip] + 0.4
    calf = go2.joint_names.index("FL_calf_joint")
    target[0, calf] = go2.position_lower[calf] - 0.3
    out = guard.filter(target, state, out=np.empty_like(target))
    np.testing.assert_array_equal(out, target)
    assert guard.totals()["pd_barrier"] == 0 and guard.totals()["soft_limit"] == 0
    assert not guard.hard_violation.any()


@GUARDS
def test_a_loaded_knee_pushing_its_foot_into_the_ground_is_judged_as_lifting_the_body(
    go2, guard_type
):
    """A Go2 rear knee climbing a step (stairs up, HIMLoco's policy): its foot in stance, the
    knee at rest 0.15 rad short of its extension stop, asked for a target 0.3 rad past it (the
    push that lifts the body onto the step). Extension drives that foot into the ground, so on
    a loaded foot the barrier judges the knee with the heavier inertia only: the target passes
    further than with the leg in the air (the least inertia, where it must hold the knee off the
    stop), and still off the stop in a plant whose knee is that heavy. A humanoid's ankle roll,
    whose foot rolls on its edge as it lifts off, presses nothing: judged as before."""
    press = pb.pressing_joints(go2)
    knees = [j for j, name in enumerate(go2.joint_names) if name.endswith("calf_joint")]
    assert press[0, knees].all() and not press[1, knees].any()  # extension: the upper limit
    assert not pb.pressing_joints(load_robot("h1_2")).any()
    knee = go2.joint_names.index("RR_calf_joint")
    q = go2.home.copy()
    q[knee] = go2.position_upper[knee] - 0.15
    target = np.tile(q, (1, 1))
    target[0, knee] = go2.position_upper[knee] + 0.3
    outs = {}
    for loaded in (False, True):
        guard = guard_type(go2, 1, "position")
        state = _state(go2, 1, q)
        state.foot_contact[:] = 1.0 if loaded else 0.0
        guard.reset(state.q)
        outs[loaded] = guard.filter(target, state, out=np.empty_like(target))[0, knee]
    assert outs[False] < target[0, knee]  # in the air: held off the stop
    assert outs[True] > outs[False]  # loaded: the push lifts the body, judged so
    extra = (pb.INERTIA_SPREAD - 1.0) * pb.least_inertia(go2)[knee]
    peak = _swing_peak(go2, q, np.zeros(go2.n_joints), knee, outs[True], armature=extra)
    assert peak < go2.position_upper[knee], peak


@GUARDS
def test_a_pd_target_that_would_reach_the_hard_limit_is_changed_minimally(go2, guard_type):
    """The hip roll 0.08 rad short of its upper limit and swinging toward it at 6 rad/s, asked
    for a target past the range: under its drive's PD law it would reach the stop within the
    period. The target is lowered to the largest one whose predicted motion is safe (a hair more
    is not), far above the soft limit an arm's clamp would give; the other joints are untouched,
    and the env counts one ``pd_barrier`` intervention."""
    guard = guard_type(go2, 1, "position")
    hip = go2.joint_names.index("FL_hip_joint")
    q = go2.home.copy()
    q[hip] = go2.position_upper[hip] - 0.08
    dq = np.zeros(go2.n_joints)
    dq[hip] = 6.0
    state = _state(go2, 1, q, dq)
    guard.reset(state.q)
    target = np.tile(go2.home, (1, 1))
    target[0, hip] = go2.position_upper[hip] + 0.5
    out = guard.filter(target.copy(), state, out=np.empty_like(target))
    others = np.arange(go2.n_joints) != hip
    np.testing.assert_array_equal(out[0, others], target[0, others])
    assert out[0, hip] < target[0, hip]
    assert guard.totals()["pd_barrier"] == 1 and guard.totals()["soft_limit"] == 0

    c = pb.pd_barrier_constants(guard)
    effort = go2.effort_limit * guard.effort_scale
    hi = np.maximum(c[pb.BOUND_UP], q)
    d = c[pb.TOWARD]  # env 0's gravity torque toward the upper limits
    brake = np.maximum((effort - d) * c[pb.BRAKE], 0.0) * c[pb.INV_INERTIA]

    def unsafe(t):  # the foot in the air: the least inertia alone
        full = np.tile(go2.home, (1, 1))
        full[0, hip] = t
        u = pb._unsafe_np(full, q[None], dq[None], hi, d, c, effort, brake, c[pb.INV_INERTIA])
        return bool(u[0, hip])

    assert unsafe(target[0, hip]) and not unsafe(out[0, hip])
    assert unsafe(out[0, hip] + 1e-6)  # the least change: a hair more is unsafe
    # the joint's own motion under the changed target in MuJoCo, the leg in the air: it stays
    # off the hard limit, where the raw target carried it past within the period
    assert _swing_peak(go2, q, dq, hip, out[0, hip]) < go2.position_upper[hip]
    assert _swing_peak(go2, q, dq, hip, target[0, hip]) > go2.position_upper[hip] - 1e-3


@GUARDS
@pytest.mark.parametrize("heavier", [1.0, 2.5], ids=["free foot", "loaded foot"])
def test_a_foot_heavier_than_its_least_inertia_is_braked_off_the_stop(guard_type, heavier):
    """H1-2's ankle roll 0.04-0.06 rad short of its upper stop, rolling toward it at 4-6 rad/s,
    its foot in contact (the estimate's), its target 0.3 rad past the range (a recovery step's
    request). The foot in the plant is the free one or 2.5 times as heavy (a foot still rolling
    on its edge as it lifts off brakes worse than the free foot the barrier's least inertia
    describes): under the guard's target the joint stays off the hard limit over the period
    either way."""
    robot = load_robot("h1_2")
    j = robot.joint_names.index("left_ankle_roll_joint")
    extra = (heavier - 1.0) * pb.least_inertia(robot)[j]
    for gap in (0.04, 0.06):
        for speed in (4.0, 6.0):
            q = robot.home.copy()
            q[j] = robot.position_upper[j] - gap
            dq = np.zeros(robot.n_joints)
            dq[j] = speed
            guard = guard_type(robot, 1, "position")
            state = _state(robot, 1, q, dq)
            state.foot_contact[:] = 1.0  # the foot still touches as it rolls on its edge
            guard.reset(state.q)
            target = np.tile(robot.home, (1, 1))
            target[0, j] = robot.position_upper[j] + 0.3
            out = guard.filter(target, state, out=np.empty_like(target))
            peak = _swing_peak(robot, q, dq, j, out[0, j], armature=extra, height=2.0)
            assert peak < robot.position_upper[j], (gap, speed, peak)


def _swing_peak(robot, q, dq, joint, target, armature=0.0, height=1.0) -> float:
    """Highest angle (rad) of ``joint`` over one control period of the plant's position drives
    with the base held in the air (the free joint welded by zero gravity on it is not needed:
    the base is pinned by resetting it each substep), from ``q``, ``dq``, all other targets at
    ``q``; ``armature`` (kg m^2) added to the joint's in the plant, the base ``height`` m up."""
    m = robot.plant_model("position")
    m.dof_armature[m.jnt_dofadr[m.joint(robot.joint_names[joint]).id]] += armature
    d = mujoco.MjData(m)
    o, v = robot.qpos_offset, robot.qvel_offset
    d.qpos[2] = height
    d.qpos[3] = 1.0
    d.qpos[o:] = q
    d.qvel[v:] = dq
    d.ctrl[:] = q
    d.ctrl[joint] = target
    base = d.qpos[:o].copy()
    peak = q[joint]
    for _ in range(robot.decimation):
        mujoco.mj_step(m, d)
        d.qpos[:o], d.qvel[:v] = base, 0.0
        peak = max(peak, d.qpos[o + joint])
    return float(peak)


@pytest.mark.parametrize("name", ["go2", "h1_2"])
def test_the_compiled_barrier_equals_the_reference(name):
    """Random states in and around the joints' ranges, fast joints, tilted bases, targets spread
    about them, feet in contact or not: the compiled guard and the numpy reference give the same
    targets and counters bit for bit, and the barrier acts on a share of them (the test exercises both branches)."""
    robot = load_robot(name)
    envs = 16
    compiled, reference = (
        SafetyGuard(robot, envs, "position"),
        ReferenceGuard(robot, envs, "position"),
    )
    rng = np.random.default_rng(7)
    changed = 0
    for _ in range(20):
        q = rng.uniform(
            robot.position_lower - 0.05, robot.position_upper + 0.05, (envs, robot.n_joints)
        )
        state = _state(robot, envs, q, rng.normal(0.0, 8.0, q.shape))
        tilt = rng.normal(0.0, 0.3, (envs, 3)) + [0.0, 0.0, -1.0]  # bases tilted every way
        state.base.projected_gravity[:] = tilt / np.linalg.norm(tilt, axis=1, keepdims=True)
        state.foot_contact[:] = rng.integers(0, 2, state.foot_contact.shape)  # loaded or not
        target = q + rng.normal(0.0, 1.0, q.shape)
        a = compiled.filter(target, state, out=np.empty_like(target))
        b = reference.filter(target, state, out=np.empty_like(target))
        np.testing.assert_array_equal(a, b)
        changed += int((a != target).sum())
    np.testing.assert_array_equal(compiled.count_matrix, reference.count_matrix)
    assert 0 < changed < 20 * q.size


@pytest.mark.parametrize("name", ["go2", "h1_2"])
def test_the_rows_follow_the_estimate_as_the_fixed_base_gravity_turned_into_the_base(name):
    """Each tick's gravity rows are the fixed-base model's generalized gravity with gravity
    turned into the base frame (``-G`` toward the upper limit, ``G`` toward the lower, plus the
    slack, at most the bound), also for a base upside down; an env whose estimate is not finite
    keeps the bound; the loaded rows count the feet in contact whose chain holds each joint."""
    import pinocchio as pin

    robot = load_robot(name)
    envs = 6
    guard = SafetyGuard(robot, envs, "position")
    c = pb.pd_barrier_constants(guard)
    fixed = pin.Model(robot.fixed_base_model)
    data = fixed.createData()
    magnitude = np.linalg.norm(fixed.gravity.linear)
    chains = pb.foot_chains(robot)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(robot.position_lower, robot.position_upper, (envs, robot.n_joints))
        direction = rng.normal(size=(envs, 3))
        direction[0] = [0.0, 0.0, -1.0]  # upright
        direction[1] = [0.0, 0.0, 1.0]  # upside down
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        q[2, 3] = np.nan  # a joint estimate lost
        contact = rng.integers(0, 2, (envs, robot.n_feet)).astype(float)
        pb.barrier_rows(guard, q, direction, contact)
        for e in range(envs):
            fixed.gravity.linear = direction[e] * magnitude
            g = pin.computeGeneralizedGravity(fixed, data, q[e])
            up, down = c[pb.TOWARD + 2 * e], c[pb.TOWARD + 2 * e + 1]
            if e == 2:
                np.testing.assert_array_equal(up, c[pb.GRAVITY])
                np.testing.assert_array_equal(down, c[pb.GRAVITY])
            else:
                np.testing.assert_allclose(
                    up, np.minimum(c[pb.SLACK] - g, c[pb.GRAVITY]), atol=1e-9
                )
                np.testing.assert_allclose(
                    down, np.minimum(c[pb.SLACK] + g, c[pb.GRAVITY]), atol=1e-9
                )
        np.testing.assert_array_equal(c[pb.TOWARD + 2 * envs :], contact @ chains)
    pb.barrier_rows(guard, q, None, None)  # upright, no foot in contact
    assert not c[pb.TOWARD + 2 * envs :].any()


def test_an_arm_keeps_its_soft_limit_clamp(arm3):
    """An arm's servo clamps its targets: the soft-limit clamp as before, no barrier."""
    guard = SafetyGuard(arm3, 1, "position")
    state = RobotState.zeros(1, arm3.n_joints, 25.0)
    state.q[:] = arm3.home
    guard.reset(state.q)
    target = np.tile(arm3.home, (1, 1))
    target[0, 1] = arm3.soft_upper[1] + 0.05
    out = guard.filter(target, state, out=np.empty_like(target))
    assert out[0, 1] == arm3.soft_upper[1]
    assert guard.totals()["soft_limit"] == 1 and guard.totals()["pd_barrier"] == 0


@pytest.mark.parametrize("name", ["go2", "arm3", "so101"])
def test_the_plant_clamps_a_position_target_only_where_the_drive_does(name):
    """A target 0.5 rad past a joint's upper limit, the joint at home: a Unitree motor's PD law
    takes it (``kp (target - q)``, within the effort limit); an arm's servo clamps it to the
    range first."""
    robot = load_robot(name)
    m = robot.plant_model("position")
    d = mujoco.MjData(m)
    o, v = robot.qpos_offset, robot.qvel_offset
    if o:
        d.qpos[3] = 1.0
    d.qpos[o:] = robot.home
    d.ctrl[:] = robot.home
    j = 0
    d.ctrl[j] = robot.position_upper[j] + 0.5
    mujoco.mj_forward(m, d)
    kp = robot.config.joints[j].kp
    clamps = robot.clamps_position_target[j]
    assert clamps == (name != "go2")
    goal = robot.position_upper[j] if clamps else robot.position_upper[j] + 0.5
    expected = min(kp * (goal - robot.home[j]), robot.effort_limit[j])
    assert d.qfrc_actuator[v + j] == pytest.approx(expected, rel=1e-9)
    assert bool(m.actuator_ctrllimited[j]) == clamps
    # the joint's range stays a contact of the physics
    assert bool(m.jnt_limited[m.actuator_trnid[j, 0]])


#: A biped written the way mjlab's asset zoo writes its G1 (no actuators, a ``<default>`` class
#: tree with ``childclass`` on the root body, capsule feet, an IMU site and sensors), whose waist
#: carries an upper body with arms on a weak joint as the G1's does: the all-pose gravity bound
#: of the waist (its masses at their longest lever, the arms held out) is near its motor's 50 N m.
WAIST_BIPED = """<mujoco model="waist_biped">
  <compiler angle="radian"/>
  <default>
    <default class="robot">
      <joint damping="0.001" armature="0.01" frictionloss="0.1"/>
      <site group="5"/>
      <default class="collision">
        <geom type="capsule" priority="1" condim="6" group="3"/>
        <default class="foot_capsule"><geom size="0.01"/></default>
      </default>
    </default>
  </default>
  <worldbody>
    <body name="pelvis" pos="0 0 0.68" childclass="robot">
      <freejoint name="floating_base_joint"/>
      <inertial pos="0 0 0" mass="4" diaginertia="0.04 0.03 0.03"/>
      <geom name="pelvis_collision" class="collision" type="sphere" size="0.07"/>
      <site name="imu_in_pelvis" pos="0.04 0 -0.05"/>
      <body name="torso_link" pos="0 0 0.05">
        <inertial pos="0 0 0.15" mass="8" diaginertia="0.1 0.1 0.05"/>
        <joint name="waist_pitch_joint" axis="0 1 0" range="-0.52 0.52"/>
        <geom name="torso_collision" class="collision" type="capsule" size="0.09"
              fromto="0 0 0.08 0 0 0.3"/>
{arms}
      </body>
{legs}
    </body>
  </worldbody>
  <sensor>
    <gyro name="imu_ang_vel" site="imu_in_pelvis"/>
    <accelerometer name="imu_lin_acc" site="imu_in_pelvis"/>
  </sensor>
</mujoco>
"""
WAIST_ARM = """        <body name="{s}_shoulder_pitch_link" pos="0 {y} 0.35">
          <inertial pos="0 0 -0.2" mass="3.2" diaginertia="0.03 0.03 0.003"/>
          <joint name="{s}_shoulder_pitch_joint" axis="0 1 0" range="-3.0 2.6"/>
          <geom name="{s}_arm_collision" class="collision" size="0.03" fromto="0 0 -0.05 0 0 -0.4"/>
        </body>"""
WAIST_LEG = """      <body name="{s}_hip_pitch_link" pos="0 {y} -0.06">
        <inertial pos="0 0 -0.12" mass="2" diaginertia="0.02 0.02 0.003"/>
        <joint name="{s}_hip_pitch_joint" axis="0 1 0" range="-2.5 2.8"/>
        <body name="{s}_knee_link" pos="0 0 -0.28">
          <inertial pos="0 0 -0.12" mass="1.5" diaginertia="0.015 0.015 0.002"/>
          <joint name="{s}_knee_joint" axis="0 1 0" range="-0.08 2.9"/>
          <body name="{s}_ankle_pitch_link" pos="0 0 -0.28">
            <inertial pos="0.02 0 -0.02" mass="0.6" diaginertia="0.002 0.002 0.0005"/>
            <joint name="{s}_ankle_pitch_joint" axis="0 1 0" range="-0.87 0.52"/>
            <site name="{s}_foot" pos="0.03 0 -0.04"/>
            <geom name="{s}_foot1_collision" class="foot_capsule" fromto="-0.05 -0.02 -0.04 0.12 -0.02 -0.04"/>
            <geom name="{s}_foot2_collision" class="foot_capsule" fromto="-0.05 0.02 -0.04 0.12 0.02 -0.04"/>
          </body>
        </body>
      </body>"""


@pytest.fixture(scope="module")
def waist_biped(tmp_path_factory):
    """The biped above imported as the G1 is (robot-import, Unitree G1 motors, PD gains)."""
    from sim2real.deploy.cli.robot_import import main

    folder = tmp_path_factory.mktemp("waist_biped")
    legs = "\n".join(WAIST_LEG.format(s=s, y=y) for s, y in (("left", 0.1), ("right", -0.1)))
    source = folder / "waist_biped.xml"
    arms = "\n".join(WAIST_ARM.format(s=s, y=y) for s, y in (("left", 0.2), ("right", -0.2)))
    source.write_text(WAIST_BIPED.format(legs=legs, arms=arms))
    out = folder / "robots" / "waist_biped"
    flags = ["--floating-base", "--imu", "imu_in_pelvis"]
    flags += ["--foot", "left_ankle_pitch_link", "--foot", "right_ankle_pitch_link"]
    flags += ["--motor", "*=g1_7520_22", "--motor", "*_ankle_pitch_joint=g1_5020_x2"]
    flags += ["--motor", "waist_pitch_joint=g1_5020_x2", "--motor", "*_shoulder_*=g1_5020"]
    for gain, values in (("--kp", (99, 28.5, 14.3)), ("--kd", (6.3, 1.8, 0.9))):
        flags += [gain, f"*={values[0]}", gain, f"*_ankle_pitch_joint={values[1]}"]
        flags += [gain, f"waist_pitch_joint={values[1]}", gain, f"*_shoulder_*={values[2]}"]
    assert main([str(source), "--out", str(out), *flags]) == 0
    return load_robot(out)


def _tilted(pitch: float) -> np.ndarray:
    """(3,) gravity's direction in the frame of a base pitched by ``pitch`` rad about its y
    axis (nose down for pitch > 0)."""
    return np.array([np.sin(pitch), 0.0, -np.cos(pitch)])


@GUARDS
def test_a_weak_joint_under_a_heavy_chain_is_judged_by_its_gravity_at_the_estimate(
    waist_biped, guard_type
):
    """The waist at home and at rest, asked to hold home: its gravity torque upright is small,
    so the target passes (judged with the all-pose bound, 0.99 of the motor's torque, the joint
    could never brake and the target became a swing to the far side: a G1 walking with its
    waist flung +-4 rad). The same waist near its forward limit, moving toward it at 2 rad/s:
    its target passes on an upright base and is held back on a base pitched 50 deg forward,
    gravity then pulling the upper body onto the stop."""
    robot = waist_biped
    waist = robot.joint_names.index("waist_pitch_joint")
    guard = guard_type(robot, 1, "position")
    bound = guard.gravity_bound[waist]
    assert 0.95 * robot.effort_limit[waist] < bound < robot.effort_limit[waist]
    state = _state(robot, 1, robot.home)
    guard.reset(state.q)
    target = np.tile(robot.home, (1, 1))
    out = guard.filter(target.copy(), state, out=np.empty_like(target))
    np.testing.assert_array_equal(out, target)
    assert guard.totals()["pd_barrier"] == 0

    q = robot.home.copy()
    q[waist] = robot.soft_upper[waist] - 0.12
    dq = np.zeros(robot.n_joints)
    dq[waist] = 2.0
    state = _state(robot, 1, q, dq)
    target = np.tile(q, (1, 1))
    target[0, waist] = q[waist] + 0.2  # 5.7 N m toward the stop
    upright = guard.filter(target.copy(), state, out=np.empty_like(target))
    np.testing.assert_array_equal(upright, target)
    state.base.projected_gravity[0] = _tilted(np.radians(50.0))
    leaning = guard.filter(target.copy(), state, out=np.empty_like(target))
    assert leaning[0, waist] < target[0, waist]
    assert guard.totals()["pd_barrier"] == 1


@pytest.mark.parametrize("name", ["go2", "go2w", "h1", "h1_2"])
def test_the_least_inertia_bounds_a_pd_joints_motion_in_the_plant(name):
    """Each PD joint of a legged robot held in the air (the base welded; no gravity, contact or
    joint stop), at rest at home and three seeded poses, its target stepped 3 effort/kp away
    (the drive saturated), the others holding theirs: over one control period it moves no
    farther than the barrier's 1-D prediction (the PD law saturated by the effort limit,
    semi-implicit Euler at the physics step) with its least inertia says. The mass matrix's
    diagonal (the other joints locked) says less: up to 11 x the inertia the joint moves with
    (H1-2's hip roll)."""
    robot = load_robot(name)
    least = pb.least_inertia(robot)
    spec = robot.mjspec("position")
    off = mujoco.mjtDisableBit
    spec.option.disableflags |= off.mjDSBL_GRAVITY | off.mjDSBL_CONTACT | off.mjDSBL_LIMIT
    spec.delete(next(j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_FREE))
    m = spec.compile()
    d = mujoco.MjData(m)
    rng = np.random.default_rng(1)
    lo, hi = (
        np.nan_to_num(b, posinf=0.0, neginf=0.0) for b in (robot.soft_lower, robot.soft_upper)
    )
    poses = [robot.home, *(rng.uniform(lo, hi) for _ in range(3))]  # a wheel: at 0.0
    h, checked = robot.physics_timestep, 0
    for q0 in poses:
        for j, joint in enumerate(robot.config.joints):
            if robot.velocity_driven[j]:
                continue
            kp, kd, effort = joint.kp, joint.kd, robot.effort_limit[j]
            mujoco.mj_resetData(m, d)
            d.qpos[:] = q0
            d.ctrl[:] = np.where(robot.velocity_driven, 0.0, q0)
            d.ctrl[j] += 3.0 * effort / kp
            for _ in range(robot.decimation):
                mujoco.mj_step(m, d)
            q, v = 0.0, 0.0  # the prediction, from the same rest
            for _ in range(robot.decimation):
                tau = np.clip(kp * (3.0 * effort / kp - q) - kd * v, -effort, effort)
                v += tau / least[j] * h
                q += v * h
            assert d.qpos[j] - q0[j] <= q, (joint.name, d.qpos[j] - q0[j], q)
            checked += 1
    assert checked >= 4 * 8
