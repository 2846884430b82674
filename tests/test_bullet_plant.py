"""The plant on pybullet (sim2real.deploy.backends.sim.bullet) against the MuJoCo plant: every shipped robot
builds and stands, the drives respond alike, limits and dry friction hold, motors heat alike,
sensors keep their statistics, hooks reach pybullet, and the runtime cannot tell the engines
apart."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pybullet")

from sim2real.deploy.backends.sim.bullet.plant import BulletBackend  # noqa: E402
from sim2real.deploy.backends.sim.engines import ENGINES, make_plant, plant_class  # noqa: E402
from sim2real.deploy.backends.sim.plant import SimBackend  # noqa: E402
from sim2real.deploy.core.backend import Backend, SimulatedPlant  # noqa: E402
from sim2real.robots import load_robot  # noqa: E402
from tests.runtime_fixtures import shipped_onnx  # noqa: E402


def run(backend, ticks: int, command: np.ndarray | None = None) -> None:
    for _ in range(ticks):
        backend.read()
        if command is not None:
            backend.write(command)
        backend.advance()


def both(robot, **kwargs):
    return SimBackend(robot, **kwargs), BulletBackend(robot, **kwargs)


def test_the_engine_switch_names_both_engines_and_refuses_others(arm3):
    assert ENGINES == ("mujoco", "pybullet")
    assert plant_class("mujoco") is SimBackend and plant_class("pybullet") is BulletBackend
    plant = make_plant("pybullet", arm3, envs=2, seed=3)
    assert isinstance(plant, Backend) and isinstance(plant, SimulatedPlant)
    assert plant.envs == 2 and plant.engine == "pybullet"
    with pytest.raises(ValueError, match="engine 'ode' is unknown; expected one of"):
        plant_class("ode")


@pytest.mark.parametrize("name", ["arm3", "arm6", "so101", "ur5"])
def test_every_shipped_arm_holds_its_home_pose_as_on_mujoco(name):
    """An arm holding its home command for 1 s ends where the MuJoCo plant's does (the drives
    are MuJoCo's law, the armature exact in joint space)."""
    robot = load_robot(name)
    mj, pb = both(robot)
    ticks = int(round(1.0 / robot.control_period))
    run(mj, ticks)
    run(pb, ticks)
    np.testing.assert_allclose(pb.true_position(), mj.true_position(), atol=2e-3)


@pytest.mark.parametrize("name", ["go2", "h1", "h1_2"])
def test_every_shipped_legged_robot_stands_on_pybullet_and_its_feet_carry_its_weight(name):
    """Holding its home pose for 0.4 s, a legged robot stays up; its touch sensors (pybullet's
    contact normal forces) carry its weight and its accelerometer reads gravity, up."""
    robot = load_robot(name)
    pb = BulletBackend(robot)
    start = pb.true_base_state()[0, 2]
    run(pb, int(round(0.4 / robot.control_period)))
    base = pb.true_base_state()[0]
    assert base[2] > 0.8 * start  # still standing
    weight = float(pb.models[0].body_subtreemass[1]) * 9.81
    feet = pb.base_sensors.true_foot_force()[0]
    assert abs(feet.sum() - weight) < 0.15 * weight, (feet, weight)
    imu = pb.base_sensors.true_imu()[0]
    assert np.linalg.norm(imu[3:]) == pytest.approx(9.81, abs=1.0)
    assert imu[5] > 8.0


@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_a_drive_step_responds_as_on_mujoco_in_every_control_mode(arm3, mode):
    """A step of the elbow's command (0.3 rad, 1 rad/s, or 5 N m over the holding torque):
    the joint's trajectory over 0.3 s follows the MuJoCo plant's within 3 % of its travel."""
    mj, pb = both(arm3, mode=mode)
    steps = {"position": 0.3, "velocity": 1.0, "torque": 5.0}
    traj = {}
    for plant in (mj, pb):
        command = plant.state_dict()["command"].copy()
        command[0, 1] += steps[mode]
        q0 = plant.true_position()[0, 1]
        out = []
        for _ in range(int(round(0.3 / arm3.control_period))):
            plant.write(command)
            plant.advance()
            out.append(plant.true_position()[0, 1] - q0)
        traj[plant.engine if hasattr(plant, "engine") else "mujoco"] = np.array(out)
    travel = np.abs(traj["mujoco"]).max()
    assert travel > 0.05
    assert np.abs(traj["pybullet"] - traj["mujoco"]).max() < 0.03 * travel


