"""Two memory layouts of one IDL struct: the C struct the robot's firmware checks the CRC of, and
the XCDR1 body DDS carries; both derived from the :class:`~cyclonedds.idl.IdlStruct` type.

- **C layout** (:func:`c_dtype`): each member at the next multiple of its alignment (a primitive's
  size; a struct's largest member alignment), a struct's size rounded up to its alignment, as a C
  compiler lays out Unitree's generated structs (``unitree_go::msg::dds_::LowCmd_`` is 812
  bytes). Returned as a numpy structured dtype with nested fields (``motor_cmd`` a (20,) array
  of records), which the backend and the emulator fill in place.
- **XCDR1 body** (:func:`cdr_gather`): the OMG XTypes 1.3 plain CDR encoding (section 7.4.3.5):
  members in order, each primitive aligned to its size relative to the start of the body, no
  padding after a struct. The two layouts differ where a struct starts at an offset its first
  member does not need (a ``MotorCmd_`` after a 2-byte ``bandwidth``), so the body is expressed
  as a gather: ``body = c_bytes[gather]`` with ``-1`` for a padding byte (zero).

Supported members: the primitives of :data:`PRIMITIVES`, fixed-length arrays of them or of
structs, nested structs; everything the low-level messages use (no strings, no sequences).
"""

from __future__ import annotations

import typing
from dataclasses import dataclass
from functools import cache

import numpy as np
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array

#: IDL primitive name -> numpy type (little endian, as the robots and XCDR1 ``CDR_LE`` use).
PRIMITIVES = {
    "bool": "u1",
    "uint8": "u1",
    "int8": "i1",
    "uint16": "<u2",
    "int16": "<i2",
    "uint32": "<u4",
    "int32": "<i4",
    "uint64": "<u8",
    "int64": "<i8",
    "float32": "<f4",
    "float64": "<f8",
}


@dataclass(frozen=True)
class Member:
    """One member of a struct: its name, its element (a primitive name or an IdlStruct class)
    and its array length (None: not an array)."""

    name: str
    element: str | type
    length: int | None


def members(cls: type) -> list[Member]:
    """The members of IdlStruct ``cls`` in declaration order.

    Raises:
        TypeError: a member type this module does not lay out (string, sequence, union, ...).
    """
    out = []
    for name, hint in typing.get_type_hints(cls, include_extras=True).items():
        length = None
        if typing.get_origin(hint) is typing.Annotated:
            base, *extra = typing.get_args(hint)
            if isinstance(extra[0], array):
                length, hint = extra[0].length, extra[0].subtype
            elif isinstance(extra[0], str) and extra[0] in PRIMITIVES:
                out.append(Member(name, extra[0], None))
                continue
            else:
                raise TypeError(f"{cls.__name__}.{name}: member type {hint} is not laid out")
        element = _element(cls, name, hint)
        out.append(Member(name, element, length))
    return out


def _element(cls: type, name: str, hint) -> str | type:
    if isinstance(hint, type) and issubclass(hint, IdlStruct):
        return hint
    if hint is bool:
        return "bool"
    if typing.get_origin(hint) is typing.Annotated:
        _, tag = typing.get_args(hint)
        if isinstance(tag, str) and tag in PRIMITIVES:
            return tag
    raise TypeError(f"{cls.__name__}.{name}: element type {hint} is not laid out")


def _size(element: str | type) -> int:
    return np.dtype(PRIMITIVES[element]).itemsize if isinstance(element, str) else 0


@cache
def c_dtype(cls: type) -> np.dtype:
    """The C layout of IdlStruct ``cls`` as a numpy structured dtype (explicit offsets and
    itemsize; nested records for struct members, subarrays for arrays)."""
    names, formats, offsets = [], [], []
    offset, align = 0, 1
    for m in members(cls):
        if isinstance(m.element, str):
            fmt = np.dtype(PRIMITIVES[m.element])
            a = fmt.itemsize
        else:
            fmt = c_dtype(m.element)
            a = _c_alignment(m.element)
        offset = -(-offset // a) * a
        names.append(m.name)
        formats.append(fmt if m.length is None else (fmt, (m.length,)))
        offsets.append(offset)
        offset += fmt.itemsize * (m.length or 1)
        align = max(align, a)
    size = -(-offset // align) * align
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": size})


@cache
def _c_alignment(cls: type) -> int:
    return max(
        _size(m.element) if isinstance(m.element, str) else _c_alignment(m.element)
        for m in members(cls)
    )


def _leaves(cls: type, base: int) -> list[tuple[int, int]]:
    """(C offset, size) of every primitive of ``cls`` at C offset ``base``, in encoding order."""
    dtype = c_dtype(cls)
    out = []
    for m in members(cls):
        offset = base + dtype.fields[m.name][1]
        count = m.length or 1
        if isinstance(m.element, str):
            size = _size(m.element)
            out += [(offset + i * size, size) for i in range(count)]
        else:
            stride = c_dtype(m.element).itemsize
            for i in range(count):
                out += _leaves(m.element, offset + i * stride)
    return out


@cache
def cdr_gather(cls: type) -> np.ndarray:
    """(body bytes,) int64: for each byte of the XCDR1 body of ``cls`` (without the 4-byte
    encapsulation header), its index in the C-layout bytes, or -1 for a padding byte."""
    gather: list[int] = []
    for c_offset, size in _leaves(cls, 0):
        pad = (-len(gather)) % min(size, 8)
        gather += [-1] * pad + list(range(c_offset, c_offset + size))
    return np.array(gather, dtype=np.int64)
