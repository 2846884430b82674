"""Stateful TorchScript for ``policy-export``: legged_gym's ``PolicyExporterLSTM`` layout.

legged_gym and unitree_rl_gym (``legged_gym/utils/helpers.py``, ``export_policy_as_jit``) write a
recurrent rsl_rl policy as ``torch.jit.script`` of a module holding

- ``memory``: a copy of the actor's ``nn.LSTM`` (``memory_a.rnn``, sequence-first);
- ``actor``: a copy of the actor MLP (an ``nn.Sequential`` of ``Linear`` and activations);
- buffers ``hidden_state`` and ``cell_state``, each ``(layers, 1, hidden)`` float32, zeros;

whose ``forward(x)`` runs ``memory(x.unsqueeze(0), (hidden_state, cell_state))``, writes the new
state into the buffers in place and returns ``actor(out.squeeze(0))`` (``reset_memory()`` zeroes
the buffers). Calling the file is stateful and only works at batch 1.

:func:`load_legged_gym_lstm` recognises that layout (those two buffer names, an LSTM ``memory``, a
Sequential ``actor``), rebuilds the LSTM and the actor as plain torch modules and lifts the buffers
into explicit state I/O (:mod:`sim2real.deploy.export.recurrent`: ``obs``, ``h_in``, ``c_in`` -> ``action``,
``h_out``, ``c_out``, state ``[layers, batch, hidden]``; initial state zeros, as ``reset_memory``
sets it). The file itself (:class:`StatefulScriptReference`, batch 1, buffers zeroed on reset) is
the reference of the extra parity run :func:`sim2real.deploy.export.parity.source_sequence_parity`.

Any other TorchScript whose state changes when it runs is refused by :func:`check_stateless`:
a buffer that ``forward`` modifies, a ``prim::SetAttr`` in ``forward``, or two calls on the same
observation that answer differently.
"""

from __future__ import annotations

import inspect
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from sim2real.deploy.export.errors import ExportError, _first_line
from sim2real.deploy.export.network import check_finite_tensors
from sim2real.deploy.export.recurrent import RecurrentCore, RecurrentPolicyModule
from sim2real.deploy.export.source import SourcePolicy
from sim2real.deploy.spec.policy_spec import PolicySpec

#: The buffers of legged_gym's PolicyExporterLSTM (hidden state, cell state), in that order.
STATE_BUFFERS = ("hidden_state", "cell_state")
LAYOUT = (
    "legged_gym's PolicyExporterLSTM layout (buffers 'hidden_state' and 'cell_state' of shape "
    "(layers, 1, hidden), an nn.LSTM 'memory', an nn.Sequential 'actor')"
)
#: Containers read as a sequence of their children (``nn.Sequential`` subclasses: rsl_rl's MLP);
#: the parity run against the file itself checks that reading.
SEQUENCES = ("Sequential", "MLP")
#: Activation modules rebuilt from a scripted actor (torch.nn classes without parameters).
ACTIVATIONS = (
    "ELU",
    "SELU",
    "CELU",
    "ReLU",
    "LeakyReLU",
    "Tanh",
    "Sigmoid",
    "Softsign",
    "Softplus",
    "SiLU",
    "Mish",
    "GELU",
    "Hardtanh",
    "Identity",
)


def is_legged_gym_lstm(net: torch.jit.ScriptModule) -> bool:
    """True when ``net`` holds a ``hidden_state`` or ``cell_state`` buffer (the layout's mark;
    :func:`load_legged_gym_lstm` then checks the rest)."""
    return any(name in STATE_BUFFERS for name, _ in net.named_buffers(recurse=False))


def _lstm_from_script(memory, path: Path, error) -> nn.LSTM:
    """A plain ``nn.LSTM`` with the parameters and hyper-parameters of a scripted one."""
    name = getattr(memory, "original_name", type(memory).__name__)
    if name != "LSTM":
        raise error(
            f"{path}: buffers {STATE_BUFFERS} found but 'memory' is a {name}, not an LSTM; "
            f"expected {LAYOUT}"
        )
    attrs = {a: getattr(memory, a, None) for a in ("input_size", "hidden_size", "num_layers")}
    if not all(isinstance(v, int) and v > 0 for v in attrs.values()):
        raise error(f"{path}: 'memory' (LSTM) lacks its sizes: {attrs}")
    for flag, expected in (("batch_first", False), ("bidirectional", False), ("proj_size", 0)):
        value = getattr(memory, flag, expected)
        if value != expected:
            raise error(
                f"{path}: 'memory' has {flag}={value}; a one-directional, sequence-first LSTM "
                f"without projection is expected ({LAYOUT})"
            )
    bias = bool(getattr(memory, "bias", True))
    rnn = nn.LSTM(attrs["input_size"], attrs["hidden_size"], attrs["num_layers"], bias=bias)
    try:
        rnn.load_state_dict({k: v.detach().float() for k, v in memory.named_parameters()})
    except RuntimeError as exc:
        first = str(exc).strip().splitlines()[0]
        raise error(f"{path}: 'memory' parameters do not form an LSTM: {first}") from None
    return rnn.eval()


