"""Export of recurrent sources made by other projects, and ``policy-export --inspect``.

- legged_gym / unitree_rl_gym's ``PolicyExporterLSTM`` TorchScript: an rsl_rl
  ``ActorCriticRecurrent`` wrapped the way ``legged_gym/utils/helpers.py`` wraps it (deep copies of
  ``actor`` and ``memory_a.rnn``, buffers ``hidden_state`` / ``cell_state`` of shape
  (layers, 1, hidden) updated in place by ``forward``, ``reset_memory`` exported) and written with
  ``torch.jit.script(...).save``. The reference is the saved file itself, called at batch 1.
- SB3-contrib ``RecurrentPPO`` (``MlpLstmPolicy``) saved with ``model.save``; the reference is
  sb3-contrib's own ``model.predict(obs, state=..., episode_start=..., deterministic=True)``.

Networks are small (LSTM of 16 units); each export is then run through ``deploy-run`` on arm3.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from torch import nn

from sim2real.deploy.cli.policy_export import main as export_main
from sim2real.deploy.export import ExportError, run_export
from sim2real.deploy.export.errors import InspectError
from sim2real.deploy.export.inspect_policy import inspect_file
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from tests import helpers_policies as helpers
from tests.helpers_policies import (
    PlainNet,
    PolicyExporterLSTM,
    assert_ran,
    make_spec,
    random_walk,
    write_spec,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")

STEPS = 500
HIDDEN = 16


def rsl_rl_recurrent(obs_dim: int, act_dim: int, seed: int = 0):
    """A small rsl_rl ActorCriticRecurrent (LSTM) as legged_gym trains it (no normalizer)."""
    return helpers.rsl_rl_actor_critic(obs_dim, act_dim, seed=seed)


def deploy_run(policy_path, tmp_path, capsys) -> None:
    """A few simulated seconds of ``deploy-run`` on arm3 with the exported policy."""
    report = tmp_path / "run.json"
    assert_ran(*helpers.deploy_run(capsys, policy_path, report=report))
    assert report.is_file()


def script_save(module: nn.Module, path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.jit.script(module).save(str(path))
    return path


@pytest.fixture(scope="module")
def legged_gym_file(arm3, tmp_path_factory):
    """(TorchScript path, spec path) of a PolicyExporterLSTM file for arm3."""
    tmp = tmp_path_factory.mktemp("legged_gym")
    spec = make_spec(arm3)
    ac = rsl_rl_recurrent(spec.obs_dim, spec.act_dim)
    path = script_save(PolicyExporterLSTM(ac), tmp / "policy_lstm_1.pt")
    return path, write_spec(spec, tmp / "spec.json")


@pytest.fixture(scope="module")
def legged_gym_onnx(legged_gym_file):
    src, spec = legged_gym_file
    out = src.with_name("policy_lstm_1.onnx")
    assert export_main([str(src), "--spec", str(spec), "--out", str(out)]) == 0
    return out


def test_legged_gym_lstm_export_lifts_the_buffers_into_state_io(legged_gym_onnx, arm3):
    policy = OnnxPolicy(legged_gym_onnx, arm3)
    assert [(s.input, s.output, s.layers, s.hidden) for s in policy.states] == [
        ("h_in", "h_out", 1, HIDDEN),
        ("c_in", "c_out", 1, HIDDEN),
    ]
    f = policy.parity
    assert f["source_steps"] >= STEPS and f["source_max_abs_error"] <= 1e-5
    assert f["max_abs_error"] <= 1e-5 and f["replay_max_abs_error"] <= 1e-5
    assert policy.metadata["source_format"].startswith("legged_gym PolicyExporterLSTM")
    # the batch axis is real: 3 envs each carry their own state
    policy.reset(np.ones(3, dtype=bool))
    assert policy.state_dict()["h_in"].shape == (1, 3, HIDDEN)


def test_legged_gym_onnx_matches_the_stateful_file_over_500_steps(
    legged_gym_file, legged_gym_onnx, arm3
):
    src, _ = legged_gym_file
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        source = torch.jit.load(str(src))
    policy = OnnxPolicy(legged_gym_onnx, arm3)
    walk = random_walk(STEPS + 100, policy.obs_dim, seed=5)
    policy.reset(np.ones(1, dtype=bool))
    got, ref = [], []
    with torch.no_grad():
        for t, obs in enumerate(walk):
            if t == 300:  # an episode ends: legged_gym's reset_memory, our reset
                source.reset_memory()
                policy.reset(np.ones(1, dtype=bool))
            ref.append(np.clip(source(torch.from_numpy(obs)).numpy(), -1.0, 1.0))
            got.append(policy(obs).copy())
    assert np.abs(np.stack(ref)).max() > 0.05  # the comparison is not between zeros
    np.testing.assert_allclose(np.stack(got), np.stack(ref), rtol=0, atol=1e-5)
    # the state matters: the last observation alone, from a zero state, answers differently
    policy.reset(np.ones(1, dtype=bool))
    assert np.abs(policy(walk[-1]) - got[-1]).max() > 1e-3


def test_deploy_run_with_the_legged_gym_export(legged_gym_onnx, tmp_path, capsys):
    deploy_run(legged_gym_onnx, tmp_path, capsys)


class SquashingExporter(PolicyExporterLSTM):
    """The layout, but a forward that does more than ``actor(memory(x))``."""

    def forward(self, x):
        out, (h, c) = self.memory(x.unsqueeze(0), (self.hidden_state, self.cell_state))
        self.hidden_state[:] = h
        self.cell_state[:] = c
        return torch.tanh(2.0 * self.actor(out.squeeze(0)))


def test_a_file_that_does_not_behave_as_its_layout_fails_the_source_parity(
    arm3, tmp_path, legged_gym_file
):
    _, spec_file = legged_gym_file
    spec = make_spec(arm3)
    ac = rsl_rl_recurrent(spec.obs_dim, spec.act_dim, seed=1)
    src = script_save(SquashingExporter(ac), tmp_path / "squash.pt")
    out = tmp_path / "squash.onnx"
    assert export_main([str(src), "--spec", str(spec_file), "--out", str(out)]) == 1
    assert not out.exists()


class CountingPolicy(nn.Module):
    """Stateful in a way we do not recognise: a step counter buffer that shifts the action."""

    def __init__(self, obs_dim: int, act_dim: int):
        super().__init__()
        self.net = nn.Linear(obs_dim, act_dim)
        self.register_buffer("steps", torch.zeros(1))

    def forward(self, x):
        self.steps.add_(1.0)  # in place: the buffer changes, no attribute is assigned
        return self.net(x) + 0.01 * self.steps


class AssigningPolicy(CountingPolicy):
    """Stateful by assigning the attribute (``prim::SetAttr`` in the graph)."""

    def forward(self, x):
        self.steps = self.steps + 1.0
        return self.net(x) + 0.01 * self.steps


class GruExporter(nn.Module):
    """legged_gym's buffer names around a GRU (their exporter assumes an LSTM)."""

    def __init__(self, obs_dim: int, act_dim: int):
        super().__init__()
        self.memory = nn.GRU(obs_dim, HIDDEN)
        self.actor = nn.Sequential(nn.Linear(HIDDEN, act_dim))
        self.register_buffer("hidden_state", torch.zeros(1, 1, HIDDEN))
        self.register_buffer("cell_state", torch.zeros(1, 1, HIDDEN))

    def forward(self, x):
        out, h = self.memory(x.unsqueeze(0), self.hidden_state)
        self.hidden_state[:] = h
        return self.actor(out.squeeze(0))


