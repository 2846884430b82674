"""Shared helpers of the policy tests: tiny networks, specs, hand-made ONNX graphs, observation
walks and a short ``deploy-run`` on arm3.

Module-level classes can be pickled by ``torch.save`` (the pickled-module tests import them from
here).
"""

from __future__ import annotations

import copy
import warnings
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch
from onnx import TensorProto, helper, numpy_helper
from torch import nn

from sim2real.deploy.spec.policy_spec import PolicySpec

#: arm3 with every block the seed's arm uses: obs 21, act 3.
ARM3_BLOCKS = (
    "joint_position",
    "joint_velocity",
    "ee_position",
    "goal_position",
    "goal_in_ee",
    "last_action",
    "winding_temperature",
)


def target_policy(robot, target_at):
    """A scripted position-mode policy of ``robot`` for the runtime: on its ``n``-th call it
    commands ``target_at(n)`` (n,) rad, as the action that the spec's scale and offset map to
    that target. ``policy.calls`` counts its calls."""
    spec = PolicySpec.for_robot(robot, mode="position")
    scale, offset = np.asarray(spec.action.scale), np.asarray(spec.action.offset)

    def policy(obs):
        target = np.asarray(target_at(policy.calls), dtype=np.float64)
        policy.calls += 1
        return ((target - offset) / scale)[None].astype(np.float32)

    policy.spec, policy.calls = spec, 0
    return policy


def random_walk(steps: int, d: int, seed: int, envs: int = 1, scale: float = 1.0) -> np.ndarray:
    """(steps, envs, d) float32 observations: a random walk (steps of sigma 0.15) clipped to
    [-1, 1], then times ``scale`` (sequential, like a run)."""
    rng = np.random.default_rng(seed)
    walk = np.clip(np.cumsum(rng.normal(0, 0.15, (steps, envs, d)), axis=0), -1.0, 1.0)
    return (scale * walk).astype(np.float32)


def deploy_run(
    capsys, policy: Path, spec: Path | None = None, seconds: float = 3.0, report: Path | None = None
) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of ``deploy-run`` on arm3 with ``policy`` for ``seconds``
    simulated seconds, with ``--spec`` / ``--report`` when given."""
    from sim2real.deploy.cli.deploy_run import deploy_run_main

    args = ["--robot", "arm3", "--policy", str(policy), "--duration", str(seconds)]
    for flag, value in (("--spec", spec), ("--report", report)):
        if value is not None:
            args += [flag, str(value)]
    code = deploy_run_main(args)
    out, err = capsys.readouterr()
    return code, out, err


def assert_ran(code: int, out: str, err: str) -> None:
    """A ``deploy_run`` result of an untrained policy: it loaded, ran and hit no hard limit."""
    # an untrained policy may latch a fault (2), or drive arm3 out of its workspace box (1: velocity
    # mode has no motion envelope yet, and deploy-run fails a run with a true violation); it must
    # load, run and not hit a hard limit
    assert code in (0, 1, 2), out + err
    assert code != 1 or "hard_limit 0," in out, out
    assert "tick cost" in out and "error" not in err


def rsl_rl_actor_critic(
    obs_dim: int, act_dim: int, rnn: str | None = "lstm", seed: int = 0, normalizer: bool = False
):
    """A small rsl_rl actor-critic in eval mode, ``torch.manual_seed(seed)`` first: an
    ``ActorCritic`` (``rnn`` None) or an ``ActorCriticRecurrent`` with one ``rnn`` ("lstm"/"gru")
    layer of 16 units; 16-unit actor and critic layers. ``normalizer``: the actor's observation
    normalizer on, with non-trivial mean and std. Skips the test without rsl_rl or tensordict."""
    rsl_rl = pytest.importorskip("rsl_rl.modules")
    tensordict = pytest.importorskip("tensordict")
    torch.manual_seed(seed)
    obs = tensordict.TensorDict({"policy": torch.zeros(1, obs_dim)}, batch_size=[1])
    kwargs = {"actor_hidden_dims": [16], "critic_hidden_dims": [16]}
    if normalizer:
        kwargs["actor_obs_normalization"] = True
    if rnn is not None:
        kwargs.update(rnn_type=rnn, rnn_hidden_dim=16, rnn_num_layers=1)
    groups = {"policy": ["policy"], "critic": ["policy"]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        kind = rsl_rl.ActorCritic if rnn is None else rsl_rl.ActorCriticRecurrent
        ac = kind(obs, groups, act_dim, **kwargs)
    if normalizer:
        norm = ac.actor_obs_normalizer
        g = torch.Generator().manual_seed(seed + 1)
        norm._mean.copy_(0.1 * torch.randn(norm._mean.shape, generator=g))
        norm._std.copy_(0.5 + torch.rand(norm._std.shape, generator=g))
        norm._var.copy_(norm._std**2)
    return ac.eval()


class LeggedGymLstm(nn.Module):
    """legged_gym's ``PolicyExporterLSTM`` layout (``export_policy_as_jit``): an LSTM ``memory``
    whose state lives in the buffers ``hidden_state`` / ``cell_state`` (layers, 1, hidden),
    updated in place by ``forward``, then an ``actor``; ``reset_memory`` exported."""

    def __init__(self, memory: nn.LSTM, actor: nn.Module):
        super().__init__()
        self.actor = actor
        self.memory = memory
        shape = (memory.num_layers, 1, memory.hidden_size)
        self.register_buffer("hidden_state", torch.zeros(shape))
        self.register_buffer("cell_state", torch.zeros(shape))

    def forward(self, x):
        out, (h, c) = self.memory(x.unsqueeze(0), (self.hidden_state, self.cell_state))
        self.hidden_state[:] = h
        self.cell_state[:] = c
        return self.actor(out.squeeze(0))

    @torch.jit.export
    def reset_memory(self):
        self.hidden_state[:] = 0.0
        self.cell_state[:] = 0.0


class PolicyExporterLSTM(LeggedGymLstm):
    """The module legged_gym's ``export_policy_as_jit`` scripts for an rsl_rl recurrent actor:
    deep copies of ``actor`` and ``memory_a.rnn``."""

    def __init__(self, actor_critic):
        memory = copy.deepcopy(actor_critic.memory_a.rnn)
        memory.cpu()
        super().__init__(memory, copy.deepcopy(actor_critic.actor))
        self.is_recurrent = actor_critic.is_recurrent


def make_spec(robot, blocks=ARM3_BLOCKS, **kwargs) -> PolicySpec:
    return PolicySpec.for_robot(robot, blocks=blocks, **kwargs)


def write_spec(spec: PolicySpec, path: Path) -> Path:
    path.write_text(spec.to_json())
    return path


class PlainNet(nn.Module):
    """A user's own actor module (not our MLPActor): Linear-Tanh-Linear."""

    def __init__(self, obs_dim: int = 21, act_dim: int = 3, hidden: int = 16):
        super().__init__()
        self.body = nn.Sequential(nn.Linear(obs_dim, hidden), nn.Tanh())
        self.head = nn.Linear(hidden, act_dim)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return 3.0 * self.head(self.body(obs))


