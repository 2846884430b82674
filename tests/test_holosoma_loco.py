"""holosoma_inference's G1 locomotion policies (``models/loco/g1_29dof/*.onnx`` of amazon-far/holosoma)
on unitree_mujoco's G1 (both read from their checkouts under ``SIM2REAL_STACKS``, :mod:`tests.stacks`; skipped
without them): the files carry no
``experiment_config``, and are read with holosoma_inference's own locomotion configuration: the
observation and targets it computes from the same state, by joint names, with its gait clock."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import pytest

from tests.motion_files import G1_FLAGS, g1_xml

pytest.importorskip("onnxruntime")

LOCO = "src/holosoma_inference/holosoma_inference/models/loco/g1_29dof/{}.onnx"
FILES = ("ppo_g1_29dof", "fastsac_g1_29dof")
#: holosoma_inference ``config_values/robot.py`` ``g1_29dof.default_dof_angles``, in its
#: ``dof_names`` order (legs, waist, arms), rad.
DEFAULT = (
    -0.312, 0.0, 0.0, 0.669, -0.363, 0.0, -0.312, 0.0, 0.0, 0.669, -0.363, 0.0,
    0.0, 0.0, 0.0,
    0.2, 0.2, 0.0, 0.6, 0.0, 0.0, 0.0, 0.2, -0.2, 0.0, 0.6, 0.0, 0.0, 0.0,
)  # fmt: skip


def _loco(stacks, root: Path, name: str) -> Path:
    path = LOCO.format(name)
    data = stacks.read("holosoma", path)
    if data.startswith(b"version https://git-lfs"):
        pytest.skip(f"{path} is a Git LFS pointer in the checkout")
    out = root / f"{name}.onnx"
    out.write_bytes(data)
    return out


@pytest.fixture(scope="module")
def g1(stacks, tmp_path_factory):
    """(robot, {name: file}): unitree_mujoco's G1 imported with the G1's robot-level flags and
    ``--drive-from`` the PPO file (its gains, home and rate from the contract), and the files."""
    from sim2real.deploy.cli.robot_import import main as robot_import
    from sim2real.robots import load_robot

    root = tmp_path_factory.mktemp("loco")
    files = {name: _loco(stacks, root, name) for name in FILES}
    xml = g1_xml(stacks, root)
    out = root / "g1"
    flags = [str(xml), *G1_FLAGS, "--drive-from", str(files["ppo_g1_29dof"]), "--out", str(out)]
    assert robot_import(flags) == 0
    return load_robot(out), files


def _names(path: Path) -> list[str]:
    return json.loads({p.key: p.value for p in onnx.load(str(path)).metadata_props}["dof_names"])


def holosoma_observation(q, dq, quat, omega, command, last, phase) -> np.ndarray:
    """(100,) holosoma_inference's ``actor_obs`` (``BasePolicy.get_current_obs_buffer_dict``,
    ``LocomotionPolicy``'s terms, scaled by observation ``loco-g1-29dof``, sorted by name) from
    joints ``q``, ``dq`` in its ``dof_names`` order, the base's ``quat`` (w, x, y, z) and body
    rate ``omega``, ``command`` (vx, vy, yaw rate), the last clipped action and the feet's
    ``phase``."""
    w, x, y, z = quat
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    terms = {
        "actions": last,
        "base_ang_vel": 0.25 * omega,
        "command_ang_vel": command[2:],
        "command_lin_vel": command[:2],
        "cos_phase": np.cos(phase),
        "dof_pos": q - np.array(DEFAULT),
        "dof_vel": 0.05 * dq,
        "projected_gravity": rotation.T @ [0.0, 0.0, -1.0],
        "sin_phase": np.sin(phase),
    }
    return np.concatenate([np.asarray(terms[k], dtype=float) for k in sorted(terms)])


@pytest.mark.parametrize("name", FILES)
def test_the_shipped_g1_loco_files_read_as_holosoma_inference_runs_them(g1, name):
    """No ``experiment_config`` in the files: holosoma_inference's task ``locomotion`` and
    observation ``loco-g1-29dof`` (terms sorted, 100 entries, the two-foot gait clock of period
    1 s that stands below 0.01), action scale 0.25 and clip 100 about its G1 default pose, 50 Hz;
    robot-import --drive-from wrote that pose as home and the file's gains, by joint name."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.foreign.registry import OnnxFacts, read_contract

    robot, files = g1
    path = files[name]
    c = read_contract(OnnxFacts.of(path, onnx.load(str(path))))
    assert c.format == "holosoma" and c.obs_dim == 100 and not c.missing
    assert [(t.name, t.kind, t.components) for t in c.terms] == [
        ("actions", "last_action", ()),
        ("base_ang_vel", "base_angular_velocity", ()),
        ("command_ang_vel", "velocity_command", (2,)),
        ("command_lin_vel", "velocity_command", (0, 1)),
        ("cos_phase", "gait_phase", (1, 3)),
        ("dof_pos", "joint_position", ()),
        ("dof_vel", "joint_velocity", ()),
        ("projected_gravity", "projected_gravity", ()),
        ("sin_phase", "gait_phase", (0, 2)),
    ]
    phase = [t for t in c.terms if t.kind == "gait_phase"]
    assert {(t.period, t.stand_below, t.stand_phase) for t in phase} == {(1.0, 0.01, np.pi)}
    assert c.action_scale == 0.25 and c.action_clip == 100.0 and c.control_rate == 50.0
    names = _names(path)
    assert c.default_pose == DEFAULT
    md = {p.key: json.loads(p.value) for p in onnx.load(str(path)).metadata_props}
    home = dict(zip(robot.joint_names, robot.home, strict=True))
    joints = {j.name: j for j in robot.config.joints}
    for j, name_ in enumerate(names):
        assert home[name_] == pytest.approx(DEFAULT[j])
        assert joints[name_].kp == pytest.approx(md["kp"][j])
        assert joints[name_].kd == pytest.approx(md["kd"][j])
    assert OnnxPolicy(path, robot).spec.control_rate == 50.0


