"""Files the toolkit writes and fingerprints: atomic writes and SHA-256 digests.

Every file the toolkit writes for a user or for a later run (ONNX exports, checkpoints, reports,
soak checkpoints, bench results, run reports) goes through :func:`atomic_write` or
:func:`atomic_path`: the bytes go to a temporary file in the destination's folder (same file
system, so the rename is atomic), are flushed and ``fsync``-ed, and the temporary file is then
moved onto the destination with ``os.replace``. A reader therefore sees the previous file or the
new one, never a part of one, whatever moment a crash or ``kill -9`` strikes. A failed write
removes its temporary file and leaves the destination untouched.

Temporary files are named ``<name>.<random>.part`` and created exclusively, so two writers of the
same destination never share one, and a leftover of a crashed write is recognisable by its
``.part`` suffix (the soak's film recorder skips such files). They are created with the mode a
plain ``open(path, "w")`` gives (0o666 less the umask), unlike ``tempfile.mkstemp``'s 0o600, so
that a written file is as readable as any other the user creates.

This module imports only the standard library: the runtime install (no torch) uses it.
"""

from __future__ import annotations

import hashlib
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: Read size of :func:`sha256_file` (1 MiB): large enough that the digest, not the system calls,
#: bounds the speed; small enough that a multi-gigabyte file is never held in memory.
CHUNK = 1 << 20


def sha256_file(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes, read in chunks of :data:`CHUNK` bytes.

    Args:
        path: The file.

    Returns:
        The digest as 64 lowercase hexadecimal characters.

    Raises:
        OSError: the file cannot be opened or read (FileNotFoundError, IsADirectoryError, ...).
    """
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def _create_temporary(path: Path) -> tuple[int, Path]:
    """A new file ``<name>.<random>.part`` beside ``path``, opened for writing: (fd, its path)."""
    while True:
        tmp = path.with_name(f"{path.name}.{secrets.token_hex(4)}.part")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), tmp
        except FileExistsError:  # another writer drew the same name: draw again
            continue


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Context manager for writers that need a file name (``torch.save``, ``onnx.save``, ...).

    Yields the path of a new, empty temporary file in ``path``'s folder. The body writes it (and
    may check it: a body that raises discards it). When the body returns, the temporary file is
    ``fsync``-ed and moved onto ``path`` with ``os.replace``; when it raises, the temporary file
    is removed, ``path`` is left as it was and the exception propagates.

    Args:
        path: Destination file. Its folder must exist (it is not created).

    Yields:
        The temporary file's path.

    Raises:
        OSError: the folder does not exist or is not writable (raised on entry), or the rename
            fails (e.g. ``path`` is an existing folder).
    """
    path = Path(path)
    fd, tmp = _create_temporary(path)
    os.close(fd)
    try:
        yield tmp
        _fsync_path(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder, fsync,
    ``os.replace``; see the module docstring).

    Args:
        path: Destination file. Its folder must exist (it is not created).
        data: The file's content; a ``str`` is encoded as UTF-8.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OSError: the folder does not exist or is not writable, the disk is full, or ``path`` is
            an existing folder. ``path`` is left as it was.
    """
    path = Path(path)
    payload = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    fd, tmp = _create_temporary(path)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path
