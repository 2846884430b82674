"""One registry of named entries, for every seam a contributor extends by registration: the
backends (:mod:`sim2real.deploy.backends.registry`), the physics engines
(:mod:`sim2real.deploy.backends.sim.engines`), deploy-run's after-tick hooks
(:mod:`sim2real.deploy.rig.hooks`) and the robot kinds (:mod:`sim2real.deploy.robot_kind`).

An entry is registered once under its name; the built-in entries register when the modules named
at the registry's creation are imported (light modules: a registry lists its entries without
importing MuJoCo or a vendor SDK). Code an entry runs is named ``"module:attribute"`` and imported
only when used (:func:`load_target`).
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Generic, TypeVar

T = TypeVar("T")


def load_target(target: str):
    """The attribute ``target`` (``"module:attribute"``) names, its module imported now.

    Raises:
        ImportError: the module cannot be imported; AttributeError: it has no such attribute.
    """
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def check_target(what: str, name: str, target: str) -> None:
    """Raise ``ValueError`` naming the entry unless ``target`` is ``"module:attribute"``."""
    if ":" not in target:
        raise ValueError(f"{what} '{name}': {target!r} is not 'module:attribute'")


class Registry(Generic[T]):
    """Named entries of one kind.

    Args:
        what: The entries' kind, for messages (``"backend"``, ``"engine"``, ...).
        builtin: Modules whose import registers the built-in entries.
    """

    def __init__(self, what: str, builtin: tuple[str, ...] = ()):
        self.what = what
        self.builtin = builtin
        self._entries: dict[str, T] = {}

    def register(self, name: str, entry: T) -> T:
        """Register ``entry`` under ``name``; returns it.

        Raises:
            ValueError: ``name`` is registered already.
        """
        if name in self._entries:
            raise ValueError(f"{self.what} '{name}' is registered already")
        self._entries[name] = entry
        return entry

    def entries(self) -> dict[str, T]:
        """The entries by name, in registration order (the built-in modules imported first)."""
        for module in self.builtin:
            importlib.import_module(module)
        return dict(self._entries)

    def names(self) -> tuple[str, ...]:
        """The registered names, in registration order."""
        return tuple(self.entries())

    def get(self, name: str) -> T:
        """The entry ``name``.

        Raises:
            ValueError: no entry of that name (the message lists the known ones).
        """
        entries = self.entries()
        if name not in entries:
            raise ValueError(f"{self.what} '{name}' is unknown; expected one of {tuple(entries)}")
        return entries[name]

    @contextmanager
    def scoped(self) -> Iterator[Registry[T]]:
        """Entries registered inside the ``with`` block are forgotten after it (a test's)."""
        kept = self.entries()
        try:
            yield self
        finally:
            self._entries = kept
