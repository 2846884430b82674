"""Per-joint drive kinds within one robot: a wheel-legged robot's legs take PD position targets
and its wheels speed targets (kp 0, kd 0.5, the action scaled to rad/s: rl_sar's
policy/go2w/robot_lab/config.yaml ``rl_kp``/``rl_kd``/``action_scale``). Built on unitree_mujoco's
Go2-W (sim2real/robots/go2w)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sim2real.deploy.smoothing.smoother import CommandSmoother
from sim2real.deploy.spec.drive import DriveSpec, drive_robot
from sim2real.robots import load_robot
from sim2real.robots.drive import with_drive
from sim2real.robots.robot import RobotSpecError

KD = 0.5  # N m s/rad, rl_sar's rl_kd of a wheel


@pytest.fixture(scope="module")
def go2w():
    return load_robot("go2w")


def wheel_drive(robot):
    """``(kp, kd, kinds)`` of rl_sar's Go2-W drive in ``robot``'s joint order."""
    wheel = np.array(["wheel" in n for n in robot.joint_names])
    kp = np.where(wheel, 0.0, 20.0)
    kinds = tuple("velocity" if w else "position" for w in wheel)
    return kp, np.full(robot.n_joints, KD), kinds, wheel


def position_driven(robot):
    """``robot`` with every joint a position drive at rl_sar's leg gains (kp 20, kd 0.5): the
    Go2-W as it was shipped before its wheels became velocity drives."""
    n = robot.n_joints
    return with_drive(robot, kp=np.full(n, 20.0), kd=np.full(n, KD), kinds=("position",) * n)


@pytest.fixture(scope="module")
def wheeled(go2w):
    kp, kd, kinds, _ = wheel_drive(go2w)
    return with_drive(go2w, kp=kp, kd=kd, kinds=kinds)


def test_a_wheels_kp_0_is_a_velocity_drive_and_refused_on_a_position_drive(go2w, wheeled):
    kp, kd, kinds, wheel = wheel_drive(go2w)
    assert np.array_equal(wheeled.velocity_driven, wheel)
    positional = position_driven(go2w)
    with pytest.raises(RobotSpecError, match="kp must be positive"):
        with_drive(positional, kp=kp, kd=kd)  # kp 0 on a wheel that is still a position drive
    spec_drive = DriveSpec(kp=tuple(kp), kd=tuple(kd), kinds=kinds)
    assert spec_drive.problems(go2w.n_joints) == []
    assert DriveSpec(kp=tuple(kp), kd=tuple(kd)).problems(go2w.n_joints)


def test_the_plant_applies_kd_times_the_speed_error_to_a_wheel(wheeled):
    m = wheeled.plant_model()
    d = mujoco.MjData(m)
    w = int(np.flatnonzero(wheeled.velocity_driven)[0])
    dof = wheeled.qvel_offset + w
    d.qvel[dof] = 3.0
    d.ctrl[w] = 10.0  # rad/s, the wheel's speed target
    mujoco.mj_forward(m, d)
    assert d.qfrc_actuator[dof] == pytest.approx(KD * (10.0 - 3.0))


def test_the_smoother_passes_a_wheels_speed_and_brakes_it_to_zero_in_a_safe_stop(wheeled):
    n = wheeled.n_joints
    wheel = wheeled.velocity_driven
    sm = CommandSmoother(wheeled, 1, "position", bounded=False)
    q = np.array(wheeled.home, dtype=float)[None].copy()
    q[0, wheel] = 40.0  # rad: a wheel turned many times over
    sm.reset(q, np.zeros((1, n)))
    target = q.copy()
    target[0, wheel] = [5.0, -5.0, 100.0, -100.0]  # rad/s
    cmd = sm.step(target).copy()
    limit = wheeled.soft_velocity_limit[wheel]
    assert np.allclose(cmd[0, wheel], np.clip([5.0, -5.0, 100.0, -100.0], -limit, limit))
    assert np.allclose(cmd[0, ~wheel], q[0, ~wheel])  # legs: their PD targets
    assert sm.wheels.clamps[0] == 2 and sm.target_clamps[0] == 2  # counted as interventions
    sm.safe_stop()
    assert np.all(sm.step(target)[0, wheel] == 0.0)


def test_a_policys_wheel_drive_builds_the_plant_it_was_trained_with(go2w):
    kp, kd, kinds, wheel = wheel_drive(go2w)

    class Spec:
        drive = DriveSpec(kp=tuple(kp), kd=tuple(kd), kinds=kinds)

    positional = position_driven(go2w)
    robot, differences = drive_robot(positional, Spec)
    assert "kinds" in differences and np.array_equal(robot.velocity_driven, wheel)
    assert drive_robot(go2w, Spec) == (go2w, {})  # the shipped go2w: rl_sar's drive already


def test_an_excitation_swings_a_wheel_within_a_turn_and_never_asks_for_nan(go2w):
    from sim2real.deploy.policy.excitation import Excitation, ExcitationPolicy, trajectory

    ex = Excitation(joints=("FL_wheel_joint",), chirp=2.0, chirp_together=0.0)
    rows = trajectory(go2w, ex)
    w = go2w.joint_names.index("FL_wheel_joint")
    assert np.all(np.isfinite(rows))
    assert 0.1 < np.ptp(rows[:, w]) <= 2 * np.pi  # it moves, within one turn
    assert np.all(np.isfinite(ExcitationPolicy(go2w, ex).actions))


def test_a_ramp_to_home_holds_a_wheel_at_speed_0_wherever_its_angle(wheeled):
    from sim2real.deploy.runtime.handover import RampIn
    from sim2real.deploy.runtime.supervision import RAMP_IN

    wheel = wheeled.velocity_driven
    start = np.array(wheeled.home, dtype=float)[None].copy()
    start[0, wheel] = [40.0, -7.0, 123.0, 3.0]  # rad: wheels turned many times over
    ramp = RampIn(start, wheeled.home, np.ones(1, bool), 10, speeds=wheel)
    target = np.zeros((1, wheeled.n_joints))
    ramp.shape(target, np.array([RAMP_IN]))
    assert np.all(target[0, wheel] == 0.0)  # rad/s, not the angle


def test_go2w_is_a_wheel_legged_kind_whose_wheels_brake_to_zero_in_a_safe_stop(go2w, wheeled):
    from sim2real.deploy.kinds import LEGGED, robot_kind

    kind = robot_kind(go2w)  # robot.toml: kind = "wheel_legged"
    assert kind.name == "wheel_legged" and kind.floating_base and kind.task == "locomotion"
    assert kind.pd_targets and kind.hard_limit_bounce  # as a legged robot
    wheel = wheel_drive(go2w)[3]
    assert kind.wheels(go2w).tolist() == wheel.tolist()  # its continuous joints
    drives = robot_kind(wheeled).wheel_drives(wheeled, 2, "position")
    out = np.zeros((2, wheeled.n_joints))
    speeds = np.full((2, wheeled.n_joints), 3.0)  # rad/s on the wheels
    drives.command(speeds, out, stopping=np.array([True, False]))
    assert np.all(out[0, wheel] == 0.0) and np.all(out[1, wheel] == 3.0)  # env 0 stops
    assert robot_kind(wheeled).wheel_drives(wheeled, 2, "torque") is None
    # a legged kind drives no wheel: the robot's velocity drives need this kind
    with pytest.raises(ValueError, match=r"kind = 'legged' drives no joint by velocity, but FL_wh"):
        LEGGED.check(wheeled, "robot.toml: kind")
    with pytest.raises(ValueError, match=r"kind = 'wheel_legged' needs wheels"):
        kind.check(load_robot("go2"), "robot.toml: kind")


def test_ramp_in_ends_at_the_legs_home_wherever_the_wheels_stand(tmp_path):
    """A Go2-W handed over with its wheels turned many times over (they roll in a bring-up: a
    wheel at speed 0 has no pose): RAMP_IN ends on its legs' home pose and the policy runs. A
    wheel's angle judged against its home 0 kept the runtime in RAMP_IN for good."""
    pytest.importorskip("torch")
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.core.modes import RUNNING
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.rig.rig import Rig
    from tests.test_rl_sar_contract import write

    go2w = load_robot("go2w")
    policy = OnnxPolicy(write(tmp_path), go2w)  # rl_sar's folder: wheels on speed targets
    robot, _ = drive_robot(go2w, policy.spec)
    plant = SimBackend(robot, envs=1, seed=0)
    m, d = plant.models[0], plant.datas[0]
    d.qpos[7:][robot.velocity_driven] = [40.0, -7.0, 123.0, 3.0]  # rad
    mujoco.mj_forward(m, d)
    plant.advance()  # the encoders read them
    rig = Rig(robot, policy, plant, envs=1)
    rig.start()
    rig.run(round(1.0 / robot.control_period))
    assert rig.runtime.mode[0] == RUNNING
