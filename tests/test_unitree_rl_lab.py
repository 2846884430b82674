"""unitree_rl_lab's published policy folder read as its own C++ deployment reads it, no hand work.

unitreerobotics/unitree_rl_lab ships ``deploy/robots/<robot>/config/policy/velocity/v0/`` with
``exported/policy.onnx`` (Isaac Lab's exporter: ``obs`` -> ``actions``, opset 11, batch 1, the
weights inside) and ``params/deploy.yaml``, written by its ``utils/export_deploy_cfg.py`` (read,
not copied): ``joint_ids_map`` the SDK (motor slot) index of each articulation joint, Isaac Lab's
breadth-first order (left and right legs interleaved); ``stiffness`` / ``damping`` laid out in
the SDK order (``stiffness[joint_ids_map] = ...``; the C++ ``ArticulationData`` comments them
"sdk order" and sets ``motor_cmd[i].kp = stiffness[i]``); ``default_joint_pos``, scales and
offsets in the articulation order; numbers at 3 significant figures; ``yaml.dump`` (not the safe
dumper), so the action's ``joint_ids`` (``slice(None)``) carries
``!!python/object/apply:builtins.slice``; every observation term ``history_length: 5`` on the G1.

Their C++ deployment (``deploy/include/isaaclab``): per term an ``ObservationTermCfg`` deque
filled with ``history_length`` copies of the reading at ``reset`` (the policy's start), each tick
the reading pushed and the oldest dropped, and the deque given clipped then scaled, the oldest
first, term after term; the action ``raw * scale + offset`` written to ``motor_cmd[joint_ids_map
[i]].q``. The robot is a small biped whose description order is its motor slots (``unitree_hg``).
"""

from __future__ import annotations

import io
import warnings
from collections import deque

import numpy as np
import onnx
import pytest
import torch
import yaml

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from tests import foreign_stacks as fs
from tests.test_frame_history import euler_state
from tests.test_import_humanoid import MOTORS, write_humanoid

#: The biped's SDK order (its description order, the ``unitree_hg`` motor slots).
SDK = tuple(
    f"{s}_{p}_joint" for s in ("left", "right") for p in ("hip_roll", "hip_pitch", "knee", "ankle")
)
#: Isaac Lab's articulation order of the same joints: breadth first, the legs interleaved.
ISAAC = tuple(
    f"{s}_{p}_joint" for p in ("hip_roll", "hip_pitch", "knee", "ankle") for s in ("left", "right")
)
#: Per joint part: stiffness N m/rad, damping N m s/rad, default position rad (distinct values,
#: so a list read in the wrong order cannot pass).
PARTS = {"hip_roll": (90.0, 2.0, 0.0), "hip_pitch": (100.0, 2.5, -0.1), "knee": (150.0, 4.0, 0.3),
         "ankle": (40.0, 1.0, -0.2)}  # fmt: skip
HISTORY = 5
#: The G1 velocity policy's terms (its deploy.yaml): name -> (entries, scale); -1: one per joint.
TERMS = {"base_ang_vel": (3, 0.2), "projected_gravity": (3, 1.0), "velocity_commands": (3, 1.0),
         "joint_pos_rel": (-1, 1.0), "joint_vel_rel": (-1, 0.05), "last_action": (-1, 1.0)}  # fmt: skip


def _part(name: str) -> str:
    return name.split("_", 1)[1].removesuffix("_joint")


def _three(x):
    """``export_deploy_cfg.format_value``: a float at 3 significant figures, lists through."""
    if isinstance(x, float):
        return float(f"{x:.3g}")
    if isinstance(x, list):
        return [_three(v) for v in x]
    if isinstance(x, dict):
        return {k: _three(v) for k, v in x.items()}
    return x


def rl_lab_deploy(clip_ang_vel=None) -> dict:
    """deploy.yaml as ``export_deploy_cfg`` builds it for the biped (module docstring)."""
    n = len(ISAAC)
    ids_map = [SDK.index(name) for name in ISAAC]
    stiffness, damping = np.zeros(n), np.zeros(n)
    stiffness[ids_map] = [PARTS[_part(j)][0] for j in ISAAC]
    damping[ids_map] = [PARTS[_part(j)][1] for j in ISAAC]
    default = [PARTS[_part(j)][2] for j in ISAAC]
    obs = {}
    for name, (size, scale) in TERMS.items():
        size = n if size < 0 else size
        params = {"command_name": "base_velocity"} if name == "velocity_commands" else {}
        obs[name] = {
            "params": params,
            "clip": None,
            "scale": [scale] * size,
            "history_length": HISTORY,
        }
    obs["base_ang_vel"]["clip"] = clip_ang_vel
    ranges = {
        "lin_vel_x": [-0.5, 1.0],
        "lin_vel_y": [-0.3, 0.3],
        "ang_vel_z": [-0.2, 0.2],
        "heading": None,
    }
    action = {"clip": None, "joint_names": [".*"], "scale": [0.25] * n, "offset": default,
              "joint_ids": slice(None)}  # fmt: skip
    cfg = {"joint_ids_map": ids_map, "step_dt": 0.02, "stiffness": stiffness.tolist(),
           "damping": damping.tolist(), "default_joint_pos": default,
           "commands": {"base_velocity": {"ranges": ranges}},
           "actions": {"JointPositionAction": action}, "observations": obs}  # fmt: skip
    return _three(cfg)