def test_a_joint_driven_into_its_stop_stays_at_its_hard_limit(so101):
    """The shoulder pushed with its peak torque rests at its joint range's end (pybullet's limit
    constraint), as on MuJoCo; without the limit it would swing far past."""
    mj, pb = both(so101, mode="torque")
    command = pb.state_dict()["command"].copy()
    command[0, 1] = so101.effort_limit[1]
    for plant in (mj, pb):
        run(plant, int(round(1.0 / so101.control_period)), command)
    upper = so101.position_upper[1]
    assert pb.true_position()[0, 1] == pytest.approx(upper, abs=0.01)
    assert mj.true_position()[0, 1] == pytest.approx(upper, abs=0.01)


@pytest.mark.parametrize("engine", ENGINES)
def test_dry_joint_friction_holds_a_joint_below_its_breakaway_torque(arm6, engine):
    """arm6's base joint (vertical axis, 0.5 N m of dry friction): 0.4 N m turns it by less than
    0.01 rad in 0.5 s (both engines' dry friction creeps a little), 2 N m by far more."""
    friction = arm6.plant_model().dof_frictionloss[0]
    assert friction == pytest.approx(0.5)
    moved = []
    for torque in (0.4, 2.0):
        plant = make_plant(engine, arm6, mode="torque")
        command = plant.state_dict()["command"].copy()
        command[0, 0] = torque
        q0 = plant.true_position()[0, 0]
        run(plant, int(round(0.5 / arm6.control_period)), command)
        moved.append(abs(plant.true_position()[0, 0] - q0))
    assert moved[0] < 0.01 < 0.03 < moved[1]


def test_the_motors_heat_as_on_mujoco_under_the_same_load(arm3):
    """Holding the arm out against gravity for 30 s heats each winding as on MuJoCo (the same
    torque through the same thermal model) within 0.1 degC."""
    mj, pb = both(arm3, mode="position")
    pose = np.array([[0.0, 1.2, 0.3]])
    for plant in (mj, pb):
        run(plant, int(round(30.0 / arm3.control_period)), pose)
    rise = mj.thermal.winding_temperature - mj.thermal.ambient[:, None]
    assert rise.max() > 1.0
    np.testing.assert_allclose(
        pb.thermal.winding_temperature, mj.thermal.winding_temperature, atol=0.1
    )


def test_encoder_readings_keep_their_noise_statistics(arm3):
    """Encoder readings minus pybullet's truth: zero mean, the configured sigma (within 10 %)."""
    pb = BulletBackend(arm3, seed=4)
    pb.noise_sigma[:] = 0.01
    pb.latency_ticks[:] = 0
    pb.dropout_probability[:] = 0.0
    errors = []
    for _ in range(1500):
        pb.advance()
        frame = pb.read()
        ok = np.isfinite(frame.position[0])
        errors.append((frame.position[0] - pb.true_position()[0])[ok])
    errors = np.concatenate(errors)
    assert errors.size > 3000
    assert abs(errors.mean()) < 1e-3
    assert errors.std() == pytest.approx(0.01, rel=0.1)


def test_a_push_and_a_cable_pull_reach_pybullet_as_on_mujoco(go2, so101):
    """``set_base_velocity`` moves the go2's base in pybullet; a 3 N cable on the SO-101's end
    effector (rotor inertia a hundred times its links') moves its joints as on MuJoCo."""
    dog = BulletBackend(go2)
    run(dog, 5)
    x0 = dog.true_base_state()[0, 0]
    dog.set_base_velocity(0, np.array([1.0, 0.0]))
    run(dog, 2)
    assert dog.true_base_state()[0, 0] - x0 > 0.02

    mj, pb = both(so101, mode="position")
    free = BulletBackend(so101, mode="position")
    for plant in (mj, pb):
        plant.set_external_force(0, np.array([0.0, 0.0, -3.0]))
    for plant in (mj, pb, free):
        run(plant, int(round(0.5 / so101.control_period)))
    moved = np.abs(pb.true_position() - free.true_position()).max()
    assert moved > 0.01
    assert np.abs(pb.true_position() - mj.true_position()).max() < 0.05 * moved


