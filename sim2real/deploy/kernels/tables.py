"""A kernel's arrays as one declared table: each array named once, read by name in the kernel.

A :class:`Table` declares the arrays (and integer scalars) a kernel reads: each field's name,
dtype and shape symbols (``Table("guard", out="f8[envs,n]", mode="i8")``). From that one
declaration come both sides:

- Python: :meth:`Table.pack` checks each array against its field (dtype, dimensions, C order; a
  shape symbol such as ``envs`` names one length across the table, ``*`` any) and returns a
  :class:`Packed`: the arrays, kept alive by it, and one int64 buffer of their addresses and
  dimensions, laid out from the declaration (no caller writes an index). A packed table pickles
  and copies as its arrays: the copy packs them again at their new addresses.
- The kernel: a :class:`Packed` argument types as :class:`TableType` (its key the declaration's
  layout), unboxed as that one int64 buffer, so a call unboxes one array whatever the table's
  size; ``t.pred`` in a compiled kernel is the array of field ``pred`` (``numba.carray`` at its
  address and dimensions), ``t.mode`` the scalar's value; an undeclared name fails to compile.

The type is numba's documented extension API (``typeof_impl``, ``register_model``, ``unbox``,
``infer_getattr``, ``lower_getattr_generic``); a kernel taking a table keeps ``cache=True``
(numba pickles the type, by its layout, into the cache's index).
"""

from __future__ import annotations

import copy
import importlib
import re
from typing import NamedTuple

import numpy as np
from numba.core import cgutils, types
from numba.core.extending import (
    NativeValue,
    lower_getattr_generic,
    models,
    register_model,
    typeof_impl,
    unbox,
)
from numba.core.typing.templates import AttributeTemplate, infer_getattr
from numba.np.arrayobj import populate_array

from sim2real.robots.errors import Sim2RealError

#: A field's spelling: a dtype code, then the shape symbols in brackets (none: a scalar).
_FIELD = re.compile(r"^(f8|f4|i8|i1|b1)(?:\[([\w*+, ]*)\])?$")


class Field(NamedTuple):
    """One declared field: ``name``, numpy ``dtype`` code, shape ``dims`` (symbols, ints, ``*``;
    empty for a scalar) and ``at``, its first int of the packed buffer."""

    name: str
    dtype: str
    dims: tuple
    at: int


class TableMismatch(Sim2RealError, ValueError):
    """Values that do not fit a :class:`Table`'s declaration (the field and what it expected)."""


