"""Recurrent policies end to end: rsl_rl ActorCriticRecurrent export with state I/O, OnnxPolicy's
per-env state and reset, the runtime's resets, foreign recurrent ONNX layouts, bad input.

The networks are small (LSTM/GRU of 16 units, a 16-unit actor layer); rsl_rl's own
``act_inference`` is the independent reference of the parity runs.
"""

from __future__ import annotations

import io
import warnings

import numpy as np
import onnx
import pytest
import torch
from onnx import TensorProto, helper, numpy_helper
from torch import nn

from sim2real.deploy.export import run_export
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.runtime import Mode, Runtime
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from tests.helpers_policies import (
    assert_ran,
    deploy_run,
    make_spec,
    random_walk,
    rsl_rl_actor_critic,
    write_spec,
)
from tests.soak_fixtures import kill_after_first_checkpoint, short_session

pytest.importorskip("rsl_rl.modules")
tensordict = pytest.importorskip("tensordict")
pytestmark = pytest.mark.usefixtures("one_torch_thread")

STEPS = 500
HIDDEN = 16


def rsl_rl_actions(ac, walk: np.ndarray, resets: dict[int, np.ndarray]) -> np.ndarray:
    """rsl_rl's own deterministic actions along ``walk`` (steps, envs, obs_dim), state carried,
    ``ac.reset(dones)`` at the given steps."""
    ac.reset()
    out = []
    with torch.no_grad():
        for t, obs in enumerate(walk):
            if t in resets:
                ac.reset(torch.from_numpy(resets[t].astype(np.int64)))
            td = tensordict.TensorDict({"policy": torch.from_numpy(obs)}, batch_size=[len(obs)])
            out.append(ac.act_inference(td).numpy().copy())
    return np.stack(out)


@pytest.fixture(scope="module", params=["lstm", "gru"])
def exported(request, arm3, tmp_path_factory):
    """(kind, actor-critic, ExportResult) of an rsl_rl recurrent checkpoint for arm3."""
    tmp = tmp_path_factory.mktemp(f"rsl_rl_{request.param}")
    spec = make_spec(arm3)
    ac = rsl_rl_actor_critic(spec.obs_dim, spec.act_dim, request.param, normalizer=True)
    src = tmp / "model_100.pt"
    torch.save({"model_state_dict": ac.state_dict(), "iter": 100}, src)
    result = run_export(src, tmp / "policy.onnx", spec=write_spec(spec, tmp / "spec.json"))
    return request.param, ac, result


# ---------------------------------------------------------------- export and parity
def test_rsl_rl_recurrent_export_passes_the_sequence_parity_gate(exported):
    kind, _, result = exported
    f = result.parity
    assert kind in result.source_format and result.source_format.startswith("rsl_rl recurrent")
    assert f["max_abs_error"] <= 1e-5 and f["replay_max_abs_error"] <= 1e-5
    assert f["samples"] >= 4 * STEPS and f["replay_ticks"] >= STEPS
    model = onnx.load(result.path)
    ins = [i.name for i in model.graph.input]
    outs = [o.name for o in model.graph.output]
    names = ("h", "c") if kind == "lstm" else ("h",)
    assert ins == ["obs", *(f"{n}_in" for n in names)]
    assert outs == ["action", *(f"{n}_out" for n in names)]


def test_exported_policy_matches_rsl_rl_over_500_steps_with_resets(exported, arm3):
    kind, ac, result = exported
    policy = OnnxPolicy(result.path, arm3)
    assert policy.recurrent and [s.input for s in policy.states][0] == "h_in"
    envs = 3
    walk = random_walk(STEPS, policy.obs_dim, seed=7, envs=envs)
    resets = {200: np.array([True, False, True]), 350: np.array([False, True, False])}
    ref = rsl_rl_actions(ac, walk, resets)
    policy.reset(np.ones(envs, dtype=bool))
    got = []
    for t, obs in enumerate(walk):
        if t in resets:
            policy.reset(resets[t])
        got.append(policy(obs).copy())
    clip = policy.spec.action.clip
    np.testing.assert_allclose(np.stack(got), np.clip(ref, -clip, clip), rtol=0, atol=1e-5)


