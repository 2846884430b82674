"""The toolkit's exception base class.

Every exception class defined in ``deploy/``, ``eval/``, ``robots/`` and ``policies/`` derives
from :class:`Sim2RealError`, so a caller (a script driving the toolkit, a command-line entry
point) can catch the toolkit's own errors in one clause and let genuine bugs through::

    try:
        run_export("sim2real/policies/arm.pt")
    except Sim2RealError as exc:
        print(f"policy-export: {exc}")

Each error class keeps its second, built-in base (``ValueError`` for bad input such as a spec,
a robot description or a checkpoint; ``RuntimeError`` for a failure while running, such as a
diverged simulation or a failed parity check; ``OSError`` for a serial bus), so existing
``except ValueError`` clauses keep working::

    class SpecError(Sim2RealError, ValueError): ...

This module imports nothing: the runtime install (no torch) uses it.
"""

from __future__ import annotations


class Sim2RealError(Exception):
    """Base class of every error the toolkit raises on purpose; the message names the file,
    field or device concerned and the value expected."""
