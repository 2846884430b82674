"""Calling a compiled kernel without numba's dispatch, the two ways the tick does it.

Calling a numba dispatcher types every argument first (``typeof``; a named tuple of arrays field
by field) to pick the specialization, then calls that specialization's entry point, which unboxes
the arguments and runs the machine code; for a small robot the typing costs more than the
arithmetic.

- :func:`bind`: a stage that calls its kernel on the same arrays every tick knows the
  specialization already: the entry point, looked up once, with the arguments that do not change
  bound to it. The entry point does not check its arguments' types: it is only called with the
  very objects it was bound with (the caller compares them by identity), or with Python scalars
  of the bound scalar types; anything else goes through the dispatcher.
- One table of a kernel's arrays: declared once and read by name in the kernel
  (:mod:`sim2real.deploy.kernels.tables`), bound as one argument. :func:`pointer` is left to the
  kernels that view foreign memory (each env's ``MjData`` arrays) by an address a declared
  int64 field holds.
"""

from __future__ import annotations

import functools
import importlib

import numpy as np
from numba.core import cgutils, types
from numba.extending import intrinsic


class Bound(functools.partial):
    """A kernel's entry point with its first arguments bound (:func:`bind`). It pickles and
    copies as the kernel's name and those arguments: the copy binds its own copies of them (a
    :class:`~sim2real.deploy.kernels.tables.Packed` table packs its arrays at their new
    addresses), so an owner keeps it as any other attribute."""

    def __reduce__(self):
        kernel, args, rest = self.binding
        return _rebind, (kernel.py_func.__module__, kernel.py_func.__qualname__, args, rest)


def _rebind(module: str, name: str, args: tuple, rest: tuple) -> Bound:
    return bind(getattr(importlib.import_module(module), name), *args, rest=rest)


def bind(kernel, *args, rest: tuple = ()) -> Bound:
    """The entry point of the numba dispatcher ``kernel`` specialized to the types of ``args``
    and ``rest`` (compiled, or loaded from numba's cache, now), with ``args`` bound: a callable
    taking the remaining arguments, of the types of the examples ``rest`` (e.g. ``(0,)``: an int
    given at each call). Each array's dtype, dimensions, layout and writeability and each
    scalar's type select the specialization.

    Raises:
        numba.core.errors.TypingError: the kernel does not compile for these types.
    """
    types = tuple(kernel.typeof_pyval(a) for a in (*args, *rest))
    if types not in kernel.overloads:
        kernel.compile(types)
    bound = Bound(kernel.overloads[types].entry_point, *args)
    bound.binding = (kernel, args, rest)
    return bound


@intrinsic
def pointer(typingctx, address):
    """The integer ``address`` as a ``void *`` (for ``numba.carray``), in a compiled kernel."""

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return types.voidptr(address), codegen


def fits(array, dtype, shape: tuple) -> bool:
    """Whether ``array`` is a C-contiguous numpy array of ``dtype`` and exactly ``shape``: what a
    kernel bound to it (:func:`bind`) may be called with again."""
    return (
        isinstance(array, np.ndarray)
        and array.dtype == dtype
        and array.shape == shape
        and array.flags.c_contiguous
    )