def test_action_after_reset_equals_a_fresh_policys(exported, arm3):
    _, _, result = exported
    policy = OnnxPolicy(result.path, arm3)
    walk = random_walk(60, policy.obs_dim, seed=3, envs=2)
    for obs in walk[:50]:
        policy(obs)
    before = policy.state_dict()
    policy.reset(np.array([True, False]))
    after = policy(walk[50]).copy()
    fresh = OnnxPolicy(result.path, arm3)
    first = fresh(walk[50]).copy()
    np.testing.assert_array_equal(after[0], first[0])  # env 0: as fresh
    assert not np.array_equal(after[1], first[1])  # env 1 kept its state
    # state_dict / load_state_dict round trip, per env and whole
    policy.load_state_dict(before)
    np.testing.assert_array_equal(policy.state_dict()["h_in"], before["h_in"])
    one = policy.state_dict(1)
    assert one["h_in"].shape == (1, HIDDEN)
    with pytest.raises(ValueError, match="expected keys"):
        policy.load_state_dict({"nope": one["h_in"]}, 1)


def test_runtime_resets_the_state_on_ramp_in_take_over_and_fault_reset(exported, arm3):
    from sim2real.deploy.backends.sim.plant import SimBackend

    _, _, result = exported
    policy = OnnxPolicy(result.path, arm3)
    backend = SimBackend(arm3, mode=policy.spec.action.mode, envs=2, seed=0)
    calls = []
    reset = policy.reset
    policy.reset = lambda envs=None: (calls.append(np.array(envs)), reset(envs))[1]
    rt = Runtime(arm3, policy, backend)
    rt.start()
    assert calls and calls[0].tolist() == [True, True]  # start: every env enters RAMP_IN
    for _ in range(2000):
        rt.tick()
        if (rt.mode == Mode.RUNNING).all():
            break
    assert (rt.mode == Mode.RUNNING).all()
    assert any(c.any() for c in calls[1:])  # the policy took over from its initial state
    for _ in range(20):
        rt.tick()
    assert np.abs(policy.state_dict(1)["h_in"]).max() > 0
    rt.mode[1] = Mode.FAULTED
    calls.clear()
    rt.reset_faults(np.array([False, True]))
    assert calls[0].tolist() == [False, True] and rt.mode[1] == Mode.RAMP_IN
    assert not policy.state_dict(1)["h_in"].any() and policy.state_dict(0)["h_in"].any()


def test_deploy_run_with_the_exported_recurrent_policy(exported, tmp_path, capsys):
    _, _, result = exported
    report = tmp_path / "run.json"
    assert_ran(*deploy_run(capsys, result.path, report=report))
    assert report.is_file()


# ---------------------------------------------------------------- foreign layouts
class _RslRlOnnxLike(nn.Module):
    """The module rsl_rl's ``export_policy_to_onnx`` / Isaac Lab's ``export_policy_as_onnx``
    export for a recurrent LSTM actor: (obs, h_in, c_in) -> (actions, h_out, c_out)."""

    def __init__(self, obs_dim: int, act_dim: int):
        super().__init__()
        torch.manual_seed(5)
        self.rnn = nn.LSTM(obs_dim, HIDDEN, 1)
        self.mlp = nn.Sequential(nn.Linear(HIDDEN, HIDDEN), nn.ELU(), nn.Linear(HIDDEN, act_dim))

    def forward(self, obs, h_in, c_in):
        x, (h, c) = self.rnn(obs.unsqueeze(0), (h_in, c_in))
        return self.mlp(x.squeeze(0)), h, c


def test_rsl_rl_exporter_layout_loads_with_spec_and_carries_its_state(arm3, tmp_path):
    spec = make_spec(arm3)
    net = _RslRlOnnxLike(spec.obs_dim, spec.act_dim).eval()
    path = tmp_path / "policy.onnx"
    dummy = (torch.zeros(1, spec.obs_dim), torch.zeros(1, 1, HIDDEN), torch.zeros(1, 1, HIDDEN))
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # as rsl_rl's OnnxPolicyExporter calls it: fixed batch 1, no dynamic axes
        torch.onnx.export(
            net,
            dummy,
            buf,
            export_params=True,
            opset_version=18,
            input_names=["obs", "h_in", "c_in"],
            output_names=["actions", "h_out", "c_out"],
            dynamo=False,
        )
    path.write_bytes(buf.getvalue())
    policy = OnnxPolicy(path, arm3, spec=write_spec(spec, tmp_path / "spec.json"))
    assert policy.output_name == "actions" and len(policy.states) == 2
    walk = random_walk(STEPS, spec.obs_dim, seed=11)
    h, c = dummy[1], dummy[2]
    worst = 0.0
    with torch.no_grad():
        for obs in walk:
            ref, h, c = net(torch.from_numpy(obs), h, c)
            ref = np.clip(ref.numpy(), -1, 1)
            worst = max(worst, float(np.abs(np.clip(policy(obs), -1, 1) - ref).max()))
    assert worst <= 1e-5


