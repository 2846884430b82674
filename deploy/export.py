"""policy-export: a trained policy -> ONNX with its contract, accepted only after a parity gate.

Usage::

    policy-export SOURCE [--spec SPEC.json] [--out FILE.onnx] [--trust-pickle]
                  [--vecnormalize FILE(.npz|.json|.pkl)] [--activation elu|tanh|relu]
                  [--robot NAME|PATH] [--exporter torchscript|dynamo]
    policy-export --inspect FILE     # what FILE is (deploy.inspect_policy); nothing exported

``SOURCE`` is a file (a bare name that does not exist as given is looked up in ``policies/``); the
ONNX file is written beside it with the same stem unless ``--out`` is given. Exit status: 0
exported, 1 parity failure, 2 bad input (3: internal error, a bug). Nothing is written unless
every check passes: the graph goes to a temporary file in the destination folder and is moved into
place (``os.replace``) last; an ONNX file already at the destination is left untouched by a failed
export.

Input formats (detected from the content, not the file name):

==================  ==========================================================================
format              what is read
==================  ==========================================================================
our checkpoint      ``deploy.checkpoint`` format (MLP, spec and normalizer inside; ``--spec``
                    optional and then must agree)
TorchScript         ``torch.jit.save`` archive; needs ``--spec``. Stateful TorchScript is refused
                    (:func:`deploy.export_torchscript_lstm.check_stateless`), except
legged_gym LSTM     legged_gym's ``PolicyExporterLSTM`` (buffers ``hidden_state``/``cell_state``
                    updated in place): the buffers become explicit state I/O and the file itself
                    is a parity reference (:mod:`deploy.export_torchscript_lstm`). Needs ``--spec``.
SB3 PPO / SAC       Stable-Baselines3 ``.zip``, read without unpickling: ``policy.pth`` (state
                    dict, ``weights_only``) and the ``data`` JSON. The deterministic actor is
                    rebuilt from the state-dict shapes: PPO ``mlp_extractor.policy_net`` +
                    ``action_net`` (Tanh by default, ``tanh`` output if ``squash_output``); SAC
                    ``actor.latent_pi`` + ``actor.mu`` then ``tanh`` (ReLU by default). The
                    activation comes from ``policy_kwargs.activation_fn`` when recorded;
                    ``--activation`` overrides. The action space must be the Box [-1, 1]
                    (the spec scales actions). Needs ``--spec``.
RecurrentPPO        SB3-contrib ``MlpLstmPolicy`` zip, read the same way: ``lstm_actor`` +
                    policy net + ``action_net`` (:mod:`deploy.export_sb3_recurrent`). ``--spec``.
rsl_rl              ``{"model_state_dict": {"actor.0.weight", ...}, ...}``: the ``actor.*`` MLP
                    (ELU by default) and rsl_rl's ``EmpiricalNormalization``, either
                    ``obs_norm_state_dict`` (rsl_rl 1.x/2.x) or ``actor_obs_normalizer.*`` in the
                    model state dict (3.x): ``(obs - _mean) / (_std + 0.01)`` (rsl_rl's default
                    eps, not stored in the file), no clip. Needs ``--spec``.
rsl_rl recurrent    ``ActorCriticRecurrent``: ``memory_a.rnn`` (LSTM or GRU) + the ``actor.*`` MLP
                    (+ normalizer as above), :mod:`deploy.export_rsl_rl`; the graph has explicit
                    state I/O (:mod:`deploy.export_recurrent`). Needs ``--spec``.
pickled nn.Module   ``torch.save(module)``: only with ``--trust-pickle`` (unpickling runs code);
                    needs ``--spec``
==================  ==========================================================================

``--vecnormalize`` adds SB3 ``VecNormalize`` statistics, ``clip((obs - mean) / sqrt(var + epsilon),
-clip_obs, clip_obs)``, to a source without a normalizer: an ``.npz`` with arrays ``mean``,
``var``, ``clip_obs``, ``epsilon``, a ``.json`` with the same keys (lists and numbers), or SB3's own
pickle (``VecNormalize.save``; needs ``--trust-pickle``). To write the safe form::

    np.savez("vecnormalize.npz", mean=vn.obs_rms.mean, var=vn.obs_rms.var,
             clip_obs=vn.clip_obs, epsilon=vn.epsilon)

The graph: input ``obs`` float32 [batch, obs_dim] (the spec's normalized observation), output
``action`` float32 [batch, act_dim], dynamic batch axis, opset 18 (``OPSET``); it bakes in the
empirical observation normalizer (if any) and the action clip ``[-clip, clip]`` of the spec.
Exporter: torch's TorchScript-based exporter (``torch.onnx.export(dynamo=False)``) by default: it
takes TorchScript sources and needs no onnxscript; ``--exporter dynamo`` uses the
``torch.export`` exporter instead (not for TorchScript sources). ``onnx.checker.check_model``
(full check) must pass.

Metadata (``model.metadata_props``): ``policy_spec`` (the PolicySpec JSON with ``baked`` and
``parity`` filled), ``source_sha256``, ``tool_versions`` (JSON: torch, onnx, onnxruntime, this
package, python), ``parity`` (JSON), ``source_format``, ``exporter``.

Recurrent sources get the graph ``obs``, ``h_in`` (, ``c_in``) -> ``action``, ``h_out``
(, ``c_out``), state ``[layers, batch, hidden]`` (TorchScript-based exporter only), and a parity
gate over sequences: step 1 is replaced by :func:`deploy.export_recurrent.sequence_parity` (500
sequential steps, state carried, resets half way), and the replay of step 2 carries the state on
both sides. A source that runs as it is (legged_gym's stateful TorchScript) is also stepped
against the ONNX for 500 steps at batch 1 (figures ``source_max_abs_error``, ``source_steps``).

Parity gate (tolerance ``TOLERANCE`` = 1e-5, max abs error over all action entries), both run
through :class:`deploy.policy.OnnxPolicy` exactly as the runtime runs it:
    1. 1,000 observations uniform in [-1.2, 1.2] per normalized entry, plus edge cases (zeros,
       +-1, +-1.2, +- each block's clip, each entry alone at +-1), in one batch and the first 32
       again one by one (batch 1), ONNX Runtime vs the torch module (normalizer and clip included);
    2. a closed-loop replay of 1,000 control ticks on the MuJoCo plant (``SimBackend``, 2 envs, the
       spec's control mode): observations from the plant's true state (``RobotState`` +
       ``Kinematics`` + ``spec.observation``), goals drawn from the robot's task region every 2 s,
       the ONNX action through ``spec.action_to_target`` to ``plant.write``; torch and ONNX compared
       at every tick.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import math
import os
import pickle
import platform
import re
import sys
import time
import traceback
import warnings
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
import torch
from torch import nn

from deploy.backends.sim import NonFiniteCommandError, SimBackend, SimulationDivergedError
from deploy.checkpoint import (
    ACTIVATIONS,
    FORMAT,
    CheckpointError,
    MLPActor,
    ObservationNormalizer,
    checkpoint_from_dict,
    load_failure_cause,
    load_weights_only,
    torch_file_problem,
    unreadable_torch_file,
    unsafe_globals_in,
)
from deploy.errors import Sim2RealError
from deploy.files import atomic_path, sha256_file
from deploy.policy import OnnxPolicy, PolicyLoadError, read_spec, spec_differences
from deploy.spec import PolicySpec, SpecError
from deploy.state import Kinematics, RobotState
from robots import Robot, load_robot

OPSET = 18
TOLERANCE = 1e-5
PARITY_SAMPLES = 1000
PARITY_BATCH1 = 32
REPLAY_TICKS = 1000
REPLAY_ENVS = 2
GOAL_PERIOD = 2.0  # s between goals in the replay
RSL_RL_EPS = 1e-2  # rsl_rl EmpiricalNormalization default eps (not stored in checkpoints)
EXIT_OK, EXIT_PARITY, EXIT_BAD_INPUT, EXIT_INTERNAL = 0, 1, 2, 3
EXPORTERS = ("torchscript", "dynamo")
POLICIES_DIR = Path(__file__).resolve().parent.parent / "policies"


class ExportError(Sim2RealError, ValueError):
    """Bad input (exit status 2): the message names the file and what is wrong."""


class ParityError(Sim2RealError, RuntimeError):
    """The ONNX graph disagrees with the torch source beyond the tolerance (exit status 1).

    Attributes:
        figures: The parity figures measured.
    """

    def __init__(self, message: str, figures: dict[str, Any]):
        super().__init__(message)
        self.figures = figures


@dataclass(frozen=True)
class ExportResult:
    """What an export produced.

    Attributes:
        path: The ONNX file. source_format: Detected input format. parity: Parity figures.
        seconds: Wall time of the whole export. spec: The spec stored in the file.
    """

    path: Path
    source_format: str
    parity: dict[str, Any]
    seconds: float
    spec: PolicySpec
    exporter: str


# ---------------------------------------------------------------------- graph building blocks
class Normalize(nn.Module):
    """``clamp((obs - mean) / denom, -clip, clip)``: an empirical observation normalizer."""

    def __init__(self, mean: torch.Tensor, denom: torch.Tensor, clip: float):
        super().__init__()
        self.register_buffer("mean", mean.detach().to(torch.float32).reshape(-1).clone())
        self.register_buffer("denom", denom.detach().to(torch.float32).reshape(-1).clone())
        self.clip = float(clip)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.clamp((obs - self.mean) / self.denom, -self.clip, self.clip)


class NormalizeNoClip(nn.Module):
    """``(obs - mean) / denom`` (rsl_rl's EmpiricalNormalization has no clip)."""

    def __init__(self, mean: torch.Tensor, denom: torch.Tensor):
        super().__init__()
        self.register_buffer("mean", mean.detach().to(torch.float32).reshape(-1).clone())
        self.register_buffer("denom", denom.detach().to(torch.float32).reshape(-1).clone())

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return (obs - self.mean) / self.denom


class ActionClip(nn.Module):
    """``clamp(action, -clip, clip)``: the spec's action clip, baked into the graph."""

    def __init__(self, clip: float):
        super().__init__()
        self.clip = float(clip)

    def forward(self, action: torch.Tensor) -> torch.Tensor:
        return torch.clamp(action, -self.clip, self.clip)


def normalizer_module(norm: ObservationNormalizer) -> nn.Module:
    """The graph module of an :class:`ObservationNormalizer`."""
    if math.isinf(norm.clip):
        return NormalizeNoClip(norm.mean, norm.denominator())
    return Normalize(norm.mean, norm.denominator(), norm.clip)


@dataclass
class SourcePolicy:
    """A loaded source: the network (normalized observation -> raw action) and what goes around.

    Attributes:
        net: The network, eval mode, float32. spec: Its PolicySpec. source_format: The format.
        normalizer: Observation normalizer module (or None). normalizer_kind: Its description.
        scripted: ``net`` is TorchScript (the graph module is scripted too).
    """

    net: nn.Module
    spec: PolicySpec
    source_format: str
    normalizer: nn.Module | None = None
    normalizer_kind: str | None = None
    scripted: bool = False
    extra_hashes: dict[str, str] = field(default_factory=dict)
    #: recurrent sources that can run as they are (a stateful TorchScript file): a factory of
    #: the batch-1 reference of :func:`deploy.export_recurrent.source_sequence_parity`
    sequence_reference: Any = None

    @property
    def recurrent(self) -> bool:
        """The net is a :class:`deploy.export_recurrent.RecurrentCore` (explicit state I/O)."""
        from deploy.export_recurrent import RecurrentCore

        return isinstance(self.net, RecurrentCore)

    def module(self) -> nn.Module:
        """normalizer -> net -> action clip, eval mode; scripted when the net is TorchScript.
        A recurrent net gives a :class:`deploy.export_recurrent.RecurrentPolicyModule`."""
        if self.recurrent:
            from deploy.export_recurrent import RecurrentPolicyModule

            return RecurrentPolicyModule(self.net, self.normalizer, self.spec.action.clip).eval()
        parts = [] if self.normalizer is None else [self.normalizer]
        seq = nn.Sequential(*parts, self.net, ActionClip(self.spec.action.clip)).eval()
        if self.scripted:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                seq = torch.jit.script(seq)
        return seq


# ---------------------------------------------------------------------- helpers
def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {lines[0] if lines else ''}"


def package_version() -> str:
    """Version of this package (installed metadata, else ``pyproject.toml``)."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("sim2real-deploy")
    except PackageNotFoundError:
        pass
    pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
    try:
        m = re.search(r'^version\s*=\s*"([^"]+)"', pyproject.read_text(), re.M)
    except OSError:
        m = None
    return f"{m.group(1)}+source" if m else "unknown"


def tool_versions() -> dict[str, str]:
    return {
        "torch": torch.__version__,
        "onnx": onnx.__version__,
        "onnxruntime": ort.__version__,
        "sim2real-deploy": package_version(),
        "python": platform.python_version(),
    }


def check_finite_tensors(tensors: Mapping[str, Any], where: str) -> None:
    """Raise ExportError if a floating tensor holds NaN or inf."""
    for name, t in tensors.items():
        if isinstance(t, torch.Tensor) and t.is_floating_point():
            bad = int((~torch.isfinite(t)).sum())
            if bad:
                raise ExportError(
                    f"{where}: tensor '{name}' holds {bad} non-finite value(s) (NaN or inf)"
                )


def _first_in_features(net: nn.Module) -> int | None:
    for _, p in net.named_parameters():
        if p.ndim == 2:
            return int(p.shape[1])
    return None


def _probe(net: nn.Module, spec: PolicySpec, path: Path) -> None:
    """Run the network on zeros (2, obs_dim): it must accept the spec's observation and return
    a float tensor (2, act_dim)."""
    first = _first_in_features(net)
    if first is not None and first != spec.obs_dim:
        raise ExportError(
            f"{path}: wrong input size: the network takes {first} inputs, the spec's observation "
            f"has {spec.obs_dim}"
        )
    try:
        with torch.no_grad():
            y = net(torch.zeros(2, spec.obs_dim))
    except Exception as exc:  # noqa: BLE001 - arbitrary user modules
        raise ExportError(
            f"{path}: the network fails on an observation of shape (batch, {spec.obs_dim}) "
            f"(wrong input size?): {_first_line(exc)}"
        ) from None
    if not isinstance(y, torch.Tensor):
        raise ExportError(
            f"{path}: the network returns {type(y).__name__}, expected one tensor "
            f"(batch, {spec.act_dim})"
        )
    if tuple(y.shape) != (2, spec.act_dim) or not y.is_floating_point():
        raise ExportError(
            f"{path}: wrong output size: the network returns {y.dtype} {tuple(y.shape)} for a "
            f"batch of 2, the spec's action needs (2, {spec.act_dim})"
        )


def _require_spec(spec: PolicySpec | None, path: Path, what: str) -> PolicySpec:
    if spec is None:
        raise ExportError(
            f"{path}: a {what} carries no PolicySpec; pass its spec with --spec FILE.json "
            "(PolicySpec.to_json())"
        )
    return spec


def _linear_stack(
    sd: Mapping[str, torch.Tensor], prefix: str, path: Path
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """The (weight, bias) pairs of an ``nn.Sequential`` of Linear layers and activations stored
    under ``prefix`` (``prefix0.weight``, ``prefix2.weight``, ...), in order."""
    keys = [k for k in sd if k.startswith(prefix)]
    index: dict[int, dict[str, torch.Tensor]] = {}
    for k in keys:
        m = re.fullmatch(re.escape(prefix) + r"(\d+)\.(weight|bias)", k)
        if not m:
            raise ExportError(
                f"{path}: unsupported layer '{k}' (only Linear layers and activations)"
            )
        index.setdefault(int(m.group(1)), {})[m.group(2)] = sd[k]
    layers = []
    for i in sorted(index):
        w, b = index[i].get("weight"), index[i].get("bias")
        if w is None or b is None or w.ndim != 2 or b.ndim != 1 or b.shape[0] != w.shape[0]:
            raise ExportError(
                f"{path}: '{prefix}{i}' is not a Linear layer with bias "
                f"(weight {None if w is None else tuple(w.shape)}, "
                f"bias {None if b is None else tuple(b.shape)})"
            )
        layers.append((w, b))
    return layers


def _build_mlp(
    layers: list[tuple[torch.Tensor, torch.Tensor]],
    activation: str,
    output: str | None,
    path: Path,
    where: str,
) -> MLPActor:
    for i, (w, b) in enumerate(layers):
        check_finite_tensors(
            {f"{where} layer {i} weight": w, f"{where} layer {i} bias": b}, str(path)
        )
    try:
        return MLPActor.from_linear_layers(layers, activation, output).eval()
    except ValueError as exc:
        raise ExportError(f"{path}: {where}: {exc}") from None


# ---------------------------------------------------------------------- source formats
def _detect(path: Path) -> str:
    if not path.exists():
        raise ExportError(f"{path}: no such file")
    if not path.is_file():
        raise ExportError(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise ExportError(f"{path}: the file is empty")
    if path.suffix.lower() == ".onnx":
        raise ExportError(f"{path}: already an ONNX file; export takes a torch checkpoint")
    if not zipfile.is_zipfile(path):
        problem = torch_file_problem(path)
        if problem is not None:
            raise ExportError(f"{path}: {problem}")
        return "torch"  # legacy torch.save format (a pickle), or damaged: torch.load decides
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (zipfile.BadZipFile, OSError) as exc:
        raise ExportError(f"{path}: damaged zip archive: {exc}") from None
    if "policy.pth" in names and "data" in names:
        return "sb3"
    if any(n.endswith("constants.pkl") or "/code/" in n for n in names):
        return "torchscript"
    if any(n.endswith("data.pkl") for n in names):
        return "torch"
    raise ExportError(
        f"{path}: a zip archive that is neither a torch checkpoint, a TorchScript module nor a "
        f"Stable-Baselines3 model (entries: {names[:6]})"
    )


def _torch_load(path: Path, trust_pickle: bool) -> Any:
    try:
        return load_weights_only(path)
    except pickle.UnpicklingError as exc:
        name = unsafe_globals_in(exc)
        if name is None:
            raise ExportError(unreadable_torch_file(path, exc)) from None
        if not trust_pickle:
            raise ExportError(
                f"{path}: holds a pickled Python object ({name}), e.g. a whole nn.Module; "
                "unpickling it can run arbitrary code. Pass --trust-pickle only if you trust "
                "where the file comes from, or export a state dict, TorchScript or our checkpoint"
            ) from None
    except Exception as exc:  # noqa: BLE001 - torch raises many types for damaged files
        raise ExportError(unreadable_torch_file(path, exc)) from None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return torch.load(path, map_location="cpu", weights_only=False)  # trusted by the user
    except Exception as exc:  # noqa: BLE001
        raise ExportError(f"{path}: cannot unpickle: {_first_line(exc)}") from None


def _load_checkpoint(path: Path, obj: Mapping, spec: PolicySpec | None) -> SourcePolicy:
    try:
        ckpt = checkpoint_from_dict(obj, path)
    except CheckpointError as exc:
        raise ExportError(str(exc)) from None
    if spec is not None:
        diff = spec_differences(ckpt.spec, spec)
        if diff:
            raise ExportError(
                f"{path}: the checkpoint's spec differs from the --spec given in {diff}"
            )
    norm = None
    if ckpt.obs_normalizer is not None:
        norm = normalizer_module(ckpt.obs_normalizer)
    return SourcePolicy(
        net=ckpt.actor,
        spec=ckpt.spec,
        source_format="checkpoint",
        normalizer=norm,
        normalizer_kind=None if norm is None else "checkpoint obs_normalizer",
    )


def load_torchscript(path: Path, error=None):
    """``torch.jit.load`` of ``path`` on the CPU, its warnings silenced.

    Raises:
        error (default :class:`ExportError`): the file is not a loadable TorchScript module.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return torch.jit.load(str(path), map_location="cpu")
    except Exception as exc:  # noqa: BLE001
        raise (error or ExportError)(
            f"{path}: not a loadable TorchScript module (truncated or corrupt?): {_first_line(exc)}"
        ) from None


def _load_torchscript(path: Path, spec: PolicySpec | None) -> SourcePolicy:
    spec = _require_spec(spec, path, "TorchScript module")
    net = load_torchscript(path)
    net.eval()
    from deploy import export_torchscript_lstm as lstm_ts

    if lstm_ts.is_legged_gym_lstm(net):
        return lstm_ts.load_legged_gym_lstm(path, net, spec)
    check_finite_tensors(dict(net.state_dict()), str(path))
    lstm_ts.check_stateless(net, spec.obs_dim, path, ExportError)
    _probe(net, spec, path)
    return SourcePolicy(net=net, spec=spec, source_format="torchscript", scripted=True)


def _load_pickled_module(path: Path, net: nn.Module, spec: PolicySpec | None) -> SourcePolicy:
    spec = _require_spec(spec, path, "pickled nn.Module")
    net = net.float().eval()
    check_finite_tensors(dict(net.state_dict()), str(path))
    _probe(net, spec, path)
    return SourcePolicy(net=net, spec=spec, source_format="pickled-module")


def _sb3_activation(data: Mapping, default: str, path: Path) -> str:
    kwargs = data.get("policy_kwargs") or {}
    text = kwargs.get("activation_fn") if isinstance(kwargs, Mapping) else None
    if not text:
        return default
    m = re.search(r"\.(\w+)'>", str(text))
    name = m.group(1) if m else str(text)
    mapping = {"Tanh": "tanh", "ReLU": "relu", "ELU": "elu"}
    if name not in mapping:
        raise ExportError(
            f"{path}: policy_kwargs.activation_fn = {name} is not supported (Tanh, ReLU, ELU); "
            "pass --activation to override"
        )
    return mapping[name]


def _parse_bounds(text: Any) -> np.ndarray | None:
    if not isinstance(text, str):
        return None
    nums = re.findall(r"[-+]?(?:inf|nan|\d+\.?\d*(?:e[-+]?\d+)?|\.\d+(?:e[-+]?\d+)?)", text)
    return np.array([float(x) for x in nums]) if nums else None


def _check_sb3_spaces(data: Mapping, spec: PolicySpec, path: Path) -> None:
    obs_space, act_space = data.get("observation_space"), data.get("action_space")
    for name, space, size in (
        ("observation_space", obs_space, spec.obs_dim),
        ("action_space", act_space, spec.act_dim),
    ):
        if not isinstance(space, Mapping):
            continue
        kind = str(space.get(":type:", ""))
        if kind and "Box" not in kind:
            raise ExportError(f"{path}: {name} is {kind}; only a flat Box is supported")
        shape = space.get("_shape")
        if shape is not None and list(shape) != [size]:
            what = "observation" if name == "observation_space" else "action"
            raise ExportError(
                f"{path}: {name} has shape {list(shape)}, the spec's {what} has ({size},)"
            )
    if isinstance(act_space, Mapping):
        low, high = _parse_bounds(act_space.get("low")), _parse_bounds(act_space.get("high"))
        if (
            low is not None
            and high is not None
            and (not np.allclose(low, -1.0) or not np.allclose(high, 1.0))
        ):
            raise ExportError(
                f"{path}: action_space bounds are low={low.tolist()}, high={high.tolist()}; SB3 "
                "clips or rescales actions to them, but the spec maps [-1, 1]: train on a "
                "Box(-1, 1) action space and let the spec scale it"
            )


def _load_sb3(path: Path, spec: PolicySpec | None, activation: str | None) -> SourcePolicy:
    spec = _require_spec(spec, path, "Stable-Baselines3 model")
    try:
        with zipfile.ZipFile(path) as zf:
            data_text = zf.read("data")
            policy_bytes = zf.read("policy.pth")
    except (zipfile.BadZipFile, KeyError, OSError, EOFError) as exc:
        raise ExportError(f"{path}: damaged Stable-Baselines3 archive: {exc}") from None
    try:
        data = json.loads(data_text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ExportError(f"{path}: entry 'data' is not valid JSON: {exc}") from None
    if not isinstance(data, Mapping):
        raise ExportError(f"{path}: entry 'data' is not a JSON object")
    try:
        sd = load_weights_only(io.BytesIO(policy_bytes))
    except Exception as exc:  # noqa: BLE001
        cause = "it holds pickled objects" if unsafe_globals_in(exc) else load_failure_cause(exc)
        raise ExportError(
            f"{path}: entry 'policy.pth' is not a readable state dict ({cause}); the archive is "
            "damaged or was not written by Stable-Baselines3"
        ) from None
    if not isinstance(sd, Mapping) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise ExportError(f"{path}: entry 'policy.pth' is not a state dict of tensors")
    extractor = [k for k in sd if re.match(r"(actor\.)?(pi_|vf_)?features_extractor\.", k)]
    if extractor:
        raise ExportError(
            f"{path}: the policy has a features extractor with parameters ({extractor[0]}, ...); "
            "only MlpPolicy (flat Box observations) is supported"
        )
    _check_sb3_spaces(data, spec, path)
    kwargs = data.get("policy_kwargs") if isinstance(data.get("policy_kwargs"), Mapping) else {}
    if any(k.startswith("lstm_actor.") for k in sd):
        from deploy.export_sb3_recurrent import load_recurrent_ppo

        return load_recurrent_ppo(path, sd, data, spec, activation)
    sac = "actor.mu.weight" in sd
    if sac and data.get("use_sde"):
        raise ExportError(f"{path}: SAC with use_sde=True is not supported")
    act = activation or _sb3_activation(data, "relu" if sac else "tanh", path)
    net, fmt = sb3_actor(sd, act, bool(kwargs.get("squash_output")), path)
    _probe(net, spec, path)
    return SourcePolicy(net=net, spec=spec, source_format=fmt)


def sb3_actor(
    sd: Mapping[str, torch.Tensor],
    activation: str,
    squash_output: bool = False,
    path: str | Path = "Stable-Baselines3 policy",
) -> tuple[MLPActor, str]:
    """The deterministic actor of a Stable-Baselines3 ``MlpPolicy`` state dict as an MLPActor.

    PPO: the Gaussian mean, ``mlp_extractor.policy_net`` then ``action_net`` (``tanh`` output when
    the policy squashes); SAC: ``tanh(mu(latent_pi(obs)))``.

    Args:
        sd: ``policy.state_dict()`` of an SB3 PPO or SAC model.
        activation: Hidden activation ('tanh', 'relu', 'elu'); SB3's defaults are tanh for PPO and
            relu for SAC. squash_output: PPO's ``squash_output``. path: Named in errors.

    Returns:
        ``(actor, source_format)`` with ``source_format`` 'sb3-ppo' or 'sb3-sac'.

    Raises:
        ExportError: neither a PPO nor a SAC actor, or layers that are not Linear with bias.
    """
    path = Path(path)
    if "actor.mu.weight" in sd:
        layers = _linear_stack(sd, "actor.latent_pi.", path)
        layers.append((sd["actor.mu.weight"], sd["actor.mu.bias"]))
        return _build_mlp(layers, activation, "tanh", path, "SAC actor"), "sb3-sac"
    if "action_net.weight" in sd:
        layers = _linear_stack(sd, "mlp_extractor.policy_net.", path)
        layers.append((sd["action_net.weight"], sd["action_net.bias"]))
        output = "tanh" if squash_output else None
        return _build_mlp(layers, activation, output, path, "PPO actor"), "sb3-ppo"
    raise ExportError(
        f"{path}: not a PPO (action_net) or SAC (actor.mu) policy; keys: {sorted(sd)[:8]}"
    )


def _load_rsl_rl(
    path: Path, obj: Mapping, spec: PolicySpec | None, activation: str | None
) -> SourcePolicy:
    spec = _require_spec(spec, path, "rsl_rl checkpoint")
    msd = obj["model_state_dict"]
    if not isinstance(msd, Mapping) or not all(isinstance(v, torch.Tensor) for v in msd.values()):
        raise ExportError(f"{path}: field 'model_state_dict' is not a state dict of tensors")
    if any(k.startswith("memory_a.rnn.") for k in msd):
        from deploy.export_rsl_rl import load_rsl_rl_recurrent

        return load_rsl_rl_recurrent(path, obj, msd, spec, activation)
    recurrent = [k for k in msd if k.startswith(("memory_a.", "memory_c.", "actor.rnn"))]
    if recurrent:
        raise ExportError(
            f"{path}: recurrent rsl_rl policy ({recurrent[0]}, ...) of an unsupported layout; "
            "an ActorCriticRecurrent actor (memory_a.rnn LSTM or GRU + actor MLP) is expected"
        )
    actor_keys = {k: v for k, v in msd.items() if re.fullmatch(r"actor\.\d+\.(weight|bias)", k)}
    if not actor_keys:
        raise ExportError(
            f"{path}: field 'model_state_dict' has no 'actor.<i>.weight' layers "
            f"(keys: {sorted(msd)[:8]})"
        )
    layers = _linear_stack(actor_keys, "actor.", path)
    net = _build_mlp(layers, activation or "elu", None, path, "rsl_rl actor")
    norm = rsl_rl_normalizer(path, obj, msd, spec)
    _probe(net, spec, path)
    return SourcePolicy(
        net=net,
        spec=spec,
        source_format="rsl_rl",
        normalizer=norm,
        normalizer_kind=None
        if norm is None
        else f"rsl_rl EmpiricalNormalization (eps {RSL_RL_EPS})",
    )


def rsl_rl_normalizer(
    path: Path, obj: Mapping, msd: Mapping[str, torch.Tensor], spec: PolicySpec
) -> nn.Module | None:
    """rsl_rl's actor ``EmpiricalNormalization`` as a graph module ``(obs - _mean) / (_std +
    RSL_RL_EPS)``, or None when the checkpoint has none.

    Raises:
        ExportError: statistics without ``_mean`` / ``_std``, of the wrong size, non-finite or
            negative.
    """
    stats, where = None, None
    if "actor_obs_normalizer._mean" in msd:
        stats = {
            k.split(".", 1)[1]: v for k, v in msd.items() if k.startswith("actor_obs_normalizer.")
        }
        where = "model_state_dict 'actor_obs_normalizer'"
    elif isinstance(obj.get("obs_norm_state_dict"), Mapping):
        stats, where = obj["obs_norm_state_dict"], "field 'obs_norm_state_dict'"
    norm = None
    if stats is not None:
        if "_mean" not in stats or ("_std" not in stats and "_var" not in stats):
            raise ExportError(f"{path}: {where} needs '_mean' and '_std' (or '_var')")
        mean = stats["_mean"].reshape(-1).to(torch.float32)
        std = stats["_std"] if "_std" in stats else torch.sqrt(stats["_var"])
        std = std.reshape(-1).to(torch.float32)
        check_finite_tensors({"_mean": mean, "_std": std}, f"{path}: {where}")
        if mean.shape != (spec.obs_dim,) or std.shape != (spec.obs_dim,):
            raise ExportError(
                f"{path}: {where} has {mean.shape[0]} entries, the spec's observation has "
                f"{spec.obs_dim}"
            )
        if (std < 0).any():
            raise ExportError(f"{path}: {where} has negative standard deviations")
        norm = NormalizeNoClip(mean, std + RSL_RL_EPS)
    return norm


def load_vecnormalize(path: Path, trust_pickle: bool, obs_dim: int) -> ObservationNormalizer | None:
    """SB3 VecNormalize statistics from ``.npz``, ``.json`` or (trusted) pickle.

    Returns:
        The normalizer, or None when the statistics say observations are not normalized
        (``norm_obs = False``).

    Raises:
        ExportError: unreadable file, missing key, wrong size, untrusted pickle.
    """
    if not path.is_file():
        raise ExportError(f"{path}: no such file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
        elif suffix == ".json":
            d = json.loads(path.read_text())
        else:
            if not trust_pickle:
                raise ExportError(
                    f"{path}: VecNormalize statistics saved with pickle (VecNormalize.save); "
                    "unpickling can run arbitrary code. Pass --trust-pickle if you trust the "
                    "file, or save them as .npz (mean, var, clip_obs, epsilon)"
                )
            with open(path, "rb") as f:
                vn = pickle.load(f)  # noqa: S301 - explicitly trusted by the user
            if not getattr(vn, "norm_obs", True):
                return None
            rms = vn.obs_rms
            if isinstance(rms, Mapping):
                raise ExportError(f"{path}: dict observation spaces are not supported")
            d = {"mean": rms.mean, "var": rms.var, "clip_obs": vn.clip_obs, "epsilon": vn.epsilon}
    except ExportError:
        raise
    except Exception as exc:  # noqa: BLE001
        raise ExportError(
            f"{path}: cannot read VecNormalize statistics (truncated or corrupt?): "
            f"{_first_line(exc)}"
        ) from None
    if not isinstance(d, Mapping):
        raise ExportError(f"{path}: expected an object with mean, var, clip_obs, epsilon")
    missing = [k for k in ("mean", "var", "clip_obs", "epsilon") if k not in d]
    if missing:
        raise ExportError(f"{path}: VecNormalize statistics lack {missing}")
    try:
        norm = ObservationNormalizer(
            mean=np.asarray(d["mean"], dtype=np.float64).reshape(-1),
            var=np.asarray(d["var"], dtype=np.float64).reshape(-1),
            epsilon=float(np.asarray(d["epsilon"])),
            clip=float(np.asarray(d["clip_obs"])),
        )
        norm.validate(str(path), obs_dim=obs_dim)
    except CheckpointError as exc:
        raise ExportError(str(exc)) from None
    except (TypeError, ValueError) as exc:
        raise ExportError(f"{path}: invalid VecNormalize statistics: {exc}") from None
    return norm


def load_source(
    source: str | os.PathLike,
    spec: PolicySpec | str | os.PathLike | None = None,
    trust_pickle: bool = False,
    vecnormalize: str | os.PathLike | None = None,
    activation: str | None = None,
) -> SourcePolicy:
    """Detect the format of ``source`` and load it (see the module docstring).

    Raises:
        ExportError: bad input, naming the file and the problem.
    """
    path = Path(source)
    if activation is not None and activation not in ACTIVATIONS:
        raise ExportError(
            f"activation '{activation}' is unknown; expected one of {sorted(ACTIVATIONS)}"
        )
    if spec is not None:
        try:
            spec = read_spec(spec)
        except SpecError as exc:
            raise ExportError(str(exc)) from None
    kind = _detect(path)
    if kind == "sb3":
        src = _load_sb3(path, spec, activation)
    elif kind == "torchscript":
        src = _load_torchscript(path, spec)
    else:
        obj = _torch_load(path, trust_pickle)
        if isinstance(obj, nn.Module):
            src = _load_pickled_module(path, obj, spec)
        elif isinstance(obj, Mapping) and "format" in obj:
            src = _load_checkpoint(path, obj, spec)
        elif isinstance(obj, Mapping) and "model_state_dict" in obj:
            src = _load_rsl_rl(path, obj, spec, activation)
        else:
            what = (
                f"a dict with keys {sorted(map(str, obj))[:8]}"
                if isinstance(obj, Mapping)
                else (type(obj).__name__)
            )
            raise ExportError(
                f"{path}: unrecognized content ({what}); expected our checkpoint (a 'format': "
                f"'{FORMAT}' dict), an rsl_rl checkpoint ('model_state_dict'), TorchScript, a "
                "Stable-Baselines3 zip, or a pickled nn.Module (--trust-pickle)"
            )
    if vecnormalize is not None:
        if src.normalizer is not None:
            raise ExportError(
                f"{path}: already has an observation normalizer ({src.normalizer_kind}); "
                "--vecnormalize would apply a second one"
            )
        vpath = Path(vecnormalize)
        norm = load_vecnormalize(vpath, trust_pickle, src.spec.obs_dim)
        if norm is not None:
            src.normalizer = normalizer_module(norm)
            src.normalizer_kind = "SB3 VecNormalize"
        src.extra_hashes["vecnormalize_sha256"] = sha256_file(vpath)
    return src


# ---------------------------------------------------------------------- ONNX
def _torchscript_onnx(
    module: nn.Module, example: tuple, inputs: list[str], outputs: list[str], axes: dict
) -> onnx.ModelProto:
    """``module`` through the TorchScript-based exporter (opset ``OPSET``, constants folded)."""
    buf = io.BytesIO()
    torch.onnx.export(
        module,
        example,
        buf,
        input_names=inputs,
        output_names=outputs,
        opset_version=OPSET,
        dynamo=False,
        dynamic_axes=axes,
        do_constant_folding=True,
    )
    return onnx.load_from_string(buf.getvalue())


def to_onnx(module: nn.Module, obs_dim: int, exporter: str = "torchscript") -> onnx.ModelProto:
    """Export ``module`` (obs -> action) to an ONNX model: input ``obs`` [batch, obs_dim], output
    ``action`` [batch, act_dim], dynamic batch, opset ``OPSET``.

    Raises:
        ExportError: the exporter failed, or the checker rejects the graph.
    """
    example = torch.zeros(2, obs_dim)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if exporter == "torchscript":
                axes = {"obs": {0: "batch"}, "action": {0: "batch"}}
                model = _torchscript_onnx(module, (example,), ["obs"], ["action"], axes)
            elif exporter == "dynamo":
                if isinstance(module, torch.jit.ScriptModule):
                    raise ExportError(
                        "the dynamo exporter cannot take TorchScript; use --exporter torchscript"
                    )
                program = torch.onnx.export(
                    module,
                    (example,),
                    input_names=["obs"],
                    output_names=["action"],
                    opset_version=OPSET,
                    dynamo=True,
                    dynamic_shapes=({0: torch.export.Dim("batch")},),
                    verbose=False,
                    report=False,
                )
                model = program.model_proto
            else:
                raise ExportError(f"exporter '{exporter}' is unknown; expected one of {EXPORTERS}")
    except ExportError:
        raise
    except Exception as exc:  # noqa: BLE001 - exporter failures of all kinds
        raise ExportError(f"torch.onnx.export ({exporter}) failed: {_first_line(exc)}") from None
    try:
        onnx.checker.check_model(model, full_check=True)
    except Exception as exc:  # noqa: BLE001
        raise ExportError(f"the exported graph fails onnx.checker: {exc}") from None
    return model


def _recurrent_to_onnx(module: nn.Module, obs_dim: int, exporter: str) -> onnx.ModelProto:
    """A recurrent module (:class:`deploy.export_recurrent.RecurrentPolicyModule`) to ONNX with
    explicit state I/O (:func:`deploy.export_recurrent.recurrent_signature`).

    Raises:
        ExportError: another exporter than TorchScript, or the exporter or checker failed.
    """
    from deploy.export_recurrent import recurrent_signature

    if exporter != "torchscript":
        raise ExportError(
            f"exporter '{exporter}' does not take recurrent policies; use --exporter torchscript"
        )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = _torchscript_onnx(module, *recurrent_signature(module, obs_dim))
        onnx.checker.check_model(model, full_check=True)
    except Exception as exc:  # noqa: BLE001 - exporter and checker failures of all kinds
        raise ExportError(f"torch.onnx.export (recurrent) failed: {_first_line(exc)}") from None
    return model


def set_metadata(model: onnx.ModelProto, entries: Mapping[str, str]) -> None:
    """Replace ``model.metadata_props`` by ``entries``."""
    del model.metadata_props[:]
    for key, value in entries.items():
        prop = model.metadata_props.add()
        prop.key, prop.value = key, value


def _max_abs(a: np.ndarray, b: np.ndarray) -> float:
    if a.shape != b.shape or not (np.isfinite(a).all() and np.isfinite(b).all()):
        return math.inf
    return float(np.max(np.abs(a.astype(np.float64) - b.astype(np.float64)), initial=0.0))


def parity_observations(spec: PolicySpec, samples: int, rng: np.random.Generator) -> np.ndarray:
    """float32 (samples + 7 + 2 obs_dim, obs_dim): uniform in [-1.2, 1.2], then edge cases."""
    d = spec.obs_dim
    clips = np.concatenate([np.full(b.size, b.clip) for b in spec.observation_blocks])
    ones = np.ones(d)
    edges = [np.zeros(d), ones, -ones, 1.2 * ones, -1.2 * ones, clips, -clips]
    rows = [rng.uniform(-1.2, 1.2, (samples, d)), np.stack(edges), np.eye(d), -np.eye(d)]
    return np.concatenate(rows).astype(np.float32)


def sample_goals(robot: Robot, rng: np.random.Generator, envs: int) -> np.ndarray:
    """(envs, 3) m, goals drawn uniformly from the robot's task region (robot.toml ``[task]``)."""
    task = robot.config.task
    if task.region == "planar_annulus":
        r = rng.uniform(*task.radius, envs)
        a = rng.uniform(*task.angle, envs)
        return np.stack([r * np.cos(a), r * np.sin(a), np.zeros(envs)], axis=1)
    return rng.uniform(task.box_min, task.box_max, (envs, 3))


def static_parity(
    policy: OnnxPolicy, module: nn.Module, spec: PolicySpec, samples: int, seed: int
) -> tuple[float, int]:
    """Max abs error ONNX vs torch over the parity observations (batch and batch-1 runs)."""
    obs = parity_observations(spec, samples, np.random.default_rng(seed))
    with torch.no_grad():
        ref = module(torch.from_numpy(obs)).numpy()
    err = _max_abs(policy(obs).copy(), ref)
    for i in range(min(PARITY_BATCH1, len(obs))):
        err = max(err, _max_abs(policy(obs[i : i + 1]).copy(), ref[i : i + 1]))
    return err, len(obs)


def closed_loop_parity(
    policy: OnnxPolicy,
    module: nn.Module,
    robot: Robot,
    ticks: int = REPLAY_TICKS,
    envs: int = REPLAY_ENVS,
    seed: int = 0,
    reference=None,
) -> dict[str, Any]:
    """Drive the MuJoCo plant with the ONNX policy for ``ticks`` control ticks and compare torch
    and ONNX actions at every tick.

    ``reference(obs) -> action`` (numpy, (envs, act_dim)) replaces ``module`` as the torch side
    when given (a recurrent policy's :class:`~deploy.export_recurrent.TorchRecurrentReference`,
    which carries the state as the ONNX policy does).

    Returns:
        ``{"max_abs_error", "ticks", "envs", "mode", "plant_resets"}``.
    """
    spec = policy.spec
    n = robot.n_joints
    plant = SimBackend(robot, mode=spec.action.mode, envs=envs, seed=seed)
    kin = Kinematics(robot)
    ambient = robot.config.sensors.ambient_temperature
    rng = np.random.default_rng(seed)
    legged = robot.floating_base
    if legged:  # the base from the plant's truth, a random velocity command per env
        state = RobotState.legged(envs, n, robot.n_feet, ambient)
        state.command[:] = rng.uniform([-0.5, -0.3, -1.0], [1.0, 0.3, 1.0], (envs, 3))
        goal = np.zeros((envs, 3))
    else:
        state = RobotState.zeros(envs, n, ambient)
        goal = sample_goals(robot, rng, envs)
    goal_every = max(1, int(round(GOAL_PERIOD / robot.control_period)))
    obs = np.zeros((envs, spec.obs_dim), np.float32)
    target = np.zeros((envs, n))
    worst, resets = 0.0, 0
    for tick in range(ticks):
        if tick and tick % goal_every == 0 and not legged:
            goal = sample_goals(robot, rng, envs)
        state.q[:] = plant.true_position()
        state.dq[:] = plant.true_velocity()
        state.winding_temperature[:] = plant.thermal.winding_temperature
        kin.update(state)
        if legged:
            _true_base(plant, state, tick * robot.control_period)
        spec.observation(state, goal, out=obs)
        action = policy(obs)
        if reference is not None:
            ref = reference(obs)
        else:
            with torch.no_grad():
                ref = module(torch.from_numpy(obs)).numpy()
        worst = max(worst, _max_abs(action, ref))
        if not np.isfinite(action).all():
            break
        spec.action_to_target(action, state, out=target)
        state.last_action[:] = action
        try:
            plant.write(target)
            plant.advance()
        except (SimulationDivergedError, NonFiniteCommandError):
            plant.reset()
            state.last_action.fill(0.0)
            resets += 1
    return {
        "max_abs_error": worst,
        "ticks": ticks,
        "envs": envs,
        "mode": spec.action.mode,
        "plant_resets": resets,
    }


def _true_base(plant: SimBackend, state: RobotState, t: float) -> None:
    """Fill a legged state's base fields from the plant's truth (parity replays only)."""
    state.base.set_truth(plant.true_base_state())
    state.foot_contact[:] = plant.read().foot_contact
    state.clock[:] = t


def _resolve_robot(robot: Robot | str | os.PathLike | None, spec: PolicySpec, where: str) -> Robot:
    if isinstance(robot, Robot):
        return robot
    name = spec.robot if robot is None else robot
    try:
        return load_robot(name)
    except Exception as exc:  # noqa: BLE001 - RobotSpecError, FileNotFoundError, ...
        raise ExportError(f"{where}: cannot load robot '{name}': {_first_line(exc)}") from None


def _write(model: onnx.ModelProto, path: Path) -> None:
    path.write_bytes(model.SerializeToString())  # fsync-ed by atomic_path before the rename


def run_export(
    source: str | os.PathLike,
    out: str | os.PathLike | None = None,
    spec: PolicySpec | str | os.PathLike | None = None,
    trust_pickle: bool = False,
    vecnormalize: str | os.PathLike | None = None,
    activation: str | None = None,
    robot: Robot | str | os.PathLike | None = None,
    exporter: str = "torchscript",
    seed: int = 0,
) -> ExportResult:
    """:func:`export_policy`, returning the parity figures and timing as well."""
    t0 = time.perf_counter()
    source = Path(source)
    src = load_source(source, spec, trust_pickle, vecnormalize, activation)
    out = source.with_suffix(".onnx") if out is None else Path(out)
    if out.resolve() == source.resolve():
        raise ExportError(f"{out}: the output would overwrite the source")
    if not out.parent.is_dir():
        raise ExportError(f"{out}: the output folder {out.parent} does not exist")
    the_robot = _resolve_robot(robot, src.spec, str(source))
    try:
        src.spec.check_robot(the_robot)
    except SpecError as exc:
        raise ExportError(f"{source}: {exc}") from None

    module = src.module()
    if src.recurrent:
        model = _recurrent_to_onnx(module, src.spec.obs_dim, exporter)
    else:
        model = to_onnx(module, src.spec.obs_dim, exporter)
    baked = {"observation_normalizer": src.normalizer is not None, "action_clip": True}
    exporter_text = f"torch.onnx.export(dynamo={exporter == 'dynamo'}), opset {OPSET}" + (
        " (TorchScript-based)" if exporter == "torchscript" else " (torch.export-based)"
    )
    base_meta = {
        "source_sha256": sha256_file(source),
        "source_format": src.source_format,
        "tool_versions": json.dumps(tool_versions(), sort_keys=True),
        "exporter": exporter_text,
        **src.extra_hashes,
    }
    if src.normalizer_kind:
        base_meta["observation_normalizer"] = src.normalizer_kind

    # the file is written and checked under a temporary name, moved onto ``out`` only if it passes
    try:
        with atomic_path(out) as tmp:
            pending = dataclasses.replace(src.spec, baked=baked, parity={})
            set_metadata(model, {"policy_spec": pending.to_json(), **base_meta})
            model.doc_string = (
                f"{src.spec.robot} policy exported by policy-export from {source.name}"
            )
            _write(model, tmp)
            try:
                policy = OnnxPolicy(tmp, the_robot)
            except PolicyLoadError as exc:
                raise ExportError(
                    f"the exported graph does not load in the runtime: {exc}"
                ) from None
            reference = None
            if src.recurrent:
                from deploy.export_recurrent import TorchRecurrentReference, sequence_parity

                static_err, n_samples = sequence_parity(policy, module, src.spec, seed)
                reference = TorchRecurrentReference(module)
            else:
                static_err, n_samples = static_parity(
                    policy, module, src.spec, PARITY_SAMPLES, seed
                )
            loop = closed_loop_parity(policy, module, the_robot, seed=seed, reference=reference)
            figures = {
                "tolerance": TOLERANCE,
                "max_abs_error": static_err,
                "samples": n_samples,
                "replay_max_abs_error": loop["max_abs_error"],
                "replay_ticks": loop["ticks"],
                "replay_envs": loop["envs"],
                "replay_mode": loop["mode"],
                "replay_plant_resets": loop["plant_resets"],
            }
            worst = max(static_err, loop["max_abs_error"])
            if src.sequence_reference is not None:
                from deploy.export_recurrent import source_sequence_parity

                src_err, src_steps = source_sequence_parity(
                    policy, src.sequence_reference(), src.spec, seed
                )
                figures.update(source_max_abs_error=src_err, source_steps=src_steps)
                worst = max(worst, src_err)
                static_err = max(static_err, src_err)
            if not worst <= TOLERANCE:
                raise ParityError(
                    f"{source}: ONNX and torch disagree: max abs error {static_err:.3g} over "
                    f"{n_samples} observations, {loop['max_abs_error']:.3g} over the "
                    f"{loop['ticks']}-tick closed-loop replay (tolerance {TOLERANCE:g}); nothing "
                    "written",
                    figures,
                )
            final = dataclasses.replace(src.spec, baked=baked, parity=figures)
            set_metadata(
                model,
                {"policy_spec": final.to_json(), **base_meta, "parity": json.dumps(figures)},
            )
            _write(model, tmp)
            check = OnnxPolicy(tmp, the_robot)  # the final bytes load and give the same actions
            probe = parity_observations(src.spec, 16, np.random.default_rng(seed + 1))
            if _max_abs(check(probe).copy(), policy(probe).copy()) != 0.0:
                raise ParityError(f"{source}: the final file gives different actions", figures)
    except OSError as exc:
        raise ExportError(f"{out}: cannot write in {out.parent}: {exc.strerror or exc}") from None
    return ExportResult(
        path=out,
        source_format=src.source_format,
        parity=figures,
        seconds=time.perf_counter() - t0,
        spec=final,
        exporter=exporter_text,
    )


def export_policy(
    source: str | os.PathLike,
    out: str | os.PathLike | None = None,
    spec: PolicySpec | str | os.PathLike | None = None,
    trust_pickle: bool = False,
    vecnormalize: str | os.PathLike | None = None,
    activation: str | None = None,
    robot: Robot | str | os.PathLike | None = None,
    exporter: str = "torchscript",
    seed: int = 0,
) -> Path:
    """Export a trained policy to ONNX with its PolicySpec, after the parity gate.

    Args:
        source: Policy file: our checkpoint, TorchScript, SB3 PPO/SAC zip, rsl_rl checkpoint, or a
            pickled nn.Module (see the module docstring).
        out: Destination; default ``source`` with the suffix ``.onnx``. Its folder must exist.
        spec: PolicySpec or spec JSON file; required unless the source is our checkpoint.
        trust_pickle: Allow unpickling (pickled modules, VecNormalize pickles). Never needed for
            the other formats.
        vecnormalize: SB3 VecNormalize statistics (``.npz``, ``.json``, or pickle if trusted).
        activation: Override the hidden activation of rebuilt SB3 / rsl_rl networks.
        robot: Robot (or name / path) to check against and replay on; default the spec's robot.
        exporter: 'torchscript' (default) or 'dynamo'.
        seed: Seed of the parity observations, goals and plant noise.

    Returns:
        The ONNX file written.

    Raises:
        ExportError: bad input (missing, truncated or corrupt file; unknown format; missing spec;
            wrong input or output size; non-finite weights; spec/robot mismatch; untrusted
            pickle). Nothing is written.
        ParityError: ONNX Runtime and torch disagree by more than ``TOLERANCE``. Nothing is
            written.
    """
    return run_export(
        source, out, spec, trust_pickle, vecnormalize, activation, robot, exporter, seed
    ).path


def resolve_policy_path(name: str | os.PathLike) -> Path:
    """``name`` if it exists, else ``policies/<name>`` if that exists, else ``name``."""
    path = Path(name)
    if path.exists():
        return path
    candidate = POLICIES_DIR / path
    return candidate if candidate.exists() else path


def main(argv: Sequence[str] | None = None) -> int:
    """The ``policy-export`` command; returns the exit status (0 ok, 1 parity failure, 2 bad
    input, 3 internal error)."""
    p = argparse.ArgumentParser(
        prog="policy-export",
        description="Export a trained policy to ONNX with its PolicySpec, after a parity check "
        "(ONNX Runtime vs torch, max abs error <= 1e-5 on 1,000+ observations and a 1,000-tick "
        "closed-loop replay on the MuJoCo plant). Exit status: 0 ok, 1 parity failure, 2 bad "
        "input; nothing is written unless every check passes.",
    )
    p.add_argument("source", help="policy file, or a name in policies/")
    p.add_argument("--spec", type=Path, help="PolicySpec JSON (required unless our checkpoint)")
    p.add_argument("--out", type=Path, help="ONNX file to write (default: beside SOURCE)")
    p.add_argument(
        "--trust-pickle", action="store_true", help="allow unpickling (runs code from the file)"
    )
    p.add_argument(
        "--vecnormalize", type=Path, help="SB3 VecNormalize statistics (.npz, .json, or .pkl)"
    )
    p.add_argument(
        "--activation", choices=sorted(ACTIVATIONS), help="override SB3/rsl_rl hidden activation"
    )
    p.add_argument("--robot", help="robot name or path (default: the spec's robot)")
    p.add_argument("--exporter", choices=EXPORTERS, default="torchscript")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--inspect",
        action="store_true",
        help="print what SOURCE is (ONNX or any input format: inputs, outputs, recurrent state, "
        "metadata, spec) and exit without exporting",
    )
    args = p.parse_args(argv)
    source = resolve_policy_path(args.source)
    if not source.exists() and not source.is_absolute():
        print(
            f"policy-export: error: {source}: no such file (nor in {POLICIES_DIR})",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    if args.inspect:
        from deploy.inspect_policy import InspectError, format_report, inspect_file

        try:
            print(format_report(inspect_file(source)))
        except InspectError as exc:
            print(f"policy-export: error: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT
        return EXIT_OK
    try:
        result = run_export(
            source,
            out=args.out,
            spec=args.spec,
            trust_pickle=args.trust_pickle,
            vecnormalize=args.vecnormalize,
            activation=args.activation,
            robot=args.robot,
            exporter=args.exporter,
            seed=args.seed,
        )
    except ParityError as exc:
        print(f"policy-export: parity check FAILED: {exc}", file=sys.stderr)
        return EXIT_PARITY
    except ExportError as exc:
        print(f"policy-export: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception:  # noqa: BLE001 - a bug, not bad input nor a parity failure
        traceback.print_exc()
        print("policy-export: internal error (see the traceback above)", file=sys.stderr)
        return EXIT_INTERNAL
    s, f = result.spec, result.parity
    baked = [k.replace("_", " ") for k, v in s.baked.items() if v]
    print(f"exported {source} ({result.source_format}) -> {result.path}")
    print(
        f"  robot {s.robot}, {s.action.mode} mode at {s.control_rate:g} Hz; obs {s.obs_dim} -> "
        f"action {s.act_dim}; baked: {', '.join(baked) or 'nothing'}"
    )
    print(
        f"  parity: max |onnx - torch| {f['max_abs_error']:.2e} over {f['samples']} observations, "
        f"{f['replay_max_abs_error']:.2e} over a {f['replay_ticks']}-tick closed-loop replay "
        f"({f['replay_envs']} envs); tolerance {f['tolerance']:g}"
    )
    print(f"  export time {result.seconds:.2f} s; {result.exporter}")
    return EXIT_OK


if __name__ == "__main__":
    raise SystemExit(main())