def write_rl_lab_policy(folder, cfg: dict, bias) -> tuple:
    """``<folder>/params/deploy.yaml`` (``yaml.dump``) and ``<folder>/exported/policy.onnx``
    (``obs`` -> ``actions``, opset 11, batch 1, weights inside): (ONNX path, observation size)."""
    n = len(cfg["joint_ids_map"])
    obs_dim = HISTORY * (9 + 3 * n)
    (folder / "params").mkdir(parents=True)
    (folder / "params" / "deploy.yaml").write_text(
        yaml.dump(cfg, default_flow_style=None, sort_keys=False)
    )
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            fs.Actor(obs_dim, n, 4, 1e-3, bias).eval(), (torch.zeros(1, obs_dim),), buf,
            export_params=True, opset_version=11, input_names=["obs"], output_names=["actions"],
            dynamic_axes={}, dynamo=False,
        )  # fmt: skip
    path = folder / "exported" / "policy.onnx"
    path.parent.mkdir()
    path.write_bytes(buf.getvalue())
    return path, obs_dim


class TermHistory:
    """One ``ObservationTermCfg``: a deque of ``history_length`` readings; ``get`` clips then
    scales each entry, the oldest reading first."""

    def __init__(self, cfg: dict):
        self.length, self.clip = cfg["history_length"], cfg["clip"]
        self.scale = np.float32(cfg["scale"])
        self.buffer = deque()

    def reset(self, reading) -> None:
        for _ in range(self.length):
            self.add(reading)

    def add(self, reading) -> None:
        self.buffer.append(np.float32(reading))
        if len(self.buffer) > self.length:
            self.buffer.popleft()

    def get(self) -> np.ndarray:
        out = []
        for reading in self.buffer:
            value = reading if self.clip is None else np.clip(reading, *np.float32(self.clip))
            out.append(value * self.scale)
        return np.concatenate(out)


@pytest.fixture(scope="module")
def biped_and_policy(tmp_path_factory):
    """The biped imported with robot-level flags only and ``--drive-from`` the policy folder."""
    from sim2real.deploy.cli.robot_import import main
    from sim2real.robots import load_robot

    tmp = tmp_path_factory.mktemp("rl_lab")
    cfg = rl_lab_deploy(clip_ang_vel=[-3.0, 3.0])
    bias = np.linspace(-0.5, 0.5, len(ISAAC))
    path, obs_dim = write_rl_lab_policy(tmp / "v0", cfg, bias)
    source = write_humanoid(tmp)
    flags = ["--floating-base", "--unitree", "unitree_hg", "--unitree-damping-kd", "2"]
    motors = [a for m in MOTORS for a in ("--motor", m)]
    out = tmp / "robots" / "biped"
    assert main([str(source), *flags, *motors, "--drive-from", str(path), "--out", str(out)]) == 0
    return load_robot(out), path, obs_dim, cfg


def test_robot_import_reads_the_gains_in_the_motor_slots_order(biped_and_policy):
    """Each joint's kp and kd are its own (a hip pitch 100, a knee 150, ...), read through the
    SDK order the file lays them out in; the home is the default pose, joint by joint."""
    robot, _, _, _ = biped_and_policy
    assert robot.joint_names == SDK
    by_joint = [PARTS[_part(j)] for j in SDK]
    assert [j.kp for j in robot.config.joints] == [p[0] for p in by_joint]
    assert [j.kd for j in robot.config.joints] == [p[1] for p in by_joint]
    np.testing.assert_allclose(robot.home, [p[2] for p in by_joint])


