"""Foreign ONNX as it is found in the wild, deployed with ``--spec`` on the shipped arm3.

Layouts: Godot RL Agents (``obs``, ``state_ins`` -> ``output``, ``state_outs``, opset 17), Isaac
Lab's ``policy.onnx`` (``obs`` -> ``actions``, batch fixed at 1, opset 11) and its recurrent form
(``obs``, ``h_in``, ``c_in`` -> ``actions``, ``h_out``, ``c_out``; a GRU with ``h`` only);
refusals of unknown inputs and of non-finite weights, acceptance of non-finite constants.

The Godot file ``tests/data/godot_rl_0.8.2_ppo_arm3.onnx`` (+ its ``.onnx.data``, as the exporter
wrote it) was written by the ``godot-rl`` package's own
``godot_rl.wrappers.onnx.stable_baselines_export.export_model_as_onnx`` (godot-rl 0.8.2, torch
2.15, SB3 2.9) from a PPO ``MultiInputPolicy`` (net_arch [16, 16], seed 3, biases drawn at
0.1 sigma) for the seed's 9-dim Godot arm. ``godot-rl`` is not a dependency: it pins
``stable-baselines3<=2.4`` and ``gymnasium<=1.0`` (which pin numpy < 2), which the project's stack
cannot install; the file was made with it installed beside the venv (``pip install --no-deps
--target``). The SB3 parity test builds the same graph in-process, with the exporter's module
(``OnnxablePolicy.forward_ppo``) and ``torch.onnx.export`` call reproduced below.

Isaac Lab's exporter (``isaaclab_rl.rsl_rl.exporter``) needs Isaac Sim; its module and export call
are reproduced below around real rsl_rl ``ActorCritic`` / ``ActorCriticRecurrent`` networks,
whose own ``act_inference`` is the reference.
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from onnx import TensorProto, helper, numpy_helper
from torch import nn

from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import PolicySpec
from tests.helpers_policies import (
    assert_ran,
    deploy_run,
    make_spec,
    random_walk,
    rsl_rl_actor_critic,
    write_spec,
)

REPO = Path(__file__).resolve().parent.parent
GODOT_FILE = REPO / "tests" / "data" / "godot_rl_0.8.2_ppo_arm3.onnx"
GODOT_SPEC = REPO / "docs" / "examples" / "godot_arm3.spec.json"
STEPS = 500
pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ---------------------------------------------------------------- Godot RL Agents
def _godot_reference(x: np.ndarray) -> np.ndarray:
    """The fixture's PPO action mean, recomputed in numpy from its own weights."""
    model = onnx.load(str(GODOT_FILE))  # reads the .onnx.data beside it
    w = {t.name: numpy_helper.to_array(t).astype(np.float64) for t in model.graph.initializer}
    p = "mlp_extractor.policy_net."
    h = np.tanh(x @ w[p + "0.weight"].T + w[p + "0.bias"])
    h = np.tanh(h @ w[p + "2.weight"].T + w[p + "2.bias"])
    return h @ w["action_net.weight"].T + w["action_net.bias"]


def test_godot_rl_file_written_by_its_exporter_loads_and_matches_its_weights(arm3):
    model = onnx.load(str(GODOT_FILE), load_external_data=False)
    assert model.opset_import[0].version == 17
    assert [i.name for i in model.graph.input] == ["obs", "state_ins"]
    assert [o.name for o in model.graph.output] == ["output", "state_outs"]
    policy = OnnxPolicy(GODOT_FILE, arm3, spec=GODOT_SPEC)
    assert policy.input_name == "obs" and policy.output_name == "output"
    assert not policy.recurrent and policy.obs_dim == 9 and policy.act_dim == 3
    walk = random_walk(STEPS, 9, seed=1)
    got = np.stack([policy(obs).copy() for obs in walk])
    np.testing.assert_allclose(got, _godot_reference(walk.astype(np.float64)), rtol=0, atol=1e-5)


def test_godot_rl_file_runs_through_deploy_run(tmp_path, capsys):
    code, out, err = deploy_run(capsys, GODOT_FILE, GODOT_SPEC)
    assert_ran(code, out, err)


