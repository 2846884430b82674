"""A compiled kernel bound to the types of its arguments: its call without numba's dispatch
(the smoother's kernels and, a floor above, the guard's and the motion envelope's).

Calling a numba dispatcher types every argument first (``typeof``; a named tuple of arrays
field by field) to pick the specialization, then calls that specialization's entry point, which
unboxes the arguments and runs the machine code. A stage that calls its
kernel on the same arrays every tick knows the specialization already: :func:`bind` looks it up
once and returns the entry point with the arguments that do not change bound to it.

The entry point does not check its arguments' types: an argument of another type than the one
it was bound for is undefined behaviour (wrong numbers or a crash). So a bound call is only made
with the very objects it was bound with (the caller compares them by identity), or with
Python scalars of the bound scalar types; anything else goes through the dispatcher.
"""

from __future__ import annotations

import functools


def bind(kernel, *args):
    """The entry point of the numba dispatcher ``kernel`` specialized to the types of ``args``
    (compiled, or loaded from numba's cache, now), with ``args`` bound: a callable taking the
    remaining arguments, if any. Each array's dtype, dimensions, layout and writeability and
    each scalar's type select the specialization.

    Raises:
        numba.core.errors.TypingError: the kernel does not compile for these types.
    """
    types = tuple(kernel.typeof_pyval(a) for a in args)
    if types not in kernel.overloads:
        kernel.compile(types)
    return functools.partial(kernel.overloads[types].entry_point, *args)
