"""From a file to a :class:`~sim2real.deploy.export.source.SourcePolicy`: :func:`load_source` detects the
format from the content (:func:`_detect`: zip entries, else a torch file), reads torch files
(:func:`_torch_load`: ``weights_only``, unpickling only with ``--trust-pickle``), hands the content
to the format's loader (one module each: :mod:`~sim2real.deploy.export.checkpoint`,
:mod:`~sim2real.deploy.export.torchscript`, :mod:`~sim2real.deploy.export.sb3`,
:mod:`~sim2real.deploy.export.rsl_rl`; a pickled ``nn.Module`` here) and adds ``--vecnormalize`` statistics
(:mod:`~sim2real.deploy.export.vecnormalize`).
"""

from __future__ import annotations

import os
import pickle
import warnings
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from sim2real.deploy.export.checkpoint import _load_checkpoint
from sim2real.deploy.export.errors import ExportError, _first_line
from sim2real.deploy.export.file_kind import check_file, zip_kind
from sim2real.deploy.export.network import _probe, _require_spec, check_finite_tensors
from sim2real.deploy.export.rsl_rl import _load_rsl_rl
from sim2real.deploy.export.sb3 import _load_sb3
from sim2real.deploy.export.source import SourcePolicy, normalizer_module
from sim2real.deploy.export.torchscript import _load_torchscript
from sim2real.deploy.export.vecnormalize import load_vecnormalize
from sim2real.deploy.policy.mlp_checkpoint import ACTIVATIONS, FORMAT
from sim2real.deploy.policy.onnx_spec import read_spec
from sim2real.deploy.policy.torch_file import (
    load_weights_only,
    torch_file_problem,
    unreadable_torch_file,
    unsafe_globals_in,
)
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError
from sim2real.robots.files import sha256_file


def _detect(path: Path) -> str:
    check_file(path, ExportError)
    if path.suffix.lower() == ".onnx":
        raise ExportError(f"{path}: already an ONNX file; export takes a torch checkpoint")
    if not zipfile.is_zipfile(path):
        problem = torch_file_problem(path)
        if problem is not None:
            raise ExportError(f"{path}: {problem}")
        return "torch"  # legacy torch.save format (a pickle), or damaged: torch.load decides
    kind, names = zip_kind(path, ExportError)
    if kind is None:
        raise ExportError(
            f"{path}: a zip archive that is neither a torch checkpoint, a TorchScript module nor "
            f"a Stable-Baselines3 model (entries: {names[:6]})"
        )
    return kind


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


def _load_pickled_module(path: Path, net: nn.Module, spec: PolicySpec | None) -> SourcePolicy:
    spec = _require_spec(spec, path, "pickled nn.Module")
    net = net.float().eval()
    check_finite_tensors(dict(net.state_dict()), str(path))
    _probe(net, spec, path)
    return SourcePolicy(net=net, spec=spec, source_format="pickled-module")


def load_source(
    source: str | os.PathLike,
    spec: PolicySpec | str | os.PathLike | None = None,
    trust_pickle: bool = False,
    vecnormalize: str | os.PathLike | None = None,
    activation: str | None = None,
) -> SourcePolicy:
    """Detect the format of ``source`` and load it (see :mod:`sim2real.deploy.export`).

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