class _GodotOnnxablePolicy(nn.Module):
    """godot-rl 0.8.2's ``OnnxablePolicy`` for PPO with a dict observation (``use_obs_array``
    False, the default): the action net on the shared extractor, ``state_ins`` passed through."""

    def __init__(self, policy):
        super().__init__()
        self.features_extractor = policy.features_extractor
        self.mlp_extractor = policy.mlp_extractor
        self.action_net = policy.action_net

    def forward(self, obs, state_ins):
        features = self.features_extractor(dict(zip(["obs"], obs, strict=True)))
        action_hidden, _ = self.mlp_extractor(features)
        return self.action_net(action_hidden), state_ins


@pytest.fixture(scope="module")
def godot_ppo(tmp_path_factory):
    """(SB3 PPO, ONNX path) of a Godot-style PPO exported the way godot-rl 0.8.2 exports it."""
    gym = pytest.importorskip("gymnasium")
    sb3 = pytest.importorskip("stable_baselines3")

    class GodotArm(gym.Env):  # the seed's Godot arm: {"obs": 9 floats}, 3 continuous actions
        observation_space = gym.spaces.Dict({"obs": gym.spaces.Box(-1, 1, (9,), np.float32)})
        action_space = gym.spaces.Box(-1, 1, (3,), np.float32)

    model = sb3.PPO(
        "MultiInputPolicy",
        GodotArm(),
        policy_kwargs={"net_arch": [16, 16]},
        seed=4,
        device="cpu",
    )
    with torch.no_grad():  # means well beyond [-1, 1]: the unclipped output is exercised
        g = torch.Generator().manual_seed(4)  # SB3 initializes the action net at gain 0.01
        model.policy.action_net.weight.copy_(torch.randn(3, 16, generator=g))
        model.policy.action_net.bias.copy_(torch.tensor([0.5, -0.5, 0.2]))
    model.policy.eval()
    path = tmp_path_factory.mktemp("godot") / "godot_ppo.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # godot-rl's call, argument for argument (torch's default exporter)
        torch.onnx.export(
            _GodotOnnxablePolicy(model.policy),
            args=([torch.zeros(1, 9)], torch.zeros(1).float()),
            f=str(path),
            opset_version=17,
            input_names=["obs", "state_ins"],
            output_names=["output", "state_outs"],
            dynamic_axes={
                "obs": {0: "batch_size"},
                "state_ins": {0: "batch_size"},
                "output": {0: "batch_size"},
                "state_outs": {0: "batch_size"},
            },
        )
    return model, path


def test_godot_layout_matches_sb3_over_500_steps_and_the_spec_clips_the_mean(godot_ppo, arm3):
    model, path = godot_ppo
    policy = OnnxPolicy(path, arm3, spec=GODOT_SPEC)
    spec = policy.spec
    walk = random_walk(STEPS, 9, seed=2)
    got, mean, sb3_action = [], [], []
    with torch.no_grad():
        for obs in walk:
            got.append(policy(obs).copy())
            dist = model.policy.get_distribution({"obs": torch.from_numpy(obs)})
            mean.append(dist.distribution.mean.numpy())
            sb3_action.append(model.predict({"obs": obs}, deterministic=True)[0])
    got, mean, sb3_action = np.stack(got), np.stack(mean), np.stack(sb3_action)
    np.testing.assert_allclose(got, mean, rtol=0, atol=1e-5)  # the unclipped mean
    assert np.abs(got).max() > 1.5  # ... really beyond the action space
    # the runtime's mapping clips per the spec: SB3's own (clipped) action times 3.14 rad/s
    from sim2real.deploy.core.state import RobotState

    state = RobotState.zeros(1, 3, 25.0)
    target = np.stack([spec.action_to_target(a, state) for a in got])
    np.testing.assert_allclose(target, 3.14 * sb3_action, rtol=0, atol=1e-5)


def test_godot_state_input_is_fed_zeros_and_its_output_ignored(godot_ppo, arm3):
    _, path = godot_ppo
    policy = OnnxPolicy(path, arm3, spec=GODOT_SPEC)
    obs = random_walk(4, 9, seed=5)[:, 0]
    batch = policy(obs).copy()  # dynamic batch: state_ins is [batch] zeros
    import onnxruntime as ort

    plain = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    ref, state = plain.run(None, {"obs": obs, "state_ins": np.zeros(4, np.float32)})
    np.testing.assert_array_equal(batch, ref)
    assert state.shape == (4,)


