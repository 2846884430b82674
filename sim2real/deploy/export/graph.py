"""The ONNX graph of a loaded source: torch's exporters (the TorchScript-based one by default, the
``torch.export``-based one with ``--exporter dynamo``) at opset ``OPSET``, a recurrent module with
explicit state I/O (TorchScript-based only), ``onnx.checker`` passed (full check), and the
metadata written into the model (:func:`set_metadata`, :func:`tool_versions`).
"""

from __future__ import annotations

import io
import platform
import re
import warnings
from collections.abc import Mapping
from pathlib import Path

import onnx
import onnxruntime as ort
import torch
from torch import nn

from sim2real.deploy.export.errors import ExportError, _first_line
from sim2real.deploy.export.recurrent import recurrent_signature

OPSET = 18
EXPORTERS = ("torchscript", "dynamo")


def package_version() -> str:
    """Version of this package (installed metadata, else ``pyproject.toml``)."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("sim2real-deploy")
    except PackageNotFoundError:
        pass
    pyproject = Path(__file__).resolve().parents[3] / "pyproject.toml"
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


def to_bare_onnx(module: nn.Module, obs_dim: int) -> onnx.ModelProto:
    """Export ``module`` as another stack's bare graph: input ``obs`` [1, obs_dim], output
    ``actions`` [1, act_dim], the batch fixed at 1 (as rl_sar runs its TorchScript, and Isaac
    Lab's exporter writes), TorchScript-based exporter at opset ``OPSET``, no metadata.

    Raises:
        ExportError: the exporter failed, or the checker rejects the graph.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            example = (torch.zeros(1, obs_dim),)
            model = _torchscript_onnx(module, example, ["obs"], ["actions"], {})
        onnx.checker.check_model(model, full_check=True)
    except Exception as exc:  # noqa: BLE001 - exporter and checker failures of all kinds
        raise ExportError(f"torch.onnx.export failed: {_first_line(exc)}") from None
    return model


def _recurrent_to_onnx(module: nn.Module, obs_dim: int, exporter: str) -> onnx.ModelProto:
    """A recurrent module (:class:`sim2real.deploy.export.recurrent.RecurrentPolicyModule`) to ONNX with
    explicit state I/O (:func:`sim2real.deploy.export.recurrent.recurrent_signature`).

    Raises:
        ExportError: another exporter than TorchScript, or the exporter or checker failed.
    """
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
