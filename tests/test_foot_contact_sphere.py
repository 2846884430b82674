"""A foot modelled as a sphere geom on the calf (unitree_mujoco's Go2 and B2: the calf holds the
shin's cylinders or boxes and, at its distal end, the sphere that touches the floor): robot-import
puts the foot site at the sphere's centre, so the base estimator's leg odometry and the fall
check's kinematic height take the sphere's contact point (its radius below the centre), not the
middle of the shin. Built on unitree_mujoco's go2.xml layout written by the test
(:mod:`tests.go2_layout`); the Go2 stands under stiff PD and sways fore and aft on its planted
feet, its thighs driven +-``SWAY`` rad at ``SWAY_HZ``."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.deploy.cli.robot_import import main
from sim2real.deploy.core.attitude import quaternion_to_matrix
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.estimation.base import BaseStateEstimator
from sim2real.deploy.estimation.base_params import foot_radii
from sim2real.deploy.estimation.fall import FallDetector
from sim2real.deploy.estimation.joints import JointStateEstimator
from sim2real.robots import load_robot
from sim2real.robots.drive import with_drive
from tests.go2_layout import FOOT_POS, FOOT_RADIUS, write_go2

FEET = ("FL", "FR", "RL", "RR")
#: The import flags of the shipped go2 (its header), the feet named as go2.xml's foot bodies.
FLAGS = ["--floating-base", "--motor", "*=go_m8010_6", "--motor", "*_calf_joint=go_m8010_6_knee"]
FLAGS += ["--kp", "*=20", "--kd", "*=0.5", "--home", "F?_thigh_joint=0.8"]
FLAGS += ["--home", "R?_thigh_joint=1.0", "--home", "*_calf_joint=-1.5", "--control-rate", "50"]
FLAGS += ["--physics-timestep", "0.002"] + [x for f in FEET for x in ("--foot", f"{f}_foot")]
#: Stand PD, N m/rad and N m s/rad (unitree_sdk2's example/go2/go2_stand_example.cpp, as
#: tests/test_wheeled_base.py), and the sway: rad of thigh, Hz (about 0.2 m/s RMS of the base).
STAND_KP, STAND_KD, SWAY, SWAY_HZ = 60.0, 5.0, 0.15, 1.0


def imported(folder, capsys, extra: str = ""):
    """go2.xml's layout (each calf given ``extra`` geoms) imported into ``folder``/go2; returns
    the robot folder and the import's printed lines."""
    source = write_go2(folder)
    if extra:
        text = source.read_text()
        source.write_text(
            text.replace('<geom name="F', extra + '<geom name="F').replace(
                '<geom name="R', extra + '<geom name="R'
            )
        )
    out = folder / "robots" / "go2"
    code = main([str(source), "--out", str(out), *FLAGS])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    return out, printed.out + printed.err


#: The sensors' noise draws the sway is run under: one draw's forward-speed ratio spreads over
#: 0.95-0.99 from seed to seed (seeds 0-3), so the figure is the four draws' together.
SEEDS = (0, 1, 2, 3)


@pytest.fixture(scope="module")
def swayed(tmp_path_factory):
    """The imported Go2 settled for 2 s under stiff PD, then swaying for 4 s (ramped in over the
    first second) under the joint and base estimators and the fall check, once per seed of
    :data:`SEEDS`. Returns per tick of each run's last 3 s: estimated and true forward speed
    (m/s, base frame), the fall check's height and the true base height above the floor (m)."""
    source = write_go2(tmp_path_factory.mktemp("go2_layout"))
    out = source.parent / "robots" / "go2"
    assert main([str(source), "--out", str(out), *FLAGS]) == 0
    robot = load_robot(out)
    robot = with_drive(robot, kp=np.full(12, STAND_KP), kd=np.full(12, STAND_KD))
    return np.concatenate([_sway(robot, seed) for seed in SEEDS])