# ---------------------------------------------------------------- Isaac Lab / rsl_rl
class _IsaacLabOnnxPolicy(nn.Module):
    """Isaac Lab's ``_OnnxPolicyExporter``: the actor behind the empirical normalizer; for a
    recurrent policy the memory's RNN first, its state as explicit inputs and outputs."""

    def __init__(self, ac):
        super().__init__()
        self.actor, self.normalizer = ac.actor, ac.actor_obs_normalizer
        self.rnn = ac.memory_a.rnn if getattr(ac, "is_recurrent", False) else None

    def forward(self, x, *state):
        x = self.normalizer(x)
        if self.rnn is None:
            return self.actor(x)
        h = state if isinstance(self.rnn, nn.LSTM) else state[0]
        y, h = self.rnn(x.unsqueeze(0), h)
        return (self.actor(y.squeeze(0)), *(h if isinstance(h, tuple) else (h,)))


def _isaac_export(ac, obs_dim: int, path: Path) -> Path:
    """The export call of Isaac Lab's exporter: batch 1, no dynamic axes, opset 11."""
    net = _IsaacLabOnnxPolicy(ac).eval()
    args, ins, outs = (torch.zeros(1, obs_dim),), ["obs"], ["actions"]
    if net.rnn is not None:
        names = ("h", "c") if isinstance(net.rnn, nn.LSTM) else ("h",)
        args += tuple(torch.zeros(1, 1, net.rnn.hidden_size) for _ in names)
        ins += [f"{n}_in" for n in names]
        outs += [f"{n}_out" for n in names]
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net,
            args,
            buf,
            export_params=True,
            opset_version=11,
            input_names=ins,
            output_names=outs,
            dynamic_axes={},
            dynamo=False,  # Isaac Lab's files in the wild come from the TorchScript exporter
        )
    path.write_bytes(buf.getvalue())
    return path


@pytest.mark.parametrize("rnn", [None, "lstm", "gru"])
def test_isaac_lab_and_rsl_rl_onnx_match_rsl_rl_and_run_through_deploy_run(
    rnn, arm3, tmp_path, capsys
):
    spec = make_spec(arm3)
    spec_file = write_spec(spec, tmp_path / "spec.json")
    ac = rsl_rl_actor_critic(spec.obs_dim, spec.act_dim, rnn, normalizer=True)
    path = _isaac_export(ac, spec.obs_dim, tmp_path / "policy.onnx")
    assert onnx.load(str(path)).opset_import[0].version == 11
    policy = OnnxPolicy(path, arm3, spec=spec_file)
    assert policy.output_name == "actions" and len(policy.states) == {None: 0, "lstm": 2}.get(
        rnn, 1
    )
    walk = random_walk(STEPS, spec.obs_dim, seed=9)
    tensordict = pytest.importorskip("tensordict")
    ac.reset()
    worst = 0.0
    with torch.no_grad():
        for obs in walk:  # state carried by both sides
            td = tensordict.TensorDict({"policy": torch.from_numpy(obs)}, batch_size=[1])
            ref = ac.act_inference(td).numpy()
            worst = max(worst, float(np.abs(policy(obs) - ref).max()))
    assert worst <= 1e-5
    assert_ran(*deploy_run(capsys, path, spec_file))


# ---------------------------------------------------------------- extra inputs
def _graph_with(path: Path, nodes, inits, obs_dim: int = 21, act_dim: int = 3, extra=()) -> Path:
    """Save a graph of ``nodes``: input ``obs`` [batch, obs_dim] (then the value infos
    ``extra``), output ``action`` [batch, act_dim], opset 18."""
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", obs_dim]), *extra],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", act_dim])],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    onnx.save(model, str(path))
    return path


def _masked_graph(path: Path, obs_dim: int, act_dim: int, extra: str | None = "mask") -> Path:
    """action = tanh(obs W) + sum(mask) * 0.01: an extra [batch, 4] input besides ``obs``."""
    w = numpy_helper.from_array(np.full((obs_dim, act_dim), 0.05, np.float32), "W")
    nodes = [
        helper.make_node("MatMul", ["obs", "W"], ["h"]),
        helper.make_node("Tanh", ["h"], ["t"]),
    ]
    inputs, inits = [], [w]
    if extra:
        inputs.append(helper.make_tensor_value_info(extra, TensorProto.FLOAT, ["batch", 4]))
        inits.append(numpy_helper.from_array(np.array([1], np.int64), "axes"))
        inits.append(numpy_helper.from_array(np.array(0.01, np.float32), "k"))
        nodes += [
            helper.make_node("ReduceSum", [extra, "axes"], ["s"], keepdims=1),
            helper.make_node("Mul", ["s", "k"], ["sk"]),
            helper.make_node("Add", ["t", "sk"], ["action"]),
        ]
    else:
        nodes.append(helper.make_node("Identity", ["t"], ["action"]))
    return _graph_with(path, nodes, inits, obs_dim, act_dim, extra=inputs)


