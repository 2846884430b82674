"""The export's errors: :class:`ExportError` (bad input, exit status 2), :class:`ParityError`
(the graph disagrees with its source, exit status 1) and :class:`InspectError` (``--inspect``
cannot read the file), and :func:`_first_line`, how a caught exception is named in their messages.
"""

from __future__ import annotations

from typing import Any

from sim2real.robots.errors import Sim2RealError


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


class InspectError(Sim2RealError, ValueError):
    """``--inspect``: the file cannot be read as any policy format; the message names the file and
    why."""


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {lines[0] if lines else ''}"
