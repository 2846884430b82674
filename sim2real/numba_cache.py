"""numba's on-disk cache of the toolkit's kernels, keyed on each kernel's own sources.

numba keys a cached kernel on its own file's content (``numba.core.caching``: a SHA-256 of the
source file). A kernel compiles the helpers it calls from other modules into its own machine
code (``inline="always"`` or not), so with numba's key an edit to a helper in another file left
every kernel that calls it running the old code from the cache until its ``__pycache__`` was
deleted by hand. Here the key of a kernel in this package (:func:`source_stamp`) is one SHA-256
over the contents of its own file and of every module of the package that file imports,
followed through their imports (:func:`imported_modules`): every compiled function and every
global a kernel can reach is defined in one of them (a check's kernel reached through a
registry module's tuple too). An edit to any of them recompiles the kernel on its next load; an
edit elsewhere (another kernel's file, a comment in a module it does not import) keeps its
cache, and so does a checkout that leaves the contents alone.

:func:`install` puts the package's locators first in numba's list (``CacheImpl.
_locator_classes``), for the same cache folders numba would choose (``NUMBA_CACHE_DIR``, else
``__pycache__`` beside the file, else the user-wide cache). ``import sim2real`` arranges for it
to run when ``numba.core.caching`` is first imported (:func:`install_when_numba_loads`), so
importing the package does not import numba. A kernel decorated before :func:`install` ran keeps
numba's own key (none in this package: every kernel module is imported after ``sim2real``).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.abc
import importlib.util
import re
import sys
from pathlib import Path

#: The package whose kernels take the key of their own sources.
PACKAGE_DIR = Path(__file__).resolve().parent
_CACHING = "numba.core.caching"
#: ``import sim2real...`` and ``from sim2real... import a, b`` (parenthesized over lines too).
_IMPORT = re.compile(
    rb"^[ \t]*(?:import[ \t]+(sim2real[\w.]*)|from[ \t]+(sim2real[\w.]*)[ \t]+import[ \t]+"
    rb"(\([^)]*\)|[^\n]*))",
    re.M,
)


def _module_file(name: str) -> Path | None:
    """The file of package module ``name`` (``sim2real.x.y``), or None if it names none."""
    path = PACKAGE_DIR.parent.joinpath(*name.split("."))
    for candidate in (path.with_suffix(".py"), path / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


@functools.cache
def _imports(path: Path) -> frozenset[Path]:
    """The files of the package's modules that ``path`` imports by name (its import statements,
    at any indentation; ``from m import x``: ``m`` and, where ``x`` is a module, ``m.x``)."""
    found = set()
    for plain, base, names in _IMPORT.findall(path.read_bytes()):
        module = (plain or base).decode()
        found.add(_module_file(module))
        for name in re.findall(rb"\w+", names):
            if name != b"as":
                found.add(_module_file(f"{module}.{name.decode()}"))
    found.discard(None)
    return frozenset(found)


def imported_modules(py_file: str | Path) -> list[Path]:
    """``py_file`` and every file of the package it imports, followed through their imports
    (the whole closure, not only the modules that mention numba: a registry module's tuple of
    kernels is read by the kernel that unrolls over it), sorted."""
    seen, todo = set(), [Path(py_file).resolve()]
    while todo:
        path = todo.pop()
        if path not in seen:
            seen.add(path)
            todo.extend(_imports(path))
    return sorted(seen)


@functools.cache
def source_stamp(py_file: str) -> str:
    """Hex SHA-256 over the relative path and contents of each file of
    :func:`imported_modules` of ``py_file`` (a kernel's file): the source stamp of its kernels.
    Read once per file and process."""
    digest = hashlib.sha256()
    for path in imported_modules(py_file):
        name = path.relative_to(PACKAGE_DIR.parent) if path.is_relative_to(PACKAGE_DIR) else path
        digest.update(str(name).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _ours(py_file: str) -> bool:
    try:
        return Path(py_file).resolve().is_relative_to(PACKAGE_DIR)
    except OSError:
        return False


def install() -> None:
    """Put the key of each kernel's sources first in numba's cache locators (idempotent).
    Imports numba."""
    from numba.core import caching

    if any(getattr(c, "_sim2real", False) for c in caching.CacheImpl._locator_classes):
        return

    def keyed(base):
        class Locator(base):
            _sim2real = True

            def get_source_stamp(self):
                return source_stamp(self._py_file)

            @classmethod
            def from_function(cls, py_func, py_file):
                return super().from_function(py_func, py_file) if _ours(py_file) else None

        Locator.__name__ = f"Package{base.__name__}"
        return Locator

    bases = (
        caching.UserProvidedCacheLocator,
        caching.InTreeCacheLocator,
        caching.UserWideCacheLocator,
    )
    caching.CacheImpl._locator_classes[:0] = [keyed(b) for b in bases]


class _AfterCaching(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Runs :func:`install` right after ``numba.core.caching`` is executed."""

    def find_spec(self, fullname, path, target=None):
        if fullname != _CACHING:
            return None
        sys.meta_path.remove(self)  # find the real module with the other finders
        try:
            spec = importlib.util.find_spec(fullname)
        finally:
            sys.meta_path.insert(0, self)
        if spec is None or spec.loader is None:
            return None
        self._loader = spec.loader
        spec.loader = self
        return spec

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        self._loader.exec_module(module)
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        install()


def install_when_numba_loads() -> None:
    """:func:`install` now if numba's caching is loaded, else when it is first imported."""
    if _CACHING in sys.modules:
        install()
    elif not any(isinstance(f, _AfterCaching) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterCaching())
