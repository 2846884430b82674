"""What kind of policy file a path is, as far as ``policy-export`` and ``--inspect`` both tell
it apart before loading: an existing non-empty file, and the kind of a zip archive by its entries
(a Stable-Baselines3 model, a TorchScript module or a ``torch.save`` checkpoint)."""

from __future__ import annotations

import zipfile
from pathlib import Path


def check_file(path: Path, error: type[Exception]) -> None:
    """Raise ``error`` naming ``path`` unless it is an existing, non-empty file.

    Raises:
        error: no such file, not a file, or an empty file.
    """
    if not path.exists():
        raise error(f"{path}: no such file")
    if not path.is_file():
        raise error(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise error(f"{path}: the file is empty")


def zip_kind(path: Path, error: type[Exception]) -> tuple[str | None, list[str]]:
    """``(kind, entries)`` of the zip archive ``path``: kind 'sb3' (``policy.pth`` and
    ``data``), 'torchscript' (``constants.pkl`` or ``code/``), 'torch' (``data.pkl``), or None
    (none of these); entries its names in order.

    Raises:
        error: a damaged archive.
    """
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (zipfile.BadZipFile, OSError) as exc:
        raise error(f"{path}: damaged zip archive: {exc}") from None
    if "policy.pth" in names and "data" in names:
        return "sb3", names
    if any(n.endswith("constants.pkl") or "/code/" in n for n in names):
        return "torchscript", names
    if any(n.endswith("data.pkl") for n in names):
        return "torch", names
    return None, names
