"""The motion envelope's certify over a table of addresses (:func:`certify_table`): the same
kernel (:func:`sim2real.deploy.safety.envelope_kernel.certify`), its some thirty arrays viewed
from one int64 table instead of unboxed one by one at each call.

The table (:func:`build`): a header (``FLAGS``: a velocity drive, its mass matrix in Fortran
order as Pinocchio keeps it), then per array of :data:`SLOTS` its address and up to four
dimensions (:mod:`sim2real.deploy.kernels.calls`), and the two scalars (the margin, the drive's
period) in a float64 array of their own. The kernel rebuilds the envelope's named tuples from
the views and calls ``certify``: the numbers are its own. :func:`build` returns None (the caller
keeps the bound call with the arrays) where an array is not C-contiguous of the slot's dtype and
dimensions.
"""

from __future__ import annotations

import numba
import numpy as np

from sim2real.deploy.kernels.calls import SLOT, pointer, put_slot, view1, view2, view3, view4
from sim2real.deploy.safety import envelope_kernel as ek

#: Each array's slot: the argument or field of ``certify`` it is, its dtype and dimensions.
SLOTS = (
    *(("q", "f8", 2), ("dq", "f8", 2), ("before", "f8", 3), ("after", "f8", 3)),
    *(("stopping", "b1", 1), ("effort_scale", "f8", 2), ("command", "f8", 2)),
    *(("limits", "f8", 2), ("cached_q", "f8", 3), ("clearance", "f8", 2), ("weights", "f8", 2)),
    *(("box", "f8", 3), ("need", "b1", 2), ("joint", "i8", 2), ("grid", "f8", 3)),
    *(("cells", "i8", 2), ("offset", "i8", 2), ("values", "f8", 1), ("speeds", "f8", 3)),
    *(("order", "i8", 1), ("nest", "i1", 3), ("slack", "f8", 2), ("lead", "f8", 2)),
    *(("scratch", "f8", 2), ("setpoint", "f8", 2), ("gravity", "f8", 2), ("mass", "f8", 3)),
    *(("drive_joint", "f8", 2), ("variance", "f8", 2), ("uncertainty", "f8", 1)),
    *(("lower", "f8", 1), ("upper", "f8", 1), ("path", "f8", 4), ("beyond", "b1", 1)),
    ("scalars", "f8", 1),
)
#: The header's flags: a velocity drive; its mass matrix in Fortran order.
FLAGS, DRIVE, MASS_F = 0, 1, 2
#: The first slot's index in the table.
HEAD = 1
_NAMES = [s[0] for s in SLOTS]
_MASS, _SETPOINT, _SCALARS = _NAMES.index("mass"), _NAMES.index("setpoint"), len(SLOTS) - 1


@numba.njit(cache=True, nogil=True, inline="always")
def _call(t, mass):
    """``certify`` of the table's views (``mass`` the drive's mass matrix, either order)."""
    f8, b1, i8, w, h = np.float64, np.bool_, np.int64, SLOT, HEAD
    scalars = view1(t, h + w * 34, f8)
    s = ek.ScreenArrays(
        view2(t, h + w * 7, f8), view3(t, h + w * 8, f8), view2(t, h + w * 9, f8),
        view2(t, h + w * 10, f8), scalars[0], view3(t, h + w * 11, f8),
        view2(t, h + w * 12, b1), view2(t, h + w * 13, i8), view3(t, h + w * 14, f8),
        view2(t, h + w * 15, i8), view2(t, h + w * 16, i8), view1(t, h + w * 17, f8),
        view3(t, h + w * 18, f8), view1(t, h + w * 19, i8), view3(t, h + w * 20, np.int8),
        view2(t, h + w * 21, f8), view2(t, h + w * 22, f8), view2(t, h + w * 23, f8),
    )  # fmt: skip
    args = (view2(t, h, f8), view2(t, h + w, f8), view3(t, h + w * 2, f8))
    args2 = (view3(t, h + w * 3, f8), view1(t, h + w * 4, b1), view2(t, h + w * 5, f8))
    command = view2(t, h + w * 6, f8)
    if mass is None:
        return ek.certify(*args, *args2, command, s, None)
    d = ek.DriveArrays(
        view2(t, h + w * 24, f8), view2(t, h + w * 25, f8), mass, view2(t, h + w * 27, f8),
        view2(t, h + w * 28, f8), view1(t, h + w * 29, f8), scalars[1],
        view1(t, h + w * 30, f8), view1(t, h + w * 31, f8), view4(t, h + w * 32, f8),
        view1(t, h + w * 33, b1),
    )  # fmt: skip
    return ek.certify(*args, *args2, command, s, d)


@numba.njit(cache=True, nogil=True)
def certify_table(table: np.ndarray) -> int:
    """:func:`~sim2real.deploy.safety.envelope_kernel.certify` of the arrays of ``table``
    (module docstring); returns its code."""
    if not table[FLAGS] & DRIVE:
        return _call(table, None)
    at = HEAD + SLOT * _MASS
    shape = (table[at + 1], table[at + 2], table[at + 3])
    if table[FLAGS] & MASS_F:
        return _call(table, numba.farray(pointer(table[at]), shape, np.float64))
    return _call(table, numba.carray(pointer(table[at]), shape, np.float64))


def build(args: tuple, screen: ek.ScreenArrays, drive: ek.DriveArrays | None):
    """The table of ``certify``'s arguments ``args`` (its first seven), ``screen`` and
    ``drive`` (module docstring), and the list of arrays it names (keep it with the table); None
    where an array does not fit its slot."""
    table = np.zeros(HEAD + SLOT * len(SLOTS), dtype=np.int64)
    values = {**dict(zip([s[0] for s in SLOTS[:7]], args, strict=True)), **screen._asdict()}
    if drive is not None:
        values.update(
            {("drive_joint" if k == "joint" else k): v for k, v in drive._asdict().items()}
        )
        values["joint"] = screen.joint
    values["scalars"] = np.array([screen.margin, drive.dt if drive is not None else 0.0])
    arrays: list = []
    flags = 0
    for k, (name, dtype, ndim) in enumerate(SLOTS):
        if drive is None and _SETPOINT <= k < _SCALARS:  # a position servo: no drive's arrays
            continue
        a = values.get(name)
        shape = getattr(a, "shape", None)
        if name == "mass" and isinstance(a, np.ndarray) and not a.flags.c_contiguous:
            a, flags = a.T, flags | MASS_F  # the same memory in C order; the kernel's farray
        if not put_slot(table, arrays, HEAD + SLOT * k, a, dtype, ndim, shape):
            return None
    table[FLAGS] = flags | (DRIVE if drive is not None else 0)
    return table, arrays