class Table:
    """The declaration of one kernel's table: ``where`` (``"<module>:<NAME>"``, where it is
    declared: a pickled :class:`Packed` finds it there), then the fields as keywords, each
    ``"<dtype>[<dims>]"`` (``"f8[envs,n]"``, ``"b1[envs]"``, ``"f8[5]"``; dtypes ``f8``, ``f4``,
    ``i8``, ``i1``, ``b1``; ``envs+``: at least ``envs`` rows, the kernel viewing the first
    ``envs``) or a scalar ``"i8"``, ``"b1"``, ``"f8"`` (its value kept in the buffer: a
    table packed anew takes a new value).

    Raises:
        ValueError: a field's spelling is not of that form.
    """

    def __init__(self, where: str, /, **fields: str):
        self.where, self.fields, self.spellings, at = where, {}, dict(fields), 0
        name = self.name = where.rsplit(":", 1)[-1]
        for key, spelling in fields.items():
            m = _FIELD.match(spelling.replace(" ", ""))
            if m is None:
                raise ValueError(
                    f"table {name}: field {key}={spelling!r}, expected e.g. 'f8[envs,n]'"
                )
            dims = tuple(int(d) if d.isdigit() else d for d in (m[2] or "").split(",") if d)
            self.fields[key] = Field(key, m[1], dims, at)
            at += 1 + len(dims) if dims else 1
        self.size = at
        self.type = TableType(where, tuple((f.name, f.dtype, len(f.dims), f.at) for f in self))

    def extend(self, where: str, /, **fields: str) -> Table:
        """A table of this one's fields and ``fields`` (new names), declared at ``where``."""
        if set(fields) & set(self.fields):
            raise ValueError(
                f"table {where}: {sorted(set(fields) & set(self.fields))} declared twice"
            )
        return Table(where, **self.spellings, **fields)

    def __iter__(self):
        return iter(self.fields.values())

    def __reduce__(self):
        return _declared, (self.where,)

    def mismatch(self, values: dict, sizes: dict | None = None) -> str | None:
        """Why ``values`` (field name -> array or scalar) do not fit the declaration (the first
        field that does not, with what it expected), or None. ``sizes``: the lengths some shape
        symbols must have (e.g. ``{"window": 50}``); the others take the first array's."""
        return self._fit(values, sizes)[0]

    def _fit(self, values: dict, sizes: dict | None) -> tuple[str | None, dict]:
        """:meth:`mismatch`, and each array field's dimensions as the kernel views it."""
        if set(values) != set(self.fields):
            missing, extra = set(self.fields) - set(values), set(values) - set(self.fields)
            return f"table {self.name}: missing {sorted(missing)}, undeclared {sorted(extra)}", {}
        bound, shapes = dict(sizes or {}), {}
        # the fields of exact lengths first: they bind the symbols an "at least" row count reads
        for f in sorted(self, key=lambda f: bool(f.dims) and str(f.dims[0]).endswith("+")):
            a = values[f.name]
            if not f.dims:
                if not isinstance(a, (int, float, bool, np.integer, np.floating, np.bool_)):
                    why = f"{f.name} must be a scalar, got {type(a).__name__}"
                    return f"table {self.name}: {why}", {}
                continue
            if not (isinstance(a, np.ndarray) and a.dtype == np.dtype(f.dtype)):
                got = getattr(a, "dtype", type(a).__name__)
                return f"table {self.name}: {f.name} must be a {f.dtype} array, got {got}", {}
            if a.ndim != len(f.dims) or not a.flags.c_contiguous:
                return f"table {self.name}: {f.name} must be C-contiguous of dims {f.dims}", {}
            shape = list(a.shape)
            for k, (d, length) in enumerate(zip(f.dims, a.shape, strict=True)):
                if isinstance(d, str) and d.endswith("+"):  # at least d rows, viewed as d
                    want = bound.setdefault(d[:-1], length)
                    if length < want:
                        why = f"{f.name} has {length} rows, expected at least {d[:-1]}={want}"
                        return f"table {self.name}: {why}", {}
                    shape[k] = want
                    continue
                want = d if isinstance(d, int) else bound.setdefault(d, length)
                if d != "*" and want != length:
                    return f"table {self.name}: {f.name} has {d}={length}, expected {want}", {}
            shapes[f.name] = tuple(shape)
        return None, shapes

    def pack(self, sizes: dict | None = None, /, **values) -> Packed:
        """The :class:`Packed` table of ``values`` (each declared field, by name).

        Raises:
            TableMismatch: a field missing, undeclared or not fitting its declaration (the
                first one, with what it expected: :meth:`mismatch`). A caller with another
                path for values that do not fit asks :meth:`pack_or_none`."""
        packed = self.pack_or_none(sizes, **values)
        if packed is None:
            raise TableMismatch(self.mismatch(values, sizes))
        return packed

    def pack_or_none(self, sizes: dict | None = None, /, **values) -> Packed | None:
        """:meth:`pack`, or None if a field does not fit (:meth:`mismatch`, with ``sizes``): for
        a caller that then takes another path (numba's dispatch, numpy), and says so."""
        why, shapes = self._fit(values, sizes)
        if why is not None:
            return None
        return Packed(self, values, sizes, shapes)

    def placeholders(self, names, sizes: dict) -> dict:
        """Zero arrays of fields ``names`` (by their declaration, the symbols' lengths in
        ``sizes``, ``*`` and an unknown symbol 1): the fields a kernel does not read in a
        configuration (a flag in the table says so), packed all the same."""
        out = {}
        for name in names:
            f = self.fields[name]
            dims = [d if isinstance(d, int) else sizes.get(str(d).rstrip("+"), 1) for d in f.dims]
            out[name] = np.zeros(dims, dtype=np.dtype(f.dtype))
        return out

    def empty(self) -> Packed:
        """A packed table of null addresses, for compiling a kernel (not calling it)."""
        packed = np.zeros(self.size, dtype=np.int64).view(Packed)
        packed.table, packed.arrays, packed.sizes = self, {}, None
        return packed


def _declared(where: str) -> Table:
    """The :class:`Table` declared at ``where`` (``"<module>:<NAME>"``)."""
    module, name = where.split(":")
    return getattr(importlib.import_module(module), name)