def _sway(robot, seed: int) -> np.ndarray:
    """One seed's sway (the fixture's docstring): its rows after the first second."""
    plant = SimBackend(robot, "position", envs=1, seed=seed)
    home = np.array(robot.home, dtype=float)
    thigh = np.array(["thigh" in n for n in robot.joint_names])
    command = home[None].copy()
    for _ in range(100):
        plant.read()
        plant.write(command)
        plant.advance()
    joints, base = JointStateEstimator(robot, 1), BaseStateEstimator(robot, 1)
    fall = FallDetector(robot, 1)
    frame = plant.read()
    joints.reset(plant.true_position(), frame.time)
    base.reset(frame.time, frame.imu_acceleration, orientation=frame.imu_orientation)
    state = RobotState.legged(1, robot.n_joints, robot.n_feet)
    dt, rows = robot.control_period, []
    for k in range(int(round(4.0 / dt))):
        frame = plant.read()
        joints.update(frame, state)
        base.update(frame, state.q, state.dq, out=state.base)
        state.foot_contact[:] = base.contact
        fall.check(state)
        truth = plant.true_base_state()[0]
        forward = (quaternion_to_matrix(truth[3:7]).T @ truth[7:10])[0]
        rows.append((state.base.linear_velocity[0, 0], forward, fall.height[0], truth[2]))
        sway = SWAY * np.sin(2 * np.pi * SWAY_HZ * k * dt) * min(1.0, k * dt)
        command[0] = home + thigh * sway
        plant.write(command)
        plant.advance()
    return np.array(rows)[int(round(1.0 / dt)) :]


def test_the_foot_site_of_a_calf_with_a_foot_sphere_is_the_spheres_centre(tmp_path, capsys):
    """go2.xml's empty foot body hands the foot to its calf; of the calf's three collision geoms
    the sphere at its distal end is the foot: the site is at its centre, a sphere its radius plus
    the touch margin, and the estimator's contact radius is the sphere's (0.022 m)."""
    out, printed = imported(tmp_path, capsys)
    robot = load_robot(out)
    np.testing.assert_allclose(foot_radii(robot), FOOT_RADIUS)
    m = robot.mj_model
    for leg in FEET:
        site = m.site(f"{leg}_calf")
        assert m.body(site.bodyid[0]).name == f"{leg}_calf"
        assert site.type[0] == mujoco.mjtGeom.mjGEOM_SPHERE
        np.testing.assert_allclose(site.pos, FOOT_POS, atol=1e-9)
        assert f"note: foot {leg}_calf: a sphere of radius 0.022 m" in printed
    assert "3 geoms (cylinder, sphere) in a" not in printed  # the site around the whole calf


def test_a_swaying_go2s_base_speed_and_height_are_read_at_its_foot_spheres(swayed):
    """The base estimate's forward speed within 3 % of the truth (the ratio of their RMS over
    the sway: a filter's lag does not change it) and the fall check's kinematic base height
    within 1 cm of the true one on every tick it has a foot in contact. With the site around the
    calf's geoms (mid-shin) the speed read 25 % slow and the height 7 cm low."""
    est, true, height, true_height = swayed.T
    assert np.sqrt((true**2).mean()) > 0.15  # the base does sway
    ratio = np.sqrt((est**2).mean() / (true**2).mean())
    assert abs(ratio - 1.0) < 0.03, ratio
    seen = np.isfinite(height)
    assert seen.mean() > 0.9
    np.testing.assert_allclose(height[seen], true_height[seen], atol=0.01)


def test_a_foot_with_two_spheres_keeps_its_site_around_them_and_says_why(tmp_path, capsys):
    """A calf with a second sphere (the importer cannot tell which one touches the floor): the
    site stays the box around all its geoms, no contact radius, and an import note says so."""
    knee = '<geom size="0.015" pos="0.02 0 -0.1" type="sphere" class="collision" />\n'
    out, printed = imported(tmp_path, capsys, extra=knee)
    robot = load_robot(out)
    assert not foot_radii(robot).any()
    m = robot.mj_model
    assert all(m.site(f"{leg}_calf").type[0] == mujoco.mjtGeom.mjGEOM_BOX for leg in FEET)
    for leg in FEET:
        assert f"note: foot {leg}_calf: no one contact sphere among its 4 geoms" in printed