def test_other_stateful_torchscript_is_refused_saying_what_was_found(
    arm3, tmp_path, legged_gym_file, capsys
):
    spec = make_spec(arm3)
    _, spec_file = legged_gym_file
    counting = script_save(CountingPolicy(spec.obs_dim, spec.act_dim), tmp_path / "count.pt")
    out = tmp_path / "count.onnx"
    assert export_main([str(counting), "--spec", str(spec_file), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "stateful TorchScript" in err and "buffer(s) 'steps' (1,)" in err
    assert "PolicyExporterLSTM" in err and not out.exists()
    assigning = script_save(AssigningPolicy(spec.obs_dim, spec.act_dim), tmp_path / "assign.pt")
    with pytest.raises(ExportError, match=r"forward assigns attribute\(s\) \['steps'\]"):
        run_export(assigning, tmp_path / "assign.onnx", spec=spec_file)
    gru = script_save(GruExporter(spec.obs_dim, spec.act_dim), tmp_path / "gru.pt")
    with pytest.raises(ExportError, match="'memory' is a GRU, not an LSTM"):
        run_export(gru, tmp_path / "gru.onnx", spec=spec_file)
    # a stateless TorchScript with a constant buffer still exports
    plain = PlainNet(spec.obs_dim, spec.act_dim)
    plain.register_buffer("gain", torch.ones(1))
    result = run_export(script_save(plain, tmp_path / "plain.pt"), spec=spec_file)
    assert result.source_format == "torchscript"


# ---------------------------------------------------------------- SB3-contrib RecurrentPPO
@pytest.fixture(scope="module")
def recurrent_ppo(arm3, tmp_path_factory):
    """(model, zip, spec path) of a small RecurrentPPO MlpLstmPolicy with arm3's spaces."""
    sb3_contrib = pytest.importorskip("sb3_contrib")
    import gymnasium as gym

    spec = make_spec(arm3)

    class Spaces(gym.Env):
        observation_space = gym.spaces.Box(-np.inf, np.inf, (spec.obs_dim,), np.float32)
        action_space = gym.spaces.Box(-1.0, 1.0, (spec.act_dim,), np.float32)

        def reset(self, seed=None, options=None):
            return np.zeros(spec.obs_dim, np.float32), {}

        def step(self, action):
            return np.zeros(spec.obs_dim, np.float32), 0.0, False, False, {}

    tmp = tmp_path_factory.mktemp("recurrent_ppo")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = sb3_contrib.RecurrentPPO(
            "MlpLstmPolicy",
            Spaces(),
            policy_kwargs={
                "lstm_hidden_size": HIDDEN,
                "net_arch": {"pi": [HIDDEN], "vf": [HIDDEN]},
            },
            n_steps=8,
            batch_size=8,
            device="cpu",
            seed=0,
        )
    with torch.no_grad():  # SB3 initialises action_net with gain 0.01: make the actions sizeable
        model.policy.action_net.weight.mul_(60.0)
    model.save(tmp / "rppo.zip")
    return model, tmp / "rppo.zip", write_spec(spec, tmp / "spec.json")


@pytest.fixture(scope="module")
def recurrent_ppo_onnx(recurrent_ppo):
    _, src, spec = recurrent_ppo
    return run_export(src, src.with_suffix(".onnx"), spec=spec)


def test_recurrent_ppo_export_has_lstm_state_and_passes_the_gate(recurrent_ppo_onnx):
    r = recurrent_ppo_onnx
    assert r.source_format == f"sb3-contrib RecurrentPPO (lstm, 1 layer(s), hidden {HIDDEN})"
    assert r.parity["max_abs_error"] <= 1e-5 and r.parity["replay_max_abs_error"] <= 1e-5
    assert r.parity["samples"] >= STEPS


def test_recurrent_ppo_onnx_matches_sb3_contrib_predict_over_500_steps(
    recurrent_ppo, recurrent_ppo_onnx, arm3
):
    model, _, _ = recurrent_ppo
    policy = OnnxPolicy(recurrent_ppo_onnx.path, arm3)
    envs = 3
    walk = random_walk(STEPS, policy.obs_dim, seed=9, envs=envs)
    starts = np.zeros((STEPS, envs), dtype=bool)
    starts[0] = True
    starts[200, [0, 2]] = True
    starts[350, 1] = True
    state = None
    policy.reset(np.ones(envs, dtype=bool))
    got, ref = [], []
    for t, obs in enumerate(walk):
        action, state = model.predict(obs, state=state, episode_start=starts[t], deterministic=True)
        if starts[t].any():
            policy.reset(starts[t])
        ref.append(action)
        got.append(policy(obs).copy())
    ref, got = np.stack(ref), np.stack(got)
    assert np.abs(ref).max() > 0.05
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5)
    np.testing.assert_allclose(policy.state_dict()["h_in"], state[0], rtol=0, atol=1e-5)


def test_deploy_run_with_the_recurrent_ppo_export(recurrent_ppo_onnx, tmp_path, capsys):
    deploy_run(recurrent_ppo_onnx.path, tmp_path, capsys)


# ---------------------------------------------------------------- --inspect
def test_inspect_names_format_io_and_state_of_each_source(
    legged_gym_file, legged_gym_onnx, recurrent_ppo, capsys
):
    src, _ = legged_gym_file
    ts = inspect_file(src)
    assert "PolicyExporterLSTM" in ts["format"]
    assert [s["input"] for s in ts["state"]] == ["h_in", "c_in"]
    assert ts["inputs"][0]["shape"] == ["batch", 21] and ts["outputs"][0]["shape"] == ["batch", 3]
    assert ts["spec"] is None

    onnx_info = inspect_file(legged_gym_onnx)
    assert onnx_info["format"] == "ONNX" and onnx_info["spec"]["valid"]
    assert [i["name"] for i in onnx_info["inputs"]] == ["obs", "h_in", "c_in"]
    assert onnx_info["state"][0]["shape"] == [1, "batch", HIDDEN]
    assert onnx_info["spec"]["summary"]["robot"] == "arm3"

    _, zip_path, _ = recurrent_ppo
    z = inspect_file(zip_path)
    assert z["format"] == "sb3-contrib RecurrentPPO"
    assert z["metadata"]["policy_class"].endswith("RecurrentActorCriticPolicy")
    assert z["state"][1] == {
        "input": "c_in",
        "output": "c_out",
        "shape": [1, "batch", HIDDEN],
        "dtype": "float32",
    }

    assert export_main(["--inspect", str(legged_gym_onnx)]) == 0
    out = capsys.readouterr().out
    assert "h_in -> h_out  float32 [1, batch, 16]" in out and "policy spec (valid)" in out


def test_inspect_reads_rsl_rl_and_pickles_without_unpickling(arm3, tmp_path):
    spec = make_spec(arm3)
    ac = rsl_rl_recurrent(spec.obs_dim, spec.act_dim)
    torch.save({"model_state_dict": ac.state_dict(), "iter": 7}, tmp_path / "model_7.pt")
    info = inspect_file(tmp_path / "model_7.pt")
    assert info["format"] == "rsl_rl checkpoint (ActorCriticRecurrent)"
    assert info["details"]["memory_a.rnn"]["kind"] == "lstm" and info["metadata"]["iter"] == 7
    torch.save(PlainNet(), tmp_path / "module.pt")
    info = inspect_file(tmp_path / "module.pt")
    assert info["format"].startswith("pickled Python object")
    assert info["metadata"]["class"] == "tests.helpers_policies.PlainNet"


def test_inspect_refuses_unreadable_files_with_exit_2(tmp_path, capsys, legged_gym_onnx):
    truncated = tmp_path / "cut.onnx"
    truncated.write_bytes(legged_gym_onnx.read_bytes()[:200])
    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    for path, message in ((truncated, "not a policy file"), (empty, "the file is empty")):
        assert export_main(["--inspect", str(path)]) == 2
        err = capsys.readouterr().err
        assert str(path) in err and message in err
    with pytest.raises(InspectError, match="no such file"):
        inspect_file(tmp_path / "missing.onnx")


# ---------------------------------------------------------------- bad input
def test_state_output_that_ignores_the_batch_axis_exits_3(arm3, tmp_path, capsys):
    """h_out = h_in[:, :1]: declared [1, batch, 8] both ways and right at batch 1, wrong for
    two envs; refused at load (not a crash on the first tick of a 2-env run)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from sim2real.deploy.cli.deploy_run import deploy_run_main

    spec = make_spec(arm3)
    consts = [
        numpy_helper.from_array(np.full((spec.obs_dim, spec.act_dim), 0.01, np.float32), "w"),
        *(numpy_helper.from_array(np.array([v], np.int64), n) for n, v in (("s", 0), ("e", 1))),
        numpy_helper.from_array(np.array([1], np.int64), "axis"),
    ]
    graph = helper.make_graph(
        [
            helper.make_node("MatMul", ["obs", "w"], ["action"]),
            helper.make_node("Slice", ["h_in", "s", "e", "axis"], ["h_out"]),
        ],
        "g",
        [
            helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", spec.obs_dim]),
            helper.make_tensor_value_info("h_in", TensorProto.FLOAT, [1, "batch", 8]),
        ],
        [
            helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", spec.act_dim]),
            helper.make_tensor_value_info("h_out", TensorProto.FLOAT, [1, "batch", 8]),
        ],
        initializer=consts,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    path = tmp_path / "slice.onnx"
    onnx.save(model, path)
    spec_file = write_spec(spec, tmp_path / "spec.json")
    code = deploy_run_main(
        ["--robot", "arm3", "--policy", str(path), "--spec", str(spec_file), "--envs", "2"]
        + ["--duration", "1"]
    )
    err = capsys.readouterr().err
    assert code == 3 and str(path) in err
    assert "state output 'h_out' has shape [1, 1, 8], its input 'h_in' [1, 2, 8]" in err


def test_inspect_shows_the_specs_frame_history(arm3, tmp_path, capsys):
    """An ONNX file whose embedded spec reads 4 ticks per term (first-frame fill), the last
    block 2 ticks: ``--inspect`` prints the history's length, order, layout, fill, the ticks per
    block and the stacked input size (before: the summary named the blocks' one-frame sizes
    and nothing of the history); a spec without history says so."""
    import dataclasses

    import onnx

    from sim2real.deploy.spec.history import ObservationHistory

    spec = helpers.make_spec(arm3)
    sizes = [b.size for b in spec.observation_blocks]
    ticks = (4,) * (len(sizes) - 1) + (2,)
    history = ObservationHistory(4, layout="per_term", fill="first", lengths=ticks)
    spec = dataclasses.replace(spec, history=history)
    n = sum(s * t for s, t in zip(sizes, ticks, strict=True))
    weight = np.zeros((n, arm3.n_joints))
    path = tmp_path / "stacked.onnx"
    model = helpers.linear_onnx(
        weight, np.zeros(arm3.n_joints), metadata={"policy_spec": spec.to_json()}
    )
    onnx.save(model, str(path))
    assert export_main(["--inspect", str(path)]) == 0
    out = capsys.readouterr().out
    expected = (
        f"history: 4 ticks, oldest_first, per_term, fill first, ticks per block {list(ticks)} "
        f"(frame {sum(sizes)} entries, input {n})"
    )
    assert "policy spec (valid)" in out and expected in out, out
    plain = helpers.make_spec(arm3)
    onnx.save(
        helpers.linear_onnx(np.zeros((sum(sizes), arm3.n_joints)), np.zeros(arm3.n_joints),
                            metadata={"policy_spec": plain.to_json()}),
        str(path),
    )  # fmt: skip
    assert export_main(["--inspect", str(path)]) == 0
    assert f"history: none (one frame a tick: {sum(sizes)} entries)" in capsys.readouterr().out