class Packed(np.ndarray):
    """A :class:`Table`'s int64 buffer of addresses, dimensions and scalars (:meth:`Table.pack`),
    holding the arrays it names (alive as long as it is): ``packed.table`` the declaration,
    ``packed.arrays`` the values by field name. Itself the one array a kernel's call unboxes
    (an ndarray: unboxed as fast as a plain int64 array, no attribute looked up)."""

    def __new__(cls, table: Table, values: dict, sizes: dict | None, shapes: dict):
        self = np.zeros(table.size, dtype=np.int64).view(cls)
        self.table, self.arrays, self.sizes = table, dict(values), sizes
        for f in table:
            a = values[f.name]
            if f.dims:
                self[f.at] = a.ctypes.data
                self[f.at + 1 : f.at + 1 + a.ndim] = shapes[f.name]
            elif f.dtype == "f8":
                self[f.at] = np.float64(a).view(np.int64)  # its bits
            else:
                self[f.at] = int(a)
        return self

    def __reduce__(self):
        return _repack, (self.table, self.sizes, self.arrays)

    def __reduce_ex__(self, protocol):
        return self.__reduce__()

    def __deepcopy__(self, memo):
        return _repack(self.table, self.sizes, copy.deepcopy(self.arrays, memo))

    def __copy__(self):
        return _repack(self.table, self.sizes, self.arrays)


def _repack(table: Table, sizes: dict | None, arrays: dict) -> Packed:
    """:meth:`Table.pack` of a copy's arrays (at their own addresses); an :meth:`Table.empty`
    table's copy is empty."""
    if not arrays:
        return table.empty()
    return table.pack(sizes, **arrays)


class TableType(types.Type):
    """The numba type of a :class:`Packed` table: its declaration's name and layout (each
    field's name, dtype, dimensions and place)."""

    def __init__(self, name: str, layout: tuple):
        self.layout = layout
        super().__init__(name=f"Table({name})")

    @property
    def key(self):
        return self.name, self.layout

    def field(self, name: str):
        for f in self.layout:
            if f[0] == name:
                return f
        return None


_BUFFER = types.Array(types.int64, 1, "C")


@register_model(TableType)
class _TableModel(models.StructModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, [("addresses", _BUFFER)])


@typeof_impl.register(Packed)
def _typeof_packed(val, c):
    return val.table.type


@unbox(TableType)
def _unbox_packed(typ, obj, c):
    native = c.unbox(_BUFFER, obj)
    table = cgutils.create_struct_proxy(typ)(c.context, c.builder)
    table.addresses = native.value
    return NativeValue(table._getvalue(), is_error=native.is_error)


def _dtype(code: str):
    return {
        "f8": types.float64, "f4": types.float32, "i8": types.int64, "i1": types.int8,
        "b1": types.boolean,
    }[code]  # fmt: skip


@infer_getattr
class _TableAttributes(AttributeTemplate):
    key = TableType

    def generic_resolve(self, typ, attr):
        f = typ.field(attr)
        if f is None:
            return None
        _, code, ndim, _ = f
        if ndim == 0:
            return {"b1": types.boolean, "f8": types.float64}.get(code, types.int64)
        return types.Array(_dtype(code), ndim, "C")


@lower_getattr_generic(TableType)
def _lower_field(context, builder, typ, value, attr):
    """Field ``attr`` of the table: its scalar, or its array (C order, no owner) at the address
    and dimensions the buffer holds from the field's place on."""
    _, code, ndim, at = typ.field(attr)
    buffer = cgutils.create_struct_proxy(typ)(context, builder, value=value).addresses
    ints = context.make_array(_BUFFER)(context, builder, value=buffer).data
    word = [builder.load(cgutils.gep(builder, ints, at + i)) for i in range(ndim + 1)]
    if ndim == 0:
        if code == "b1":
            return builder.icmp_signed("!=", word[0], word[0].type(0))
        if code == "f8":
            return builder.bitcast(word[0], context.get_value_type(types.float64))
        return word[0]
    aryty = types.Array(_dtype(code), ndim, "C")
    array = context.make_array(aryty)(context, builder)
    itemsize = context.get_abi_sizeof(context.get_data_type(aryty.dtype))
    shape, strides, stride = word[1:], [], word[0].type(itemsize)
    for d in reversed(shape):
        strides.insert(0, stride)
        stride = builder.mul(stride, d)
    data = builder.inttoptr(word[0], context.get_data_type(aryty.dtype).as_pointer())
    size = word[0].type(itemsize)
    populate_array(array, data=data, shape=shape, strides=strides, itemsize=size, meminfo=None)
    return array._getvalue()
