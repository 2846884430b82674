"""Tables of array addresses for compiled kernels: numba's dispatch of each array argument costs
more than an arm's arithmetic, so a kernel may take one int64 table of addresses instead and view
each array with ``numba.carray(pointer(table[i]), shape, dtype)``.

:func:`put` writes an array's address into a table after checking its dtype, shape and layout,
and keeps the array alive in a list the table's owner holds. The arrays must live, keep their
shape and dtype and stay C-contiguous while the table is in use: the owner builds the table
again when it is handed other arrays (compared by identity).
"""

from __future__ import annotations

import numpy as np
from numba.core import cgutils, types
from numba.extending import intrinsic


@intrinsic
def pointer(typingctx, address):
    """The integer ``address`` as a ``void *`` (for ``numba.carray``), in a compiled kernel."""

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)

    return types.voidptr(address), codegen


def put(table, arrays, index, array, dtype, shape: tuple, rows: bool = False) -> bool:
    """Write the address of ``array`` into ``table[index]`` and keep the array in ``arrays``
    (alive as long as the table), if it is a C-contiguous array of ``dtype`` and ``shape`` (at
    least ``shape[0]`` rows with ``rows``); returns whether it is (nothing written if not)."""
    ok = (
        isinstance(array, np.ndarray)
        and array.dtype == dtype
        and array.flags.c_contiguous
        and array.ndim == len(shape)
        and (array.shape[0] >= shape[0] if rows else array.shape[0] == shape[0])
        and array.shape[1:] == shape[1:]
    )
    if ok:
        table[index] = array.ctypes.data
        arrays.append(array)
    return ok
