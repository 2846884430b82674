"""Our checkpoints (the :mod:`sim2real.deploy.policy.mlp_checkpoint` format: MLP actor, PolicySpec and
observation
normalizer inside) as a :class:`~sim2real.deploy.export.source.SourcePolicy`; a ``--spec`` given must agree
with the spec inside.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from sim2real.deploy.export.errors import ExportError
from sim2real.deploy.export.source import SourcePolicy, normalizer_module
from sim2real.deploy.policy.mlp_checkpoint import checkpoint_from_dict
from sim2real.deploy.policy.onnx_spec import spec_differences
from sim2real.deploy.policy.torch_file import CheckpointError
from sim2real.deploy.spec.policy_spec import PolicySpec


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