def test_a_checkpoint_resumes_the_arm_where_it_was(arm3):
    """state_dict / load_state_dict: an arm's positions, velocities and drive integrators travel
    with the mirror; resumed, it continues as the uninterrupted plant does."""
    a = BulletBackend(arm3, seed=1)
    command = np.array([[0.5, -0.2, 0.1]])
    run(a, 40, command)
    state = a.state_dict()
    b = BulletBackend(arm3, seed=1)
    b.load_state_dict(state)
    np.testing.assert_array_equal(b.true_position(), a.true_position())
    run(a, 40, command)
    run(b, 40, command)
    np.testing.assert_allclose(b.true_position(), a.true_position(), atol=1e-9)


class _Recorder:
    """A backend seen through a log of every attribute the runtime touches on it."""

    def __init__(self, inner, log: list[str]):
        object.__setattr__(self, "_inner", inner)
        object.__setattr__(self, "_log", log)

    def __getattr__(self, name):
        self._log.append(name)
        return getattr(self._inner, name)

    def __setattr__(self, name, value):
        self._log.append(f"set {name}")
        setattr(self._inner, name, value)


def test_the_runtime_takes_the_same_code_path_on_both_engines(arm3, tmp_path):
    """The runtime touches the same backend attributes in the same order on both plants over
    50 ticks (it cannot tell them apart) and ends in the same state."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.runtime import Runtime

    policy = OnnxPolicy(shipped_onnx("arm", tmp_path), arm3)
    logs, modes = {}, {}
    for engine in ENGINES:
        log: list[str] = []
        backend = make_plant(engine, arm3, mode=policy.spec.action.mode)
        rt = Runtime(arm3, policy, _Recorder(backend, log))
        rt.start()
        rt.run(50)
        logs[engine], modes[engine] = log, rt.mode_names()
    assert len(logs["mujoco"]) > 100
    assert logs["pybullet"] == logs["mujoco"]
    assert modes["pybullet"] == modes["mujoco"] == ["RUNNING"]


def test_a_legged_robots_drives_carry_their_armature_on_pybullet(go2):
    """Floating 1 m up without gravity, a torque step on each go2 calf turns it as on MuJoCo,
    whose armature (the rotor's reflected inertia) is about half the calf's inertia: the pybullet
    plant's geared rotor links carry it (without them the calves turn twice as far)."""
    models = []
    for _ in range(2):
        m = go2.plant_model("torque")
        m.opt.gravity[:] = 0.0
        m.qpos0[2] += 1.0  # clear of the floor
        models.append(m)
    mj = SimBackend(go2, mode="torque", models=[models[0]])
    pb = BulletBackend(go2, mode="torque", models=[models[1]])
    calves = [i for i, name in enumerate(go2.joint_names) if "calf" in name]
    out = {}
    for name, plant in (("mujoco", mj), ("pybullet", pb)):
        command = np.zeros((1, go2.n_joints))
        command[0, calves] = 2.0
        q0 = plant.true_position()[0, calves].copy()
        run(plant, 3, command)
        out[name] = plant.true_position()[0, calves] - q0
    assert np.all(out["mujoco"] > 0.1)
    np.testing.assert_allclose(out["pybullet"], out["mujoco"], rtol=0.05)


def test_soak_test_runs_on_pybullet_and_sim2sim_compares_it_with_mujoco(tmp_path):
    """``soak-test --engine pybullet`` (arm3, 18 simulated s, faults every 4 s) writes a report
    that names its engine; ``sim2sim --compare-only`` sets it beside the same campaign on MuJoCo
    and finds the shipped policy's goals the same on both."""
    import json

    from sim2real.eval import cli as soak_cli
    from sim2real.eval.sim2sim import cli as sim2sim_cli

    policy = shipped_onnx("arm", tmp_path)
    for engine in ENGINES:
        argv = ["--robot", "arm3", "--policy", str(policy), "--hours", "0.005", "--seed", "3"]
        argv += ["--fault-interval", "4", "--no-progress", "--no-film", "--engine", engine]
        code = soak_cli.main([*argv, "--out", str(tmp_path / engine)])
        assert code != soak_cli.EXIT_BAD_INPUT
        report = json.loads((tmp_path / engine / "report.json").read_text())
        assert report["campaign"]["engine"] == engine
    code = sim2sim_cli.main(["--compare-only", "--out", str(tmp_path)])
    result = json.loads((tmp_path / "sim2sim.json").read_text())
    assert result["engines"] == list(ENGINES) and result["robot"] == "arm3"
    goals = {f["name"]: f for f in result["totals"]}["goals_reached"]
    assert set(goals["values"]) == set(ENGINES) and not goals["engine_dependent"]
    expected = sim2sim_cli.EXIT_ENGINE_DEPENDENT if result["engine_dependent"] else 0
    assert code == expected