def test_the_observation_and_targets_are_their_deployments_through_a_reset(biped_and_policy):
    """The published layout loads with no --spec (the slice tag read), its history is per term,
    oldest first, filled with the first reading; the observation equals the C++ deployment's
    tick by tick through a reset (an angular velocity past its clip), and the PD target of
    motor slot ``joint_ids_map[i]`` is ``raw[i] * scale + offset[i]``."""
    robot, path, obs_dim, cfg = biped_and_policy
    policy = OnnxPolicy(path, robot)
    spec = policy.spec
    assert policy.foreign.format == "unitree_deploy"
    history = spec.history
    assert (history.length, history.layout, history.order, history.fill) == (
        HISTORY, "per_term", "oldest_first", "first",
    )  # fmt: skip
    ids_map = cfg["joint_ids_map"]
    default = np.asarray(cfg["default_joint_pos"])
    readings = {  # the C++ observation functions, the joints read at motor_state[joint_ids_map[i]]
        "base_ang_vel": lambda s: s.base.angular_velocity[0],
        "projected_gravity": lambda s: s.base.projected_gravity[0],
        "velocity_commands": lambda s: s.command[0],
        "joint_pos_rel": lambda s: s.q[0, ids_map] - default,
        "joint_vel_rel": lambda s: s.dq[0, ids_map],
        "last_action": lambda s: s.last_action[0, ids_map],
    }
    terms = {name: TermHistory(term) for name, term in cfg["observations"].items()}
    rng = np.random.default_rng(11)
    for tick in range(13):
        state = euler_state(robot, rng, (0.05, -0.1, 0.2))
        state.base.angular_velocity[:] = rng.uniform(-9, 9, (1, 3))
        if tick in (0, 8):
            spec.plan.reset_history()
            for name, term in terms.items():
                term.reset(readings[name](state))
        for name, term in terms.items():
            term.add(readings[name](state))
        theirs = np.concatenate([term.get() for term in terms.values()])
        ours = spec.observation(state, np.zeros((1, 3)))[0]
        assert ours.shape == (obs_dim,)
        np.testing.assert_allclose(ours, theirs, rtol=2e-7, atol=1e-6, err_msg=f"tick {tick}")
    raw = fs.run_graph(path, ours[None])[0]  # the graph in their order
    action = policy(ours[None]).copy()  # ours, in the robot's joint order
    target = spec.action_to_target(action, RobotState.legged(1, len(SDK), robot.n_feet))[0]
    theirs = np.zeros(len(SDK))
    theirs[ids_map] = raw * 0.25 + default  # motor_cmd[joint_ids_map[i]].q
    np.testing.assert_allclose(target, theirs, atol=1e-5)


def test_a_python_tag_other_than_the_slice_and_a_subset_of_joints_are_refused(
    tmp_path, biped_and_policy
):
    """Only the slice tag is built (any other Python object stays refused by the safe loader);
    an action over a subset of the joints is refused naming the key."""
    from sim2real.deploy.policy.onnx_policy import PolicyLoadError

    robot = biped_and_policy[0]
    cfg = rl_lab_deploy()
    cfg["actions"]["JointPositionAction"]["joint_ids"] = [0, 1, 2]
    path, _ = write_rl_lab_policy(tmp_path / "v1", cfg, None)
    with pytest.raises(PolicyLoadError, match=r"JointPositionAction.joint_ids \[0, 1, 2\]"):
        OnnxPolicy(path, robot)
    yaml_path = path.parent.parent / "params" / "deploy.yaml"
    yaml_path.write_text(
        yaml_path.read_text().replace(
            "joint_ids: [0, 1, 2]", "joint_ids: !!python/object/apply:os.getcwd []"
        )
    )
    with pytest.raises(PolicyLoadError, match=r"deploy.yaml: not readable as YAML"):
        OnnxPolicy(path, robot)
    assert onnx.load(str(path)).opset_import[0].version == 11


def test_policy_export_of_the_folder_keeps_its_training_domain(tmp_path, biped_and_policy, capsys):
    """``policy-export POLICY.onnx --robot R --domain FILE``: one file with our spec and the
    domain the soak runs (the ``--domain`` of another stack's ONNX was dropped without a word)."""
    from sim2real.deploy.cli.policy_export import main as policy_export_main
    from sim2real.eval.world.domain import METADATA_KEY

    robot, path, _, _ = biped_and_policy
    domain = tmp_path / "domain.toml"
    domain.write_text("floor_friction = [0.3, 1.0]\n\n[pushes]\ninterval = [5.0, 5.0]\n")
    out = tmp_path / "policy.biped.onnx"
    argv = [str(path), "--robot", str(robot.directory), "--domain", str(domain), "--out", str(out)]
    assert policy_export_main(argv) == 0
    assert "training domain from" in capsys.readouterr().out
    metadata = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert metadata[METADATA_KEY] == domain.read_text() and "policy_spec" in metadata
    assert OnnxPolicy(out, robot).foreign is None  # our spec now, no deploy.yaml read