def test_isaac_lab_obs_to_actions_loads_with_spec(arm3, tmp_path):
    spec = make_spec(arm3)
    net = nn.Sequential(nn.Linear(spec.obs_dim, 8), nn.ELU(), nn.Linear(8, spec.act_dim)).eval()
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net,
            (torch.zeros(1, spec.obs_dim),),
            buf,
            opset_version=18,
            input_names=["obs"],
            output_names=["actions"],
            dynamic_axes={"obs": {0: "batch"}, "actions": {0: "batch"}},
            dynamo=False,
        )
    path = tmp_path / "policy.onnx"
    path.write_bytes(buf.getvalue())
    policy = OnnxPolicy(path, arm3, spec=write_spec(spec, tmp_path / "spec.json"))
    assert not policy.recurrent and policy.output_name == "actions"
    policy.reset(np.ones(3, dtype=bool))  # no-op
    assert policy.state_dict() == {}
    obs = np.random.default_rng(0).uniform(-1, 1, (3, spec.obs_dim)).astype(np.float32)
    with torch.no_grad():
        np.testing.assert_allclose(policy(obs), net(torch.from_numpy(obs)).numpy(), atol=1e-6)


# ---------------------------------------------------------------- bad input
def _gru_like_onnx(
    path, obs_dim, act_dim, state_in, state_out, extra=None, out_name="h_out", in_name="h_in"
):
    """obs -> action = tanh(obs W); state output = state input + 0 (hand-made graph)."""
    w = numpy_helper.from_array(np.full((obs_dim, act_dim), 0.01, np.float32), "w")
    nodes = [
        helper.make_node("MatMul", ["obs", "w"], ["a"]),
        helper.make_node("Tanh", ["a"], ["action"]),
        helper.make_node("Identity", [in_name], [out_name]),
    ]
    inputs = [
        helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", obs_dim]),
        helper.make_tensor_value_info(in_name, TensorProto.FLOAT, state_in),
    ]
    if extra is not None:
        inputs.append(helper.make_tensor_value_info(extra, TensorProto.FLOAT, ["batch", 4]))
    graph = helper.make_graph(
        nodes,
        "g",
        inputs,
        [
            helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", act_dim]),
            helper.make_tensor_value_info(out_name, TensorProto.FLOAT, state_out),
        ],
        initializer=[w],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    onnx.save(model, path)
    return path


@pytest.mark.parametrize(
    "state_in, state_out, extra, message",
    [
        ([1, "batch", 8], [1, "batch", 9], None, "state output 'h_out' has shape [1, 'batch', 9]"),
        ([1, 8], [1, 8], None, "state input 'h_in' has shape [1, 8]: no batch axis"),
        ([1, 1, 8], [1, 1, 8], None, "state input 'h_in' has shape [1, 1, 8]: no batch axis"),
        ([1, "batch", 8], [1, "batch", 8], "mask", "extra input(s) 'mask' ['batch', 4]"),
    ],
)
def test_bad_recurrent_onnx_is_refused_naming_file_and_tensor(
    arm3, tmp_path, state_in, state_out, extra, message
):
    spec = make_spec(arm3)
    path = _gru_like_onnx(
        tmp_path / "bad.onnx", spec.obs_dim, spec.act_dim, state_in, state_out, extra
    )
    spec_file = write_spec(spec, tmp_path / "spec.json")
    with pytest.raises(PolicyLoadError) as err:
        OnnxPolicy(path, arm3, spec=spec_file)
    assert str(path) in str(err.value) and message in str(err.value)
    if extra:
        assert "'<name>_in'" in str(err.value)  # what would make it load


def test_state_output_shape_that_differs_only_when_run_is_refused(arm3, tmp_path):
    spec = make_spec(arm3)
    path = _gru_like_onnx(
        tmp_path / "bad.onnx", spec.obs_dim, spec.act_dim, [1, "batch", 8], [1, "batch", "n"]
    )
    model = onnx.load(path)
    model.graph.node[2].op_type = "Concat"  # h_out = concat(h_in, h_in) on the hidden axis
    model.graph.node[2].input.append("h_in")
    model.graph.node[2].attribute.append(helper.make_attribute("axis", 2))
    onnx.save(model, path)
    with pytest.raises(PolicyLoadError, match=r"state output 'h_out' has shape \[1, 1, 16\]"):
        OnnxPolicy(path, arm3, spec=write_spec(spec, tmp_path / "spec.json"))


def test_deploy_run_exits_3_on_a_state_input_without_batch_axis(arm3, tmp_path, capsys):
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    spec = make_spec(arm3)
    path = _gru_like_onnx(tmp_path / "bad.onnx", spec.obs_dim, spec.act_dim, [1, 8], [1, 8])
    spec_file = write_spec(spec, tmp_path / "spec.json")
    code = deploy_run_main(
        ["--robot", "arm3", "--policy", str(path), "--spec", str(spec_file), "--duration", "1"]
    )
    err = capsys.readouterr().err
    assert code == 3 and str(path) in err and "'h_in'" in err and "no batch axis" in err


# ---------------------------------------------------------------- soak: kill and resume
def test_soak_with_a_recurrent_policy_resumes_exactly_after_kill(exported, tmp_path):

    from sim2real.eval.soak import checkpoint as ckpt
    from sim2real.eval.soak.batch import SessionBatch
    from sim2real.eval.soak.campaign import run_campaign
    from sim2real.eval.soak.session import session_dir
    from sim2real.robots import load_robot

    kind, ac, _ = exported
    if kind != "lstm":
        pytest.skip("one recurrent kind is enough for the soak")
    # small actions: the arm moves without saturating the guard, so that the trajectory (and the
    # result) depends on every action, hence on the restored state
    gentle = {k: v.clone() for k, v in ac.state_dict().items()}
    last = max(int(k.split(".")[1]) for k in gentle if k.startswith("actor.") and "weight" in k)
    for name in ("weight", "bias"):
        gentle[f"actor.{last}.{name}"] *= 0.2
    src = tmp_path / "gentle.pt"
    torch.save({"model_state_dict": gentle}, src)
    spec_file = write_spec(make_spec(load_robot("arm3")), tmp_path / "spec.json")
    policy_file = run_export(src, tmp_path / "gentle.onnx", spec=spec_file).path
    config = short_session("arm3", policy_file, 8.0 / 3600.0)
    (whole,) = SessionBatch([config], tmp_path / "whole").run()
    out = tmp_path / "campaign"
    kill_after_first_checkpoint(config, out)
    arrays, meta = ckpt.read_checkpoint(session_dir(out, config.seed))
    assert arrays["policy/h_in"].shape == (1, HIDDEN) and "policy/c_in" in arrays
    assert 0 < meta["tick"] < 1600
    (resumed,) = run_campaign(config, 1, out, resume=True, progress=False)
    assert {k: v for k, v in resumed.items() if k != "wall"} == {
        k: v for k, v in whole.items() if k != "wall"
    }


def test_the_files_declared_initial_state_is_used_on_reset(arm3, tmp_path):
    spec = make_spec(arm3)
    path = _gru_like_onnx(
        tmp_path / "init.onnx", spec.obs_dim, spec.act_dim, [1, "batch", 8], [1, "batch", 8]
    )
    model = onnx.load(path)
    model.graph.initializer.append(
        numpy_helper.from_array(np.full((1, 1, 8), 0.5, np.float32), "h_in")
    )
    onnx.save(model, path)
    policy = OnnxPolicy(path, arm3, spec=write_spec(spec, tmp_path / "spec.json"))
    policy.reset(np.ones(2, dtype=bool))
    np.testing.assert_array_equal(policy.state_dict()["h_in"], np.full((1, 2, 8), 0.5))
