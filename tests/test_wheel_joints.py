"""Continuous joints (the wheels of a wheel-legged robot): robot-import takes a floating-base
robot's unlimited hinge as continuous, robot.toml says ``continuous = true``, and a wheel spun
past any angle is never a position violation while its speed and torque stay checked. Built from
unitree_mujoco's Go2-W (sim2real/robots/go2w, imported from unitree_robots/go2w/go2w.xml)."""

from __future__ import annotations

import json

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


def test_import_of_go2w_xml_writes_a_wheel_legged_robot_that_runs_rl_sars_policy(tmp_path, capsys):
    """unitree_mujoco's go2w.xml layout imported as a user would, with ``--unitree`` and rl_sar's
    wheel gain (kp 0): robot.toml says ``kind = "wheel_legged"``, makes the wheels velocity
    drives and gives them their motor slots after the legs' (the actuator order), and deploy-run
    reads rl_sar's policy folder on it with no edit and no difference of drive."""
    pytest.importorskip("torch")
    from sim2real.deploy.cli.deploy_run import deploy_run_main
    from sim2real.deploy.kinds import robot_kind
    from tests.go2w_layout import write_go2w
    from tests.test_rl_sar_contract import write

    source = write_go2w(tmp_path)
    out = tmp_path / "robots" / "go2w"
    flags = ["--floating-base", "--motor", "*=go_m8010_6", "--kp", "*=20", "--kd", "*=0.5"]
    flags += ["--kp", "*_wheel_joint=0"]  # rl_sar's rl_kp of a wheel: a speed target
    flags += ["--home", "F?_thigh_joint=0.5", "--home", "R?_thigh_joint=0.8"]
    flags += ["--home", "*_calf_joint=-1.5"]  # rl_sar's default_dof_pos
    flags += ["--control-rate", "50", "--physics-timestep", "0.005"]
    flags += ["--unitree", "unitree_go", "--unitree-damping-kd", "3.5", "--unitree-ramp-kp", "50"]
    assert main([str(source), "--out", str(out), *flags]) == 0, capsys.readouterr().err
    text = (out / "robot.toml").read_text()
    assert '\nkind = "wheel_legged"\n' in text
    robot = load_robot(out)
    assert robot_kind(robot).name == "wheel_legged"
    wheels = [f"{leg}_wheel_joint" for leg in ("FL", "FR", "RL", "RR")]
    assert list(np.array(robot.joint_names)[robot.velocity_driven]) == wheels
    # legs FR, FL, RR, RL at 0-11, wheels FR, FL, RR, RL at 12-15 (go2w.xml's actuators)
    slots = dict(zip(robot.joint_names, robot.config.unitree.motor_index, strict=True))
    assert [slots[f"{leg}_wheel_joint"] for leg in ("FR", "FL", "RR", "RL")] == [12, 13, 14, 15]
    assert [slots[f"{leg}_calf_joint"] for leg in ("FR", "FL", "RR", "RL")] == [2, 5, 8, 11]
    policy = write(tmp_path, bias=[0.0] * 12 + [1.0] * 4)  # wheels at 5 rad/s
    report = tmp_path / "run.json"
    args = ["--robot", str(out), "--policy", str(policy), "--backend", "sim", "--duration", "2"]
    args += ["--command", "0,0,0", "--report", str(report)]
    capsys.readouterr()
    assert deploy_run_main(args) == 0, capsys.readouterr().err
    assert "differs from the policy's drive" not in capsys.readouterr().err
    assert json.loads(report.read_text())["final_state"] == ["RUNNING"]
    # kp 0 makes a speed target of a continuous joint only
    flags += ["--kp", "FL_calf_joint=0"]
    assert main([str(source), "--out", str(tmp_path / "calf"), *flags]) != 0
    assert "--kp: gains must be positive" in capsys.readouterr().err
