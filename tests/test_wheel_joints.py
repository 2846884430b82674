"""Continuous joints (the wheels of a wheel-legged robot): robot-import takes a floating-base
robot's unlimited hinge as continuous, robot.toml says ``continuous = true``, and a wheel spun
past any angle is never a position violation while its speed and torque stay checked. Built from
unitree_mujoco's Go2-W (sim2real/robots/go2w, imported from unitree_robots/go2w/go2w.xml)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.cli.robot_import import main
from sim2real.deploy.monitors.violations import ViolationMonitor
from sim2real.robots import load_robot
from sim2real.robots.importer.pipeline import EXIT_REFUSED
from sim2real.robots.schema import JointConfig
from tests.import_fixtures import humanoid_with, import_tiny

WHEELS = ("FL_wheel_joint", "FR_wheel_joint", "RL_wheel_joint", "RR_wheel_joint")


@pytest.fixture(scope="module")
def go2w():
    return load_robot("go2w")


def test_go2w_wheels_are_continuous_and_its_legs_bounded(go2w):
    wheels = [go2w.joint_names.index(w) for w in WHEELS]
    legs = [i for i in range(go2w.n_joints) if i not in wheels]
    for bound in (go2w.position_lower, go2w.soft_lower):
        assert np.all(bound[wheels] == -np.inf) and np.all(np.isfinite(bound[legs]))
    for bound in (go2w.position_upper, go2w.soft_upper):
        assert np.all(bound[wheels] == np.inf) and np.all(np.isfinite(bound[legs]))
    assert [go2w.config.joints[i].continuous for i in wheels] == [True] * 4
    # speed and torque stay bounded
    assert np.all(np.isfinite(go2w.velocity_limit)) and np.all(np.isfinite(go2w.effort_limit))


def place(backend, q, dq):
    """Env 0 of ``backend`` at joint angles ``q`` and speeds ``dq`` (base untouched)."""
    m, d = backend.models[0], backend.datas[0]
    d.qpos[7:] = q
    d.qvel[6:] = dq
    mujoco.mj_forward(m, d)


def test_a_wheel_spun_past_any_angle_is_no_violation_but_its_speed_is(go2w):
    backend = SimBackend(go2w, envs=1)
    monitor = ViolationMonitor(go2w, 1)
    wheel = go2w.joint_names.index("RR_wheel_joint")
    q, dq = go2w.home.copy(), np.zeros(go2w.n_joints)
    for angle in (7.0, -400.0, 1e5):  # past a turn, many turns back, far on
        q[wheel] = angle
        place(backend, q, dq)
        monitor.update(backend)
    assert monitor.totals()["any"] == 0, monitor.totals()
    dq[wheel] = 1.2 * go2w.velocity_limit[wheel]  # its speed is checked
    place(backend, q, dq)
    monitor.update(backend)
    assert monitor.counts["velocity"].tolist() == [1]
    assert monitor.counts["hard_limit"].tolist() == [0]
    calf = go2w.joint_names.index("RR_calf_joint")  # a leg past its range still counts
    q[calf], dq[:] = go2w.position_upper[calf] + 0.05, 0.0
    place(backend, q, dq)
    monitor.update(backend)
    assert monitor.counts["hard_limit"].tolist() == [1]


def test_robot_toml_says_continuous_or_gives_a_range_never_both():
    base = dict(
        name="w", velocity_limit=30.0, acceleration_limit=1.0, jerk_limit=1.0,
        effort_limit=1.0, motor="m", kp=1.0, kd=0.1,
    )  # fmt: skip
    assert JointConfig(**base, continuous=True).position_limit is None
    for bad in (dict(), dict(continuous=True, position_limit=(-1.0, 1.0))):
        with pytest.raises(ValueError, match="position_limit = \\[lower, upper\\] or continuous"):
            JointConfig(**base, **bad)


def test_import_takes_a_floating_base_unlimited_hinge_as_continuous(tmp_path, capsys):
    # the test humanoid with one more link on a hinge without a range (a wheel on its torso)
    wheel = (
        '<body name="wheel" pos="0 0 0.1"><joint name="wheel_joint" axis="0 1 0"/>'
        '<geom type="cylinder" size="0.03 0.01" mass="0.2"/></body>'
    )
    source = humanoid_with(tmp_path, wheel, before='<body name="left_hip_roll_link"')
    code, out = import_tiny(source, tmp_path)
    assert code == 0, capsys.readouterr().err
    text = (out / "robot.toml").read_text()
    assert 'name = "wheel_joint"\ncontinuous = true' in text
    robot = load_robot(out)
    i = robot.joint_names.index("wheel_joint")
    assert robot.position_lower[i] == -np.inf and robot.position_upper[i] == np.inf


def test_an_arms_unlimited_hinge_is_still_refused(tmp_path, capsys):
    from tests.test_importer import SMALL

    mjcf = tmp_path / "arm.xml"
    mjcf.write_text(SMALL.format(free="", limit=""))
    assert main([str(mjcf), "--out", str(tmp_path / "o"), "--motor", "*=sts3215"]) == EXIT_REFUSED
    assert "continuous joint (a wheel) is taken on a floating-base robot only" in (
        capsys.readouterr().err
    )