def test_unknown_extra_input_is_refused_naming_it_and_what_would_load_it(arm3, tmp_path, capsys):
    spec = make_spec(arm3)
    path = _masked_graph(tmp_path / "masked.onnx", spec.obs_dim, spec.act_dim)
    spec_file = write_spec(spec, tmp_path / "spec.json")
    with pytest.raises(PolicyLoadError) as err:
        OnnxPolicy(path, arm3, spec=spec_file)
    msg = str(err.value)
    assert "masked.onnx" in msg and "extra input(s) 'mask' ['batch', 4]" in msg
    assert '"constant_inputs": {"mask": VALUE}' in msg and "'<name>_in'" in msg
    code, _, stderr = deploy_run(capsys, path, spec_file)
    assert code == 3 and "'mask' ['batch', 4]" in stderr and "constant_inputs" in stderr


def test_constant_inputs_in_the_spec_feed_the_extra_input(arm3, tmp_path, capsys):
    spec = make_spec(arm3)
    d = json.loads(spec.to_json())
    d["constant_inputs"] = {"mask": 1.0}
    spec_file = tmp_path / "spec.json"
    spec_file.write_text(json.dumps(d))
    masked = OnnxPolicy(_masked_graph(tmp_path / "m.onnx", 21, 3), arm3, spec=spec_file)
    plain = OnnxPolicy(_masked_graph(tmp_path / "p.onnx", 21, 3, extra=None), arm3, spec=spec)
    obs = random_walk(3, 21, seed=4)[:, 0]
    np.testing.assert_allclose(masked(obs), plain(obs) + 0.04, rtol=0, atol=1e-6)
    assert_ran(*deploy_run(capsys, tmp_path / "m.onnx", spec_file, seconds=1.0))
    d["constant_inputs"] = {"mask": 1.0, "tau": 2.0}
    spec_file.write_text(json.dumps(d))
    with pytest.raises(PolicyLoadError, match=r"constant_inputs name \['tau'\], which the graph"):
        OnnxPolicy(tmp_path / "m.onnx", arm3, spec=spec_file)


def test_spec_whose_blocks_sum_to_another_size_exits_3_naming_the_blocks(tmp_path, capsys):
    path = GODOT_FILE  # 9 inputs
    d = json.loads(GODOT_SPEC.read_text())
    d["observation"].append({"name": "joint_velocity", "scale": 3.14})
    spec_file = tmp_path / "spec.json"
    spec_file.write_text(json.dumps(d))
    code, _, err = deploy_run(capsys, path, spec_file)
    assert code == 3
    assert (
        "graph input 'obs' has size 9, the spec's observation has 12 (joint_position 3 + "
        "ee_position 3 + goal_position 3 + joint_velocity 3" in err
    )


# ---------------------------------------------------------------- non-finite constants
def test_non_finite_constants_by_design_load_and_the_model_runs(arm3, tmp_path):
    """A masked max as attention does it: -inf where the mask is off, a NaN fill never
    selected, and the weights finite."""
    spec = make_spec(arm3)
    w = np.random.default_rng(0).normal(0, 0.2, (21, 3)).astype(np.float32)
    mask = np.ones((1, 3), bool)
    nodes = [
        helper.make_node("MatMul", ["obs", "W"], ["h"]),
        helper.make_node("Where", ["mask", "h", "neg_inf"], ["masked"]),
        helper.make_node("Where", ["never", "nan_fill", "masked"], ["picked"]),
        helper.make_node("Tanh", ["picked"], ["action"]),
    ]
    inits = [
        numpy_helper.from_array(w, "W"),
        numpy_helper.from_array(mask, "mask"),
        numpy_helper.from_array(np.array([-np.inf], np.float32), "neg_inf"),
        numpy_helper.from_array(np.full((1, 3), np.nan, np.float32), "nan_fill"),
        numpy_helper.from_array(np.zeros((1, 3), bool), "never"),
    ]
    path = _graph_with(tmp_path / "masked.onnx", nodes, inits)
    policy = OnnxPolicy(path, arm3, spec=spec)
    obs = random_walk(5, 21, seed=6)[:, 0]
    np.testing.assert_allclose(policy(obs), np.tanh(obs @ w), rtol=0, atol=1e-6)