class NoisyNet(PlainNet):
    """A non-deterministic forward: the ONNX graph cannot match the torch source."""

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        out = self.head(self.body(obs))
        return out + 1e-3 * torch.rand_like(out)


def folder(path: Path) -> set[str]:
    return {p.name for p in path.iterdir()}


def clip_action(a: np.ndarray, clip: float = 1.0) -> np.ndarray:
    return np.clip(a, -clip, clip)


def torch_out(net: nn.Module, obs: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return net(torch.as_tensor(obs, dtype=torch.float32)).numpy()


def linear_onnx(
    weight: np.ndarray,
    bias: np.ndarray,
    input_name: str = "obs",
    output_name: str = "action",
    extra_inputs: tuple[str, ...] = (),
    metadata: dict[str, str] | None = None,
    batch: int | str = "batch",
) -> onnx.ModelProto:
    """A foreign policy graph: ``action = obs @ weight + bias`` (weight (obs_dim, act_dim))."""
    obs_dim, act_dim = weight.shape
    nodes = [
        helper.make_node("MatMul", [input_name, "W"], ["h"], name="matmul"),
        helper.make_node("Add", ["h", "b"], [output_name], name="add"),
    ]
    inputs = [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, [batch, obs_dim])]
    outputs = [helper.make_tensor_value_info(output_name, TensorProto.FLOAT, [batch, act_dim])]
    for name in extra_inputs:  # recurrent-style state passed through
        inputs.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, [batch, 8]))
        nodes.append(helper.make_node("Identity", [name], [f"{name}_out"]))
        outputs.append(helper.make_tensor_value_info(f"{name}_out", TensorProto.FLOAT, [batch, 8]))
    graph = helper.make_graph(
        nodes,
        "policy",
        inputs,
        outputs,
        initializer=[
            numpy_helper.from_array(weight.astype(np.float32), "W"),
            numpy_helper.from_array(bias.astype(np.float32), "b"),
        ],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    for key, value in (metadata or {}).items():
        prop = model.metadata_props.add()
        prop.key, prop.value = key, value
    onnx.checker.check_model(model)
    return model


def externalize(model: onnx.ModelProto, name: str, location: str, data_path: Path) -> None:
    """Move initializer ``name`` to external data at ``location``, writing its bytes to
    ``data_path``."""
    for t in model.graph.initializer:
        if t.name == name:
            raw = numpy_helper.to_array(t).tobytes()
            data_path.parent.mkdir(parents=True, exist_ok=True)
            data_path.write_bytes(raw)
            t.ClearField("raw_data")
            t.ClearField("float_data")
            t.data_location = TensorProto.EXTERNAL
            del t.external_data[:]
            for key, value in (("location", location), ("offset", "0"), ("length", str(len(raw)))):
                entry = t.external_data.add()
                entry.key, entry.value = key, value
            return
    raise KeyError(name)
