"""numba's on-disk cache of the toolkit's kernels, keyed on every kernel source at once.

numba keys a cached kernel on its own file's content (``numba.core.caching``: a SHA-256 of the
source file). A kernel compiles the helpers it calls from other modules into its own machine
code (``inline="always"`` or not), so with numba's key an edit to a helper in another file left
every kernel that calls it running the old code from the cache until its ``__pycache__`` was
deleted by hand. Here the key of every kernel in this package is one SHA-256 over the contents
of all the package's modules that mention numba (:func:`package_stamp`): any edit to any of
them recompiles every kernel on its next load, and nothing else does (a checkout that leaves the
contents alone keeps the cache).

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
import sys
from pathlib import Path

#: The package whose kernels take the package-wide key.
PACKAGE_DIR = Path(__file__).resolve().parent
_CACHING = "numba.core.caching"


@functools.lru_cache(maxsize=1)
def package_stamp() -> str:
    """Hex SHA-256 over the relative path and contents of every ``*.py`` under the package that
    contains the word ``numba`` (sorted by path): the source stamp of every kernel here. Read
    once per process."""
    digest = hashlib.sha256()
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        data = path.read_bytes()
        if b"numba" in data:
            digest.update(str(path.relative_to(PACKAGE_DIR)).encode() + b"\0" + data + b"\0")
    return digest.hexdigest()


def _ours(py_file: str) -> bool:
    try:
        return Path(py_file).resolve().is_relative_to(PACKAGE_DIR)
    except OSError:
        return False


def install() -> None:
    """Put the package-wide key first in numba's cache locators (idempotent). Imports numba."""
    from numba.core import caching

    if any(getattr(c, "_sim2real", False) for c in caching.CacheImpl._locator_classes):
        return

    def keyed(base):
        class Locator(base):
            _sim2real = True

            def get_source_stamp(self):
                return package_stamp()

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
