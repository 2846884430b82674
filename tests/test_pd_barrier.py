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
    brake = np.maximum((effort - c[pb.GRAVITY]) * c[pb.BRAKE], 0.0) * c[pb.INV_INERTIA]

    def unsafe(t):
        full = np.tile(go2.home, (1, 1))
        full[0, hip] = t
        u = pb._unsafe_np(full, q[None], dq[None], hi, c[pb.GRAVITY], c, effort, brake)
        return bool(u[0, hip])

    assert unsafe(target[0, hip]) and not unsafe(out[0, hip])
    assert unsafe(out[0, hip] + 1e-6)  # the least change: a hair more is unsafe
    # the joint's own motion under the changed target in MuJoCo, the leg in the air: it stays
    # off the hard limit, where the raw target carried it past within the period
    assert _swing_peak(go2, q, dq, hip, out[0, hip]) < go2.position_upper[hip]
    assert _swing_peak(go2, q, dq, hip, target[0, hip]) > go2.position_upper[hip] - 1e-3


def _swing_peak(robot, q, dq, joint, target) -> float:
    """Highest angle (rad) of ``joint`` over one control period of the plant's position drives
    with the base held in the air (the free joint welded by zero gravity on it is not needed:
    the base is pinned by resetting it each substep), from ``q``, ``dq``, all other targets at
    ``q``."""
    m = robot.plant_model("position")
    d = mujoco.MjData(m)
    o, v = robot.qpos_offset, robot.qvel_offset
    d.qpos[2] = 1.0
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
    """Random states in and around the joints' ranges, fast joints, targets spread about them:
    the compiled guard and the numpy reference give the same targets and counters bit for bit,
    and the barrier acts on a share of them (the test exercises both branches)."""
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
        target = q + rng.normal(0.0, 1.0, q.shape)
        a = compiled.filter(target, state, out=np.empty_like(target))
        b = reference.filter(target, state, out=np.empty_like(target))
        np.testing.assert_array_equal(a, b)
        changed += int((a != target).sum())
    np.testing.assert_array_equal(compiled.count_matrix, reference.count_matrix)
    assert 0 < changed < 20 * q.size


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