def _module_from_script(child, path: Path, where: str, error) -> nn.Module:
    """A plain torch module equal to a scripted ``Linear``, activation or ``Sequential``."""
    name = getattr(child, "original_name", type(child).__name__)
    if name == "Sequential" or (name in SEQUENCES and not list(child.named_buffers())):
        return nn.Sequential(
            *(
                _module_from_script(c, path, f"{where}.{n}", error)
                for n, c in child.named_children()
            )
        )
    if name == "Linear":
        params = dict(child.named_parameters())
        w, b = params.get("weight"), params.get("bias")
        if w is None or w.ndim != 2:
            raise error(f"{path}: '{where}' (Linear) has no weight matrix")
        lin = nn.Linear(int(w.shape[1]), int(w.shape[0]), bias=b is not None)
        with torch.no_grad():
            lin.weight.copy_(w.float())
            if b is not None:
                lin.bias.copy_(b.float())
        return lin
    if name in ACTIVATIONS and not list(child.parameters()):
        cls = getattr(nn, name)
        kwargs = {}
        for p in inspect.signature(cls.__init__).parameters.values():
            if p.name != "self" and p.kind is p.POSITIONAL_OR_KEYWORD:
                value = getattr(child, p.name, None)
                if value is not None:
                    kwargs[p.name] = value
        return cls(**kwargs)
    raise error(
        f"{path}: '{where}' is a {name}; the actor may hold Linear layers and parameter-free "
        f"activations ({', '.join(ACTIVATIONS)}) only"
    )


def load_legged_gym_lstm(path: Path, net: torch.jit.ScriptModule, spec: PolicySpec):
    """The :class:`sim2real.deploy.export.SourcePolicy` of a PolicyExporterLSTM TorchScript.

    Args:
        path: The file (for messages). net: The loaded TorchScript module. spec: ``--spec``.

    Returns:
        A recurrent SourcePolicy (LSTM state lifted into ``h``/``c`` I/O), with the file itself
        as the sequence reference.

    Raises:
        sim2real.deploy.export.ExportError: another layout (missing buffer, memory not an LSTM, no
            Sequential actor, other buffers), buffers not ``(layers, 1, hidden)``, non-finite
            weights, sizes that do not fit the spec.
    """
    buffers = dict(net.named_buffers(recurse=False))
    children = dict(net.named_children())
    extra = sorted(set(buffers) - set(STATE_BUFFERS))
    missing = [b for b in STATE_BUFFERS if b not in buffers]
    if missing or extra or "memory" not in children or "actor" not in children:
        found = {k: tuple(v.shape) for k, v in buffers.items()}
        raise ExportError(
            f"{path}: stateful TorchScript of an unknown layout: buffers {found}, submodules "
            f"{sorted(children)}; only {LAYOUT} is lifted into explicit state"
        )
    check_finite_tensors(dict(net.state_dict()), str(path))
    rnn = _lstm_from_script(children["memory"], path, ExportError)
    expected = (rnn.num_layers, 1, rnn.hidden_size)
    for name in STATE_BUFFERS:
        if tuple(buffers[name].shape) != expected:
            raise ExportError(
                f"{path}: buffer '{name}' has shape {tuple(buffers[name].shape)}, expected "
                f"{expected} (layers, 1, hidden) for the LSTM 'memory'"
            )
    if rnn.input_size != spec.obs_dim:
        raise ExportError(
            f"{path}: wrong input size: the LSTM 'memory' takes {rnn.input_size} inputs, the "
            f"spec's observation has {spec.obs_dim}"
        )
    actor = _module_from_script(children["actor"], path, "actor", ExportError).eval()
    core = RecurrentCore(rnn, actor).eval()
    probe = RecurrentPolicyModule(core, None, spec.action.clip).eval()
    try:
        with torch.no_grad():
            action, *_ = probe(torch.zeros(2, spec.obs_dim), *core.layout.zeros(2))
    except Exception as exc:  # noqa: BLE001 - shapes that do not chain
        raise ExportError(
            f"{path}: the 'actor' does not take the LSTM's {rnn.hidden_size} outputs: "
            f"{_first_line(exc)}"
        ) from None
    if tuple(action.shape) != (2, spec.act_dim):
        raise ExportError(
            f"{path}: wrong output size: the actor returns {action.shape[-1]} values, the "
            f"spec's action has {spec.act_dim}"
        )
    if not torch.isfinite(action).all():
        raise ExportError(f"{path}: the action for the zero observation is not finite")
    clip = spec.action.clip
    return SourcePolicy(
        net=core,
        spec=spec,
        source_format=f"legged_gym PolicyExporterLSTM TorchScript (lstm, {rnn.num_layers} "
        f"layer(s), hidden {rnn.hidden_size})",
        sequence_reference=lambda: StatefulScriptReference(net, clip),
    )