def test_the_observation_and_targets_are_holosoma_inferences_from_the_same_state(g1):
    """Ticks of seeded states (joints about the default pose, a tilted base, body rates) through
    a stand, a walk and a turn on the spot: the PPO file's observation, as our spec builds it
    from the robot's joints, equals holosoma_inference's from the same state in its
    ``dof_names`` order, and the targets are ``clip(action, -100, 100) * 0.25 + default`` by
    name."""
    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy

    robot, files = g1
    policy = OnnxPolicy(files["ppo_g1_29dof"], robot)
    spec = policy.spec
    names = _names(files["ppo_g1_29dof"])
    to_robot = [robot.joint_names.index(n) for n in names]
    state = RobotState.legged(1, robot.n_joints, robot.n_feet)
    spec.plan.reset_history()
    rng = np.random.default_rng(3)
    commands = [(0.0, 0.0, 0.0)] * 3 + [(0.5, 0.1, 0.0)] * 4 + [(0.0, 0.0, 0.4)] * 3
    phase, standing, step = np.array([0.0, np.pi]), False, 2 * np.pi / (50.0 * 1.0)
    last = np.zeros(len(names))
    obs = np.zeros((1, spec.obs_dim), dtype=np.float32)
    target = np.empty((1, robot.n_joints))
    for tick, command in enumerate(commands):
        # holosoma_inference's clock (LocomotionPolicy.update_phase_time), before it observes
        phase = np.fmod(phase + step + np.pi, 2 * np.pi) - np.pi
        if np.linalg.norm(command[:2]) < 0.01 and abs(command[2]) < 0.01:
            phase, standing = np.array([np.pi, np.pi]), True
        elif standing:
            phase, standing = np.array([0.0, np.pi]), False
        q_h = np.array(DEFAULT) + rng.normal(0.0, 0.1, len(names))
        dq_h = rng.normal(0.0, 2.0, len(names))
        quat = np.array([1.0, *rng.normal(0.0, 0.1, 3)])
        quat /= np.linalg.norm(quat)
        omega = rng.normal(0.0, 0.5, 3)
        state.q[0, to_robot], state.dq[0, to_robot] = q_h, dq_h
        truth = np.concatenate([[0.0, 0.0, 0.75], quat, [0.3, 0.0, 0.0], omega])
        state.base.set_truth(truth[None])
        state.command[0] = command
        state.clock[0] = tick / 50.0
        spec.observation(state, np.zeros((1, 3)), out=obs)
        expected = holosoma_observation(q_h, dq_h, quat, omega, np.array(command), last, phase)
        np.testing.assert_allclose(obs[0], expected, rtol=0, atol=2e-6)
        action = policy(obs)
        spec.action_to_target(action, state, out=target)
        state.last_action[:] = action
        last = np.clip(action[0], -100.0, 100.0)
        np.testing.assert_allclose(
            target[0, to_robot], last * 0.25 + np.array(DEFAULT), rtol=0, atol=1e-6
        )
