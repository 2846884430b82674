"""A policy over part of a robot's joints (unitree_rl_gym's 12-joint G1 policy on the 29-joint
G1): the joints it does not drive are held at home, the rest of the runtime is unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers_policies import linear_onnx

from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError

#: The six joints the test's policy drives, in its own (not the robot's) order.
DRIVEN = (
    "RR_calf_joint",
    "FL_hip_joint",
    "FL_thigh_joint",
    "FL_calf_joint",
    "RR_hip_joint",
    "RR_thigh_joint",
)


def narrow_spec(go2) -> dict:
    """A spec over six of the Go2's twelve joints, as another stack writes one for its robot."""
    home = [float(go2.home[go2.joint_names.index(j)]) for j in DRIVEN]
    return {
        "format_version": 1,
        "robot": "go2",
        "joint_names": list(DRIVEN),
        "control_rate": 50.0,
        "observation": [
            {"name": "projected_gravity"},
            {"name": "joint_position", "offset": home},
            {"name": "joint_velocity", "scale": 20.0},
            {"name": "last_action"},
        ],
        "action": {"mode": "position", "offset": home, "scale": 0.25, "clip": 100.0},
    }


@pytest.fixture
def subset_policy(go2, tmp_path):
    """(OnnxPolicy, weight, bias) of a linear policy over ``DRIVEN`` loaded on the Go2."""
    spec = narrow_spec(go2)
    obs_dim = 3 + 3 * len(DRIVEN)
    rng = np.random.default_rng(3)
    weight = rng.normal(0.0, 0.05, (obs_dim, len(DRIVEN)))
    bias = np.linspace(-0.3, 0.3, len(DRIVEN))
    path = tmp_path / "six.onnx"
    path.write_bytes(linear_onnx(weight, bias).SerializeToString())
    spec_path = tmp_path / "six.json"
    spec_path.write_text(json.dumps(spec))
    return OnnxPolicy(path, go2, spec_path), weight, bias


def test_the_policy_drives_its_joints_and_the_others_get_action_zero(go2, subset_policy):
    policy, weight, bias = subset_policy
    assert policy.spec.joint_names == go2.joint_names
    assert policy.policy_joints == DRIVEN
    assert policy.act_dim == go2.n_joints and policy.obs_dim == 3 + 18
    obs = np.random.default_rng(0).normal(size=(2, policy.obs_dim)).astype(np.float32)
    action = policy(obs)
    graph = obs @ weight.astype(np.float32) + bias.astype(np.float32)
    for k, name in enumerate(DRIVEN):
        np.testing.assert_allclose(action[:, go2.joint_names.index(name)], graph[:, k], rtol=1e-5)
    held = [i for i, j in enumerate(go2.joint_names) if j not in DRIVEN]
    assert not action[:, held].any()


def test_held_joints_target_home_and_driven_joints_their_own_mapping(go2, subset_policy):
    from sim2real.deploy.core.state import RobotState

    policy, _, _ = subset_policy
    spec = policy.spec
    state = RobotState.legged(1, go2.n_joints, go2.n_feet)
    action = np.full((1, go2.n_joints), 0.0, np.float32)
    for name in DRIVEN:
        action[0, go2.joint_names.index(name)] = 0.4
    target = spec.action_to_target(action, state)
    for i, name in enumerate(go2.joint_names):
        expected = go2.home[i] + (0.25 * 0.4 if name in DRIVEN else 0.0)
        assert target[0, i] == pytest.approx(expected, abs=1e-7), name


def test_the_observation_reads_the_policys_joints_in_its_order(go2, subset_policy):
    from sim2real.deploy.core.state import RobotState

    policy, _, _ = subset_policy
    state = RobotState.legged(1, go2.n_joints, go2.n_feet)
    state.q[0] = np.arange(go2.n_joints) * 0.01
    state.dq[0] = np.arange(go2.n_joints) * 0.1
    state.base.projected_gravity[0] = [0.0, 0.0, -1.0]
    state.last_action[0] = np.arange(go2.n_joints) * 0.05
    obs = policy.spec.observation(state, np.zeros((1, 3)))[0]
    index = [go2.joint_names.index(j) for j in DRIVEN]
    home = go2.home[index]
    np.testing.assert_allclose(obs[3:9], state.q[0, index] - home, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(obs[9:15], state.dq[0, index] / 20.0, rtol=1e-6)
    np.testing.assert_allclose(obs[15:21], state.last_action[0, index], rtol=1e-6)


def test_a_joint_the_robot_lacks_is_refused_by_name(go2):
    spec = narrow_spec(go2)
    spec["joint_names"][0] = "waist_yaw_joint"
    narrow = PolicySpec.from_json(json.dumps(spec))
    with pytest.raises(SpecError, match="no joint 'waist_yaw_joint'"):
        narrow.on_robot(go2)


def test_the_runtime_holds_the_undriven_joints_at_home_under_the_guard(go2, subset_policy):
    """The whole runtime on the simulated Go2: after the bring-up the held joints' guarded
    targets stay at home while the policy moves the others."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.runtime import RUNNING, Runtime

    policy, _, _ = subset_policy
    plant = SimBackend(go2, "position", envs=1, seed=0)
    rt = Runtime(go2, policy, plant)
    rt.start()
    held = [i for i, j in enumerate(go2.joint_names) if j not in DRIVEN]
    driven = [go2.joint_names.index(j) for j in DRIVEN]
    moved = 0.0
    for _ in range(round(1.0 / rt.dt)):
        rt.tick()
        if rt.mode[0] == RUNNING:
            np.testing.assert_allclose(rt.target[0, held], go2.home[held], atol=1e-9)
            moved = max(moved, float(np.abs(rt.target[0, driven] - go2.home[driven]).max()))
    assert moved > 0.01
