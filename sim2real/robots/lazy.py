"""Public names a package loads on first use (``module.__getattr__``, PEP 562): importing the
package then imports none of its heavy dependencies."""

from __future__ import annotations

import importlib
from collections.abc import Callable


def lazy_names(package: str, sources: dict[str, str], namespace: dict) -> Callable[[str], object]:
    """The ``__getattr__`` of ``package``: a name of ``sources`` (name -> defining module) is
    imported from its module on first use and kept in ``namespace`` (the package's globals).

    Raises (from the returned function):
        AttributeError: a name not in ``sources``.
    """

    def __getattr__(name: str):
        if name not in sources:
            raise AttributeError(f"module '{package}' has no attribute {name!r}")
        value = getattr(importlib.import_module(sources[name]), name)
        namespace[name] = value
        return value

    return __getattr__