class StatefulScriptReference:
    """The stateful TorchScript file itself as a parity reference: ``ref(obs)`` with ``obs``
    (1, obs_dim) float32 -> action (1, act_dim) clipped to ``[-clip, clip]``; ``reset()`` zeroes
    the state buffers (``reset_memory()`` when the module has it)."""

    batch = 1

    def __init__(self, net: torch.jit.ScriptModule, clip: float):
        self.net, self.clip = net, float(clip)
        self.reset()

    def reset(self, envs: np.ndarray | None = None) -> None:
        if hasattr(self.net, "reset_memory"):
            self.net.reset_memory()
        else:
            with torch.no_grad():
                for name in STATE_BUFFERS:
                    getattr(self.net, name).zero_()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            out = self.net(torch.from_numpy(np.ascontiguousarray(obs, np.float32)))
        return np.clip(out.numpy(), -self.clip, self.clip)


def check_stateless(net: torch.jit.ScriptModule, obs_dim: int, path: Path, error) -> None:
    """Refuse TorchScript that keeps state between calls (other than the recognised layout).

    Looks for a ``prim::SetAttr`` in ``forward`` (an attribute assigned), then runs ``forward``
    twice on the same observations (batch 2, else batch 1) and compares every buffer before and
    after, and the two answers.

    Raises:
        error: naming what was found (attribute, buffer and its shape, or the differing answers).
    """
    try:
        graph = net.inlined_graph
        set_attrs = sorted({n.s("name") for n in graph.findAllNodes("prim::SetAttr")})
    except Exception:  # noqa: BLE001 - graph introspection is best effort
        set_attrs = []
    hint = f"only {LAYOUT} is lifted into explicit state; export the policy without state"
    if set_attrs:
        raise error(
            f"{path}: stateful TorchScript: forward assigns attribute(s) {set_attrs}; {hint}"
        )
    before = {k: v.detach().clone() for k, v in net.named_buffers()}
    rng = np.random.default_rng(0)
    answers = []
    for batch in (2, 1):
        obs = torch.from_numpy(rng.uniform(-1.0, 1.0, (batch, obs_dim)).astype(np.float32))
        try:
            with warnings.catch_warnings(), torch.no_grad():
                warnings.simplefilter("ignore")
                answers = [net(obs), net(obs)]
            break
        except Exception:  # noqa: BLE001 - the probe that follows names the failure
            continue
    changed = [
        f"'{k}' {tuple(v.shape)}"
        for k, v in net.named_buffers()
        if k in before and (v.shape != before[k].shape or not torch.equal(v, before[k]))
    ]
    with torch.no_grad():
        for k, v in net.named_buffers():
            if k in before and v.shape == before[k].shape:
                v.copy_(before[k])
    if changed:
        raise error(
            f"{path}: stateful TorchScript: forward modifies buffer(s) {', '.join(changed)}; {hint}"
        )
    if (
        len(answers) == 2
        and isinstance(answers[0], torch.Tensor)
        and isinstance(answers[1], torch.Tensor)
        and not torch.equal(answers[0], answers[1])
    ):
        raise error(
            f"{path}: stateful or non-deterministic TorchScript: two calls on the same "
            f"observation return different actions; {hint}"
        )
