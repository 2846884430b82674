"""The training stacks whose policies carry their own contract, and how a file is matched to one.

The stacks (:mod:`sim2real.stacks`, :func:`sim2real.deploy.core.stacks.stacks`) are tried by rank
(metadata formats first; of those that read a file beside a bare graph, Unitree's deploy.yaml,
which its own deployment reads, and rl_sar's config.yaml before Isaac Lab's env.yaml): the first
whose ``detect`` face accepts a file reads it with its ``contract`` face. :class:`OnnxFacts` is
what they look at (the file, its metadata, the graph's inputs and outputs).
:class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy` (a file without our ``policy_spec`` and no
``--spec``) and ``policy-export --inspect`` both go through :func:`read_contract`. A new format is
one stack module (its ``detect`` and ``contract`` faces), in the tree or through an entry point.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import onnx

from sim2real.deploy.core.stacks import Stack, with_face
from sim2real.deploy.spec.foreign.contract import ForeignContract, ForeignFormatError


def _dims(vi: onnx.ValueInfoProto) -> list[int | str | None]:
    out: list[int | str | None] = []
    for d in vi.type.tensor_type.shape.dim:
        out.append(
            int(d.dim_value)
            if d.HasField("dim_value")
            else (d.dim_param if d.HasField("dim_param") else None)
        )
    return out


@dataclass(frozen=True)
class OnnxFacts:
    """What a format reader may look at.

    Attributes:
        path: The ONNX file. metadata: Its ``metadata_props`` (``str -> str``).
        inputs, outputs: The graph's data input and output names (initializers excluded).
        obs_dim, act_dim: The last axis of the first data input and first output, when fixed.
    """

    path: Path
    metadata: dict[str, str]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    obs_dim: int | None = None
    act_dim: int | None = None

    @classmethod
    def of(cls, path: str | Path, model: onnx.ModelProto) -> OnnxFacts:
        """The facts of a loaded model (external data not needed)."""
        graph = model.graph
        init = {t.name for t in graph.initializer}
        init |= {s.values.name for s in graph.sparse_initializer}
        ins = [i for i in graph.input if i.name not in init]

        def last(vi) -> int | None:
            d = _dims(vi)
            return d[-1] if d and isinstance(d[-1], int) and d[-1] > 0 else None

        primary = next((i for i in ins if i.name in ("obs", "actor_obs")), ins[0] if ins else None)
        action = next(
            (o for o in graph.output if o.name in ("actions", "action")),
            graph.output[0] if len(graph.output) else None,
        )
        return cls(
            path=Path(path),
            metadata={p.key: p.value for p in model.metadata_props},
            inputs=tuple(i.name for i in ins),
            outputs=tuple(o.name for o in graph.output),
            obs_dim=last(primary) if primary is not None else None,
            act_dim=last(action) if action is not None else None,
        )

    def contract(self, fmt: str, source: str, **fields) -> ForeignContract:
        """The :class:`ForeignContract` of this file read as format ``fmt`` from ``source``:
        its path and the graph's sizes from these facts, the other ``fields`` as given (the
        sequences ``terms``, ``found``, ``missing`` and ``notes`` made tuples)."""
        for key in ("terms", "found", "missing", "notes"):
            if key in fields:
                fields[key] = tuple(fields[key])
        return ForeignContract(
            format=fmt,
            source=source,
            path=str(self.path),
            obs_dim=self.obs_dim,
            act_dim=self.act_dim,
            **fields,
        )

    def failure(self, fmt: str):
        """``fail(message)``: a :class:`ForeignFormatError` ``"<path>: <fmt> policy: ..."``."""

        def fail(message: str) -> ForeignFormatError:
            return ForeignFormatError(f"{self.path}: {fmt} policy: {message}")

        return fail


def detect_stack(facts: OnnxFacts) -> Stack | None:
    """The first stack, by rank, whose ``detect`` face recognises the file, or None."""
    return next((stack for stack, detect in with_face("detect") if detect(facts)), None)


def read_contract(facts: OnnxFacts) -> ForeignContract | None:
    """The file's foreign contract; None when no format recognises it.

    Raises:
        ForeignFormatError: a recognised format whose contract cannot be read (naming the file,
            the format and the key).
    """
    stack = detect_stack(facts)
    if stack is None:
        return None
    read = stack.face("contract")
    if read is None:  # a stack that recognises files must read them: tests/test_stack_seams.py
        raise ForeignFormatError(f"{facts.path}: {stack.name} policy: the stack reads no contract")
    return read(facts)


def read_folder_contract(path: str | Path) -> ForeignContract | None:
    """The contract a stack wrote in files beside a policy that is not an ONNX graph yet (rl_sar's
    ``policy.pt`` with ``config.yaml`` beside it and ``../base.yaml`` above it): the formats whose
    ``detect`` reads the folder, not the graph (those that need the graph's ``obs`` -> ``actions``
    names or its metadata do not recognise a file without them). ``obs_dim`` and ``act_dim`` are
    None (no graph to read them from); the same reader reads the ONNX file exported beside it.

    Returns:
        The contract, or None when no format recognises the folder.

    Raises:
        ForeignFormatError: a recognised contract that cannot be read (naming the file and key).
    """
    return read_contract(OnnxFacts(path=Path(path), metadata={}, inputs=(), outputs=()))


def known_formats() -> str:
    """The names of the stacks that read a contract, for messages: ``"mjlab, holosoma, ..."``."""
    return ", ".join(stack.name for stack, _ in with_face("contract"))
