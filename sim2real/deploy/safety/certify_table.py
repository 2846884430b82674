"""The motion envelope's certify over one packed table (:func:`certify_servo`,
:func:`certify_drive`): the same kernel (:func:`sim2real.deploy.safety.envelope_kernel.certify`),
its some thirty arrays read from one declared table instead of unboxed one by one at each call.

:data:`SERVO` declares ``certify``'s arrays for a position servo: its first seven arguments and
the fields of :class:`~sim2real.deploy.safety.envelope_kernel.ScreenArrays`; :data:`DRIVEN` adds
those of :class:`~sim2real.deploy.safety.envelope_kernel.DriveArrays` (its ``joint`` as
``drive_joint``) for a velocity drive, whose mass matrix Pinocchio keeps in Fortran order
(``mass_fortran``: the table holds its transpose, C order, the same memory). The kernels rebuild
the envelope's named tuples field by field name and call ``certify``: the numbers are its own.
:func:`build` returns None (the caller keeps the bound call with the arrays) where an array is
not C-contiguous of its field's dtype and dimensions.
"""

from __future__ import annotations

from inspect import signature

import numba
import numpy as np

from sim2real.deploy.kernels.tables import Table
from sim2real.deploy.safety import envelope_kernel as ek

#: ``certify``'s arrays for a position servo (shapes and units there).
SERVO = Table(
    "sim2real.deploy.safety.certify_table:SERVO",
    q="f8[envs,n]", dq="f8[envs,n]", before="f8[3,envs,n]", after="f8[3,envs,n]",
    stopping="b1[envs]", effort_scale="f8[envs,n]", command="f8[envs,n]", margin="f8",
    limits="f8[*,*]", cached_q="f8[*,*,*]", clearance="f8[*,*]", weights="f8[*,*]",
    box="f8[*,*,*]", need="b1[*,*]", joint="i8[*,*]", grid="f8[*,*,*]", cells="i8[*,*]",
    offset="i8[*,*]", values="f8[*]", speeds="f8[*,*,*]", order="i8[*]", nest="i1[*,*,*]",
    slack="f8[*,*]", lead="f8[*,*]", scratch="f8[*,*]",
)  # fmt: skip
#: ... and a velocity drive's.
DRIVEN = SERVO.extend(
    "sim2real.deploy.safety.certify_table:DRIVEN",
    dt="f8", mass_fortran="b1", setpoint="f8[*,*]", gravity="f8[*,*]", mass="f8[*,*,*]",
    drive_joint="f8[*,*]", variance="f8[*,*]", uncertainty="f8[*]", lower="f8[*]",
    upper="f8[*]", path="f8[*,*,*,*]", beyond="b1[*]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True, inline="always")
def _screen(t):
    return ek.ScreenArrays(
        limits=t.limits, cached_q=t.cached_q, clearance=t.clearance, weights=t.weights,
        margin=t.margin, box=t.box, need=t.need, joint=t.joint, grid=t.grid, cells=t.cells,
        offset=t.offset, values=t.values, speeds=t.speeds, order=t.order, nest=t.nest,
        slack=t.slack, lead=t.lead, scratch=t.scratch,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def certify_servo(t) -> int:
    """``certify`` of a position servo's packed table ``t`` (:data:`SERVO`); returns its code."""
    return ek.certify(
        t.q, t.dq, t.before, t.after, t.stopping, t.effort_scale, t.command, _screen(t), None
    )


@numba.njit(cache=True, nogil=True, inline="always")
def _driven(t, mass):
    d = ek.DriveArrays(
        setpoint=t.setpoint, gravity=t.gravity, mass=mass, joint=t.drive_joint,
        variance=t.variance, uncertainty=t.uncertainty, dt=t.dt, lower=t.lower, upper=t.upper,
        path=t.path, beyond=t.beyond,
    )  # fmt: skip
    s = _screen(t)
    return ek.certify(t.q, t.dq, t.before, t.after, t.stopping, t.effort_scale, t.command, s, d)


@numba.njit(cache=True, nogil=True)
def certify_drive(t) -> int:
    """``certify`` of a velocity drive's packed table ``t`` (:data:`DRIVEN`; its mass matrix
    in either order); returns its code."""
    if t.mass_fortran:
        return _driven(t, t.mass.T)
    return _driven(t, t.mass)


def build(args: tuple, screen: ek.ScreenArrays, drive: ek.DriveArrays | None):
    """The packed table of ``certify``'s arguments ``args`` (its first seven, in its order),
    ``screen`` and ``drive`` (module docstring): :data:`DRIVEN` with a drive, else
    :data:`SERVO`; None where an array does not fit its field."""
    names = list(signature(ek.certify.py_func).parameters)[: len(args)]
    values = dict(zip(names, args, strict=True)) | screen._asdict()
    if drive is None:
        return SERVO.pack_or_none(**values)
    values |= {("drive_joint" if k == "joint" else k): v for k, v in drive._asdict().items()}
    mass = values["mass"]
    fortran = isinstance(mass, np.ndarray) and not mass.flags.c_contiguous
    values |= {"mass": mass.T if fortran else mass, "mass_fortran": fortran}
    return DRIVEN.pack_or_none(**values)


def kernel(table):
    """The kernel of a packed table of :func:`build`."""
    return certify_drive if table.table is DRIVEN else certify_servo
