"""Our policy checkpoint format: a deterministic MLP actor, its PolicySpec and its normalizer.

A ``.pt`` file holding one plain dict that loads with ``torch.load(path, weights_only=True)``
(tensors, strings, numbers, lists and dicts only: loading it never runs code)::

    {
        "format": "sim2real-deploy/mlp", "format_version": 1,
        "architecture": {
            "obs_dim": 21, "act_dim": 3,   # int: spec.obs_dim, spec.act_dim
            "hidden": [64, 64],            # widths of the hidden layers ([] = linear policy)
            "activation": "elu",           # "elu" | "tanh" | "relu", after every hidden layer
            "output": None,                # None (unsquashed) | "tanh"
        },
        "state_dict": {...},               # MLPActor.state_dict(): "net.0.weight", ...
        "spec": "<PolicySpec JSON>",       # PolicySpec.to_json()
        "obs_normalizer": None | {"mean", "var", "epsilon", "clip"},  # ObservationNormalizer
        "info": {...},                     # optional plain data (training run, seed, ...)
    }

The actor maps the spec's normalized observation, float32 (batch, obs_dim), to the action, float32
(batch, act_dim), before the spec's action clip. :func:`save_checkpoint` writes atomically;
:func:`load_checkpoint` validates every field and raises
:class:`~sim2real.deploy.policy.torch_file.CheckpointError` naming the file and the field.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from sim2real.deploy.policy.obs_normalizer import ObservationNormalizer
from sim2real.deploy.policy.torch_file import CheckpointError, finite_check, read_torch_file
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError
from sim2real.robots.files import atomic_path

FORMAT = "sim2real-deploy/mlp"
FORMAT_VERSION = 1
#: Activations of the hidden layers, by their name in ``architecture["activation"]``.
ACTIVATIONS: dict[str, type[nn.Module]] = {"elu": nn.ELU, "tanh": nn.Tanh, "relu": nn.ReLU}
#: Output squashing, by its name in ``architecture["output"]``.
OUTPUTS = (None, "tanh")


class MLPActor(nn.Module):
    """Deterministic MLP actor: normalized observation -> action.

    ``Linear -> activation`` per hidden layer, then a final ``Linear`` (and ``tanh`` when
    ``output="tanh"``). Parameters live in ``self.net`` (an ``nn.Sequential``), so the state dict
    keys are ``net.<i>.weight`` and ``net.<i>.bias``.

    Args:
        obs_dim: Observation size (input features).
        act_dim: Action size (outputs).
        hidden: Widths of the hidden layers; empty for a linear policy.
        activation: 'elu', 'tanh' or 'relu'.
        output: None (unsquashed output) or 'tanh'.
        gait: Optional description of a :class:`sim2real.deploy.policy.gait_prior.TrotPrior` (a quadruped's
            trot generator) whose offsets are added to the network's output: the network then
            learns corrections to a gait (checkpoint ``architecture.gait``).

    Raises:
        ValueError: non-positive sizes, unknown activation or output, an invalid ``gait``.
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden: Sequence[int] = (64, 64),
        activation: str = "elu",
        output: str | None = None,
        gait: Mapping[str, Any] | None = None,
    ):
        super().__init__()
        sizes = [obs_dim, *hidden, act_dim]
        if not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in sizes):
            raise ValueError(
                f"MLPActor: obs_dim, hidden and act_dim must be positive integers, got "
                f"obs_dim={obs_dim!r}, hidden={list(hidden)!r}, act_dim={act_dim!r}"
            )
        if activation not in ACTIVATIONS:
            raise ValueError(
                f"MLPActor: activation '{activation}' is unknown; expected one of "
                f"{sorted(ACTIVATIONS)}"
            )
        if output not in OUTPUTS:
            raise ValueError(f"MLPActor: output '{output}' is unknown; expected one of {OUTPUTS}")
        self.obs_dim, self.act_dim = obs_dim, act_dim
        self.hidden, self.activation, self.output = tuple(hidden), activation, output
        layers: list[nn.Module] = []
        for a, b in zip(sizes[:-2], sizes[1:-1], strict=True):
            layers += [nn.Linear(a, b), ACTIVATIONS[activation]()]
        layers.append(nn.Linear(sizes[-2], sizes[-1]))
        if output == "tanh":
            layers.append(nn.Tanh())
        self.net = nn.Sequential(*layers)
        self.gait = None
        if gait is not None:
            from sim2real.deploy.policy.gait_prior import TrotPrior

            self.gait = TrotPrior.from_description(dict(gait), where="MLPActor: gait")
            if act_dim != 12:
                raise ValueError(f"MLPActor: a trot generator drives 12 joints, act_dim={act_dim}")

    @property
    def architecture(self) -> dict[str, Any]:
        """The ``architecture`` entry of a checkpoint (plain data)."""
        arch = {
            "obs_dim": self.obs_dim,
            "act_dim": self.act_dim,
            "hidden": list(self.hidden),
            "activation": self.activation,
            "output": self.output,
        }
        if self.gait is not None:
            arch["gait"] = dict(self.gait.description)
        return arch

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Action, (batch, act_dim), for the normalized observation ``obs`` (batch, obs_dim)."""
        if self.gait is not None:
            return self.net(obs) + self.gait(obs)
        return self.net(obs)

    @classmethod
    def from_architecture(cls, arch: Any, where: str = "architecture") -> MLPActor:
        """Build an (untrained) actor from an ``architecture`` dict.

        Raises:
            CheckpointError: a field is missing or invalid (the message starts with ``where``).
        """
        if not isinstance(arch, Mapping):
            raise CheckpointError(f"{where}: expected a dict, got {type(arch).__name__}")
        for key in ("obs_dim", "act_dim", "hidden", "activation"):
            if key not in arch:
                raise CheckpointError(f"{where}.{key}: missing")
        hidden = arch["hidden"]
        if not isinstance(hidden, list | tuple):
            raise CheckpointError(f"{where}.hidden: expected a list of widths, got {hidden!r}")
        try:
            return cls(
                arch["obs_dim"],
                arch["act_dim"],
                tuple(hidden),
                arch["activation"],
                arch.get("output"),
                arch.get("gait"),
            )
        except ValueError as exc:
            raise CheckpointError(f"{where}: {exc}") from None

    @classmethod
    def from_linear_layers(
        cls,
        layers: Sequence[tuple[torch.Tensor, torch.Tensor]],
        activation: str,
        output: str | None = None,
    ) -> MLPActor:
        """An actor holding the given ``(weight, bias)`` pairs, first layer first.

        ``weight`` is (out, in) and ``bias`` (out,), as in ``nn.Linear``; consecutive layers must
        chain (out of one = in of the next). This is how policies of other libraries (SB3,
        rsl_rl) become an MLPActor.

        Raises:
            ValueError: no layers, shapes that do not chain, unknown activation.
        """
        if not layers:
            raise ValueError("from_linear_layers: no layers")
        shapes = [(tuple(w.shape), tuple(b.shape)) for w, b in layers]
        for i, ((ws, bs), nxt) in enumerate(zip(shapes, [*shapes[1:], None], strict=True)):
            if len(ws) != 2 or bs != (ws[0],):
                raise ValueError(f"layer {i}: weight {ws} and bias {bs} do not form a Linear layer")
            if nxt is not None and nxt[0][1] != ws[0]:
                raise ValueError(
                    f"layer {i + 1}: expects {nxt[0][1]} inputs, layer {i} gives {ws[0]}"
                )
        actor = cls(
            obs_dim=shapes[0][0][1],
            act_dim=shapes[-1][0][0],
            hidden=tuple(ws[0] for ws, _ in shapes[:-1]),
            activation=activation,
            output=output,
        )
        linears = [m for m in actor.net if isinstance(m, nn.Linear)]
        with torch.no_grad():
            for lin, (w, b) in zip(linears, layers, strict=True):
                lin.weight.copy_(w.detach().to(torch.float32))
                lin.bias.copy_(b.detach().to(torch.float32))
        return actor


@dataclass(frozen=True, eq=False)
class Checkpoint:
    """The validated content of a checkpoint file (see the module docstring)."""

    actor: MLPActor
    spec: PolicySpec
    obs_normalizer: ObservationNormalizer | None
    info: dict[str, Any] = field(default_factory=dict)


def _check_plain(value: Any, where: str) -> None:
    """Raise CheckpointError unless ``value`` is plain data (what ``weights_only`` loads)."""
    if value is None or isinstance(value, bool | int | float | str):
        return
    if isinstance(value, list | tuple):
        for i, v in enumerate(value):
            _check_plain(v, f"{where}[{i}]")
        return
    if isinstance(value, dict):
        for k, v in value.items():
            if not isinstance(k, str):
                raise CheckpointError(f"{where}: keys must be strings, got {k!r}")
            _check_plain(v, f"{where}.{k}")
        return
    raise CheckpointError(
        f"{where}: {type(value).__name__} is not plain data (str, numbers, lists, dicts)"
    )


def checkpoint_from_dict(d: Any, source: str | Path) -> Checkpoint:
    """Validate the dict of a checkpoint file (see the module docstring).

    Args:
        d: What ``torch.load`` returned.
        source: The file name, for messages.

    Raises:
        CheckpointError: missing or invalid field, non-finite weights, sizes that disagree with
            the spec; the message names ``source`` and the field.
    """
    src = str(source)
    if not isinstance(d, Mapping):
        raise CheckpointError(f"{src}: expected a dict, got {type(d).__name__}")
    if d.get("format") != FORMAT:
        raise CheckpointError(
            f"{src}: field 'format' is {d.get('format')!r}, expected '{FORMAT}' "
            "(not a sim2real-deploy checkpoint)"
        )
    if d.get("format_version") != FORMAT_VERSION:
        raise CheckpointError(
            f"{src}: field 'format_version' is {d.get('format_version')!r}; this version reads "
            f"{FORMAT_VERSION}"
        )
    for key in ("architecture", "state_dict", "spec"):
        if key not in d:
            raise CheckpointError(f"{src}: field '{key}' is missing")
    actor = MLPActor.from_architecture(d["architecture"], where=f"{src}: field 'architecture'")
    sd = d["state_dict"]
    if not isinstance(sd, Mapping) or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise CheckpointError(f"{src}: field 'state_dict': expected a dict of tensors")
    expected = actor.state_dict()
    missing = sorted(set(expected) - set(sd))
    unexpected = sorted(set(sd) - set(expected))
    if missing or unexpected:
        raise CheckpointError(
            f"{src}: field 'state_dict' does not match the architecture "
            f"(missing {missing}, unexpected {unexpected})"
        )
    for key, t in expected.items():
        if tuple(sd[key].shape) != tuple(t.shape):
            raise CheckpointError(
                f"{src}: field 'state_dict'['{key}']: shape {tuple(sd[key].shape)}, the "
                f"architecture needs {tuple(t.shape)}"
            )
    finite_check(sd, f"{src}: field 'state_dict'")
    actor.load_state_dict({k: v.to(torch.float32) for k, v in sd.items()})
    actor.eval()
    if not isinstance(d["spec"], str):
        raise CheckpointError(f"{src}: field 'spec': expected the PolicySpec JSON string")
    try:
        spec = PolicySpec.from_json(d["spec"], source=f"{src}: field 'spec'")
    except SpecError as exc:
        raise CheckpointError(str(exc)) from None
    if spec.obs_dim != actor.obs_dim:
        raise CheckpointError(
            f"{src}: field 'architecture.obs_dim': the network takes {actor.obs_dim} inputs, the "
            f"spec's observation has {spec.obs_dim}"
        )
    if spec.act_dim != actor.act_dim:
        raise CheckpointError(
            f"{src}: field 'architecture.act_dim': the network gives {actor.act_dim} outputs, the "
            f"spec's action has {spec.act_dim}"
        )
    norm = d.get("obs_normalizer")
    if norm is not None:
        norm = ObservationNormalizer.from_dict(norm, where=f"{src}: field 'obs_normalizer'")
        norm.validate(f"{src}: field 'obs_normalizer'", obs_dim=spec.obs_dim)
    info = d.get("info") or {}
    if not isinstance(info, Mapping):
        raise CheckpointError(f"{src}: field 'info': expected a dict")
    return Checkpoint(actor=actor, spec=spec, obs_normalizer=norm, info=dict(info))


def read_checkpoint(path: str | Path) -> Checkpoint:
    """Load and validate a checkpoint file, with its ``info``.

    Raises:
        CheckpointError: see :func:`load_checkpoint`.
    """
    path = Path(path)
    return checkpoint_from_dict(read_torch_file(path), path)


def load_checkpoint(
    path: str | Path,
) -> tuple[MLPActor, PolicySpec, ObservationNormalizer | None]:
    """Load a checkpoint written by :func:`save_checkpoint`.

    Returns:
        ``(actor, spec, normalizer)``: the actor in eval mode (float32), its PolicySpec and the
        observation normalizer (None if the policy has none).

    Raises:
        CheckpointError: missing, empty, truncated or corrupt file; pickled Python objects; wrong
            ``format`` or ``format_version``; missing or invalid field; state dict that does not
            match the architecture; non-finite weights; network sizes that disagree with the spec.
            The message names the file and the field.
    """
    ckpt = read_checkpoint(path)
    return ckpt.actor, ckpt.spec, ckpt.obs_normalizer


def save_checkpoint(
    path: str | Path,
    actor: MLPActor,
    spec: PolicySpec | str,
    obs_normalizer: ObservationNormalizer | Mapping[str, Any] | None = None,
    info: Mapping[str, Any] | None = None,
) -> Path:
    """Write a checkpoint atomically (temporary file in the same folder, then ``os.replace``).

    Args:
        path: Destination ``.pt`` file; its folder is created if needed.
        actor: The actor (weights are saved as float32 on CPU).
        spec: Its PolicySpec (or the spec's JSON).
        obs_normalizer: Optional empirical normalizer, an :class:`ObservationNormalizer` or a dict
            ``{"mean", "var", "epsilon", "clip"}``.
        info: Optional plain data (str, numbers, lists, dicts) stored under ``"info"``.

    Returns:
        The path written.

    Raises:
        TypeError: ``actor`` is not an MLPActor.
        CheckpointError: invalid spec or normalizer, sizes that disagree, non-finite weights.
            Nothing is written then.
    """
    path = Path(path)
    if not isinstance(actor, MLPActor):
        raise TypeError(f"save_checkpoint: actor must be an MLPActor, got {type(actor).__name__}")
    if isinstance(spec, str):
        try:
            spec = PolicySpec.from_json(spec, source="save_checkpoint: spec")
        except SpecError as exc:
            raise CheckpointError(str(exc)) from None
    if spec.obs_dim != actor.obs_dim or spec.act_dim != actor.act_dim:
        raise CheckpointError(
            f"{path}: the actor maps {actor.obs_dim} -> {actor.act_dim}, the spec "
            f"{spec.obs_dim} -> {spec.act_dim}"
        )
    state_dict = {
        k: v.detach().to("cpu", torch.float32).clone() for k, v in actor.state_dict().items()
    }
    finite_check(state_dict, f"{path}: state_dict")
    norm = None
    if obs_normalizer is not None:
        if not isinstance(obs_normalizer, ObservationNormalizer):
            obs_normalizer = ObservationNormalizer.from_dict(obs_normalizer)
        obs_normalizer.validate(f"{path}: obs_normalizer", obs_dim=spec.obs_dim)
        norm = obs_normalizer.to_dict()
    _check_plain(dict(info or {}), f"{path}: info")
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "architecture": actor.architecture,
        "state_dict": state_dict,
        "spec": spec.to_json(),
        "obs_normalizer": norm,
        "info": dict(info or {}),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path