def test_non_finite_weight_feeding_a_gemm_is_refused_naming_it(arm3, tmp_path):
    spec = make_spec(arm3)
    w = np.full((3, 21), 0.1, np.float32)
    w[2, 7] = np.inf
    nodes = [
        helper.make_node("Transpose", ["Wt"], ["W"], perm=[1, 0]),
        helper.make_node("Gemm", ["obs", "W"], ["action"]),
    ]
    path = _graph_with(tmp_path / "inf.onnx", nodes, [numpy_helper.from_array(w, "Wt")])
    with pytest.raises(
        PolicyLoadError,
        match=r"inf.onnx: initializer 'Wt' holds 1 non-finite value\(s\) .* feeds a Gemm",
    ):
        OnnxPolicy(path, arm3, spec=spec)


def test_a_model_judged_by_its_answers_over_the_specs_range(arm3, tmp_path):
    """Finite weights, finite at the zero observation, NaN at -1 (sqrt of a negative)."""
    spec = make_spec(arm3)
    w = np.full((21, 3), 0.1, np.float32)
    nodes = [
        helper.make_node("Sqrt", ["obs"], ["r"]),
        helper.make_node("MatMul", ["r", "W"], ["action"]),
    ]
    path = _graph_with(tmp_path / "sqrt.onnx", nodes, [numpy_helper.from_array(w, "W")])
    with pytest.raises(
        PolicyLoadError, match=r"sqrt.onnx: the action for the observation with every entry at -1"
    ):
        OnnxPolicy(path, arm3, spec=spec)


def test_the_godot_example_spec_is_the_seeds_observation(arm3):
    """angles / pi, end effector / 0.85 m, goal / 0.85 m (the Godot arm's ARM_REACH)."""
    from sim2real.deploy.core.state import Kinematics, RobotState

    spec = PolicySpec.from_json(GODOT_SPEC.read_text())
    state = RobotState.zeros(1, 3, 25.0)
    state.q[:] = [0.3, -0.7, 1.1]
    Kinematics(arm3).update(state)
    goal = np.array([[0.4, 0.2, 0.0]])
    obs = spec.observation(state, goal)[0]
    expected = np.concatenate([state.q[0] / np.pi, state.ee_position[0] / 0.85, goal[0] / 0.85])
    np.testing.assert_allclose(obs, expected, rtol=1e-6)


def test_a_spec_file_that_omits_every_optional_key_changes_nothing_the_policy_does(arm3, tmp_path):
    """A hand-written spec with only the required keys: no observation block and no action is
    clipped (before, a block left without ``clip`` was clipped to +-5 and the action to +-1, the
    schema's defaults, stated nowhere: a humanoid whose targets go past 1 fell), the scales are
    1 and the offsets 0, so the policy sees the raw quantity and its output reaches the target
    unchanged."""
    from sim2real.deploy.core.state import RobotState
    from sim2real.deploy.spec.policy_spec import UNCLIPPED

    doc = {
        "format_version": 1,
        "robot": "arm3",
        "joint_names": list(arm3.joint_names),
        "control_rate": 1.0 / arm3.control_period,
        "observation": [{"name": "joint_position", "scale": 0.01}],
        "action": {"mode": "position"},
    }
    spec_file = tmp_path / "spec.json"
    spec_file.write_text(json.dumps(doc))
    nodes = [helper.make_node("Mul", ["obs", "k"], ["action"])]
    inits = [numpy_helper.from_array(np.array([0.1], np.float32), "k")]
    policy = OnnxPolicy(_graph_with(tmp_path / "p.onnx", nodes, inits, 3, 3), arm3, spec=spec_file)
    assert policy.spec.action.clip == UNCLIPPED
    assert all(b.clip == UNCLIPPED for b in policy.spec.observation_blocks)
    state = RobotState.zeros(1, 3)
    state.q[:] = [[0.4, -0.3, 0.2]]
    obs = policy.spec.observation(state, np.zeros((1, 3)))
    np.testing.assert_allclose(obs[0], [40.0, -30.0, 20.0], rtol=1e-6)  # past the old 5
    action = policy(obs)
    np.testing.assert_allclose(action[0], [4.0, -3.0, 2.0], rtol=1e-6)  # past the old 1
    target = policy.spec.action_to_target(action, state)
    np.testing.assert_allclose(target[0], [4.0, -3.0, 2.0], rtol=1e-6)
