"""Torch files read safely: ``torch.load(weights_only=True)``, our words for a damaged file, and
the error of a checkpoint that cannot be used.

:func:`read_torch_file` loads a file on CPU without running code from it and raises
:class:`CheckpointError` naming the file (missing, empty, truncated, corrupt, or holding pickled
Python objects); :func:`unreadable_torch_file` and :func:`load_failure_cause` phrase a load
failure without torch's advice to pass ``weights_only=False``; :func:`finite_check` refuses NaN or
inf in a checkpoint's tensors (:func:`first_non_finite` finds them, for the exporters too).
"""

from __future__ import annotations

import io
import os
import pickle
import re
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from sim2real.robots.errors import Sim2RealError


class CheckpointError(Sim2RealError, ValueError):
    """A checkpoint is missing, unreadable or invalid; the message names the file and the field."""


def first_non_finite(tensors: Mapping[str, Any]) -> tuple[str, int, tuple[int, ...]] | None:
    """The first floating tensor of ``tensors`` (name -> value; values that are not floating
    tensors are passed over) that holds NaN or inf: ``(name, count of non-finite values, its
    shape)``; None when every one is finite. Raises nothing."""
    for name, t in tensors.items():
        if isinstance(t, torch.Tensor) and t.is_floating_point():
            bad = int((~torch.isfinite(t)).sum())
            if bad:
                return str(name), bad, tuple(t.shape)
    return None


def finite_check(tensors: Mapping[str, Any], where: str) -> None:
    """Raise CheckpointError if a floating tensor in ``tensors`` holds NaN or inf
    (:func:`first_non_finite`); ``where`` names the file and field in the message."""
    found = first_non_finite(tensors)
    if found is not None:
        name, bad, shape = found
        raise CheckpointError(
            f"{where}['{name}']: {bad} non-finite value(s) (NaN or inf) in a tensor of shape {shape}"
        )


def unsafe_globals_in(exc: BaseException) -> str | None:
    """The class named by a ``weights_only`` unpickling refusal, or None if ``exc`` is not one."""
    m = re.search(r"Unsupported global: GLOBAL ([\w.]+)", str(exc))
    return m.group(1) if m else None


def torch_file_problem(path: str | os.PathLike) -> str | None:
    """What makes ``path`` no torch file at all, or None if it could be one.

    ``torch.save`` writes a zip archive (since PyTorch 1.6; TorchScript and Stable-Baselines3
    files are zip archives too) or, in the legacy format, a pickle, whose first byte is the
    PROTO opcode 0x80 (pickle protocol 2 and later). Anything else is refused before torch's own
    error (which suggests ``weights_only=False``, advice that does not apply to a damaged file).
    """
    with open(path, "rb") as f:
        head = f.read(4)
    if head.startswith(b"PK\x03\x04") or head[:1] == b"\x80":
        return None
    return (
        f"not a torch file: it starts with bytes {head.hex(' ')}, neither a zip archive "
        "(torch.save, TorchScript, Stable-Baselines3) nor a pickle (legacy torch.save); the "
        "file is damaged or of another kind"
    )


def unreadable_torch_file(path: str | os.PathLike, exc: BaseException) -> str:
    """Our words for a ``torch.load(..., weights_only=True)`` failure that is not a refusal of a
    pickled object (:func:`unsafe_globals_in` returned None): the file is truncated, corrupted
    or was not written by ``torch.save``.

    torch's own message for such a file says that ``weights_only=False`` "will likely succeed";
    for a damaged file that advice is wrong, and following it would unpickle untrusted bytes. The
    message returned here names the file, its size and what it looked like, and keeps only the
    low-level cause (the unpickler's complaint or the first sentence of the reader's error).

    Args:
        path: The file that failed to load (named in the message; read for its size and head).
        exc: What ``torch.load`` raised.

    Returns:
        A one-line message starting with ``path``.
    """
    path = Path(path)
    try:
        size = f"{path.stat().st_size} bytes"
        with open(path, "rb") as f:
            zipped = f.read(4).startswith(b"PK\x03\x04")
    except OSError:
        size, zipped = "unreadable", False
    kind = "a zip archive (torch.save)" if zipped else "a pickle (legacy torch.save)"
    return (
        f"{path}: not a readable torch file (truncated or corrupt?): it starts like {kind} "
        f"but cannot be read ({size}; {load_failure_cause(exc)}); it was cut short, damaged, "
        "or not written by torch.save"
    )


def load_failure_cause(exc: BaseException) -> str:
    """The low-level cause of a ``torch.load`` failure, without torch's advice (see
    :func:`unreadable_torch_file`): e.g. ``"the unpickler found Unsupported operand 8"``."""
    text = str(exc)
    m = re.search(r"WeightsUnpickler error:\s*(\S[^\n]*)", text)
    if m:  # torch's weights_only unpickler met an opcode or type a tensor file never holds
        return f"the unpickler found {m.group(1).strip()}"
    first = text.strip().splitlines()[0] if text.strip() else ""
    if "weights_only" in first:
        return type(exc).__name__
    first = first.split(". ")[0].rstrip(".")  # torch appends advice after the first sentence
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def read_torch_file(path: Path) -> Any:
    """``torch.load(path, weights_only=True)`` on CPU with errors that name the file.

    Raises:
        CheckpointError: missing, empty, truncated or corrupt file, or a file holding pickled
            Python objects (whose loading could run arbitrary code).
    """
    if not path.is_file():
        raise CheckpointError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise CheckpointError(f"{path}: the file is empty")
    problem = torch_file_problem(path)
    if problem is not None:
        raise CheckpointError(f"{path}: {problem}")
    try:
        return load_weights_only(path)
    except pickle.UnpicklingError as exc:
        name = unsafe_globals_in(exc)
        if name is not None:
            raise CheckpointError(
                f"{path}: holds pickled Python objects ({name}), not plain tensors and data; "
                "refusing to unpickle it (that could run arbitrary code)"
            ) from None
        raise CheckpointError(unreadable_torch_file(path, exc)) from None
    except Exception as exc:  # noqa: BLE001 - torch raises many types for damaged files
        raise CheckpointError(unreadable_torch_file(path, exc)) from None


def load_weights_only(source: str | os.PathLike | io.BytesIO) -> Any:
    """``torch.load(source, map_location="cpu", weights_only=True)``, without torch's warning
    about an unusual pickle protocol (a damaged file's first bytes; the error that follows is
    reported by :func:`unreadable_torch_file`).

    Raises:
        Whatever ``torch.load`` raises (``pickle.UnpicklingError``, ``RuntimeError``, ...).
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Detected pickle protocol")
        return torch.load(source, map_location="cpu", weights_only=True)
