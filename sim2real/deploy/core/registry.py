"""One registry of named entries, for every seam a contributor extends by registration: the
backends (:mod:`sim2real.deploy.backends.registry`), the physics engines
(:mod:`sim2real.deploy.backends.sim.engines`), deploy-run's after-tick hooks
(:mod:`sim2real.deploy.rig.hooks`) and the robot kinds (:mod:`sim2real.deploy.robot_kind`); and
the faces of a robot kind in the rooms above it (:class:`Faces`, keyed by the kind's name).

An entry is registered once under its name; the built-in entries register when the modules named
at the registry's creation are imported (light modules: a registry lists its entries without
importing MuJoCo or a vendor SDK). Code an entry runs is named ``"module:attribute"`` and imported
only when used (:func:`load_target`). An entry kept outside the tree registers through a package
entry point of the registry's ``group`` (``sim2real.kinds``, ``sim2real.stacks``): its module is
imported with the built-in ones and registers itself as a built-in module does.
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
        group: The package entry-point group whose entries' modules are imported with the
            built-in ones (once each; :meth:`load_plugins`); None: no plug-ins.
    """

    def __init__(self, what: str, builtin: tuple[str, ...] = (), group: str | None = None):
        self.what = what
        self.builtin = builtin
        self.group = group
        self._entries: dict[str, T] = {}
        self._plugins: set[str] | None = None

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
        if self._plugins is None:
            self.load_plugins()
        return dict(self._entries)

    def load_plugins(self) -> tuple[str, ...]:
        """Import the module of every entry point of :attr:`group` not imported yet (the
        distributions on ``sys.path`` now): each registers its entries as it is imported.

        Returns:
            The entry points' names loaded by this call.

        Raises:
            ImportError: an entry point names a module that cannot be imported (raised as
                ``ImportError`` naming the entry point and the group).
        """
        from importlib.metadata import entry_points

        done = self._plugins if self._plugins is not None else set()
        self._plugins = done
        loaded = []
        for point in entry_points(group=self.group) if self.group else ():
            key = f"{point.name}={point.value}"
            if key in done:
                continue
            done.add(key)
            try:
                point.load()
            except (ImportError, AttributeError) as exc:
                raise ImportError(
                    f"entry point '{point.name} = {point.value}' of group '{self.group}': {exc}"
                ) from exc
            loaded.append(point.name)
        return tuple(loaded)

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


#: Every registry of faces made (:class:`Faces`), in order: a test lists the faces a registered
#: robot kind lacks (``tests/test_seams.py``).
FACE_TYPES: list[Faces] = []


class Faces(Generic[T]):
    """What a room above the robot kinds does for each kind, registered under the kind's name
    in that room (the soak's range defaults in :mod:`sim2real.eval.world.session_ranges`, the
    plant's extras in :mod:`sim2real.deploy.backends.sim.plant_faces`, the film in
    :mod:`sim2real.eval.film.render`): a kind is one module plus its faces, each in its own
    room, and no room below names a room above it. Keyed by name, not by the kind object, so a
    room registers its faces without importing the kinds; inherited along the kind hierarchy:
    a kind without a face of its own takes the nearest of its ``lineage()``
    (:meth:`sim2real.deploy.robot_kind.RobotKind.lineage`: a wheel-legged robot a legged
    robot's).

    Args:
        what: The face's name, for messages (``"soak's range defaults"``).
    """

    def __init__(self, what: str):
        self.what = what
        self._faces: dict[str, T] = {}
        FACE_TYPES.append(self)

    def register(self, kind: str, face: T) -> T:
        """Register ``face`` for the robot kind named ``kind``; returns it.

        Raises:
            ValueError: that kind has this face already.
        """
        if kind in self._faces:
            raise ValueError(f"robot kind '{kind}': {self.what} registered already")
        self._faces[kind] = face
        return face

    def find(self, kind) -> T | None:
        """The face of ``kind``, or None: a robot kind (its ``lineage()``: its own name, then the
        kinds it inherits faces from, nearest first) or a kind's name (that name only)."""
        names = kind.lineage() if hasattr(kind, "lineage") else (kind,)
        for name in names:
            if name in self._faces:
                return self._faces[name]
        return None

    def get(self, kind) -> T:
        """The face of ``kind`` (:meth:`find`): a kind without its own takes the nearest one
        along its lineage (a wheel-legged robot's, a legged robot's).

        Raises:
            ValueError: neither the kind nor one it inherits from registered one (the message
                names the kinds that did).
        """
        face = self.find(kind)
        if face is None:
            name = getattr(kind, "name", kind)
            raise ValueError(
                f"robot kind '{name}' has no {self.what}: expected one registered under its name "
                f"or a kind it inherits from (registered: {sorted(self._faces)})"
            )
        return face

    def kinds(self) -> tuple[str, ...]:
        """The names of the kinds with this face, in registration order."""
        return tuple(self._faces)

    @contextmanager
    def scoped(self) -> Iterator[Faces[T]]:
        """Faces registered inside the ``with`` block are forgotten after it (a test's)."""
        kept = dict(self._faces)
        try:
            yield self
        finally:
            self._faces = kept
