"""A kernel's declared table (:mod:`sim2real.deploy.kernels.tables`): the packer refuses what the
declaration does not describe, the kernel reads each array by its name, a copy packs its own."""

from __future__ import annotations

import copy
import pickle
import re

import numba
import numpy as np
import pytest
from numba.core.errors import TypingError

from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.kernels.tables import Packed, Table, TableMismatch

#: A table of this module (its place, for unpickling).
DEMO = Table(
    "tests.test_kernel_tables:DEMO", mode="i8", on="b1", dt="f8", q="f8[envs,n]", total="f8[envs]",
    hit="b1[envs]", rows="i8[2,envs]",
)  # fmt: skip


@numba.njit(nogil=True, _nrt=False)
def _kernel(t, x):
    for e in range(t.q.shape[0]):
        s = 0.0
        for j in range(t.q.shape[1]):
            s += t.q[e, j]
        t.total[e] = s * x + t.mode + t.dt
        t.hit[e] = t.on
        t.rows[1, e] = e
    return t.q.shape[1]


@numba.njit(nogil=True)
def _undeclared(t):
    return t.missing[0]


def _values(envs=3, n=2):
    return {
        "mode": 2, "on": True, "dt": 0.25, "q": np.arange(envs * n, dtype=float).reshape(envs, n),
        "total": np.zeros(envs), "hit": np.zeros(envs, dtype=bool),
        "rows": np.zeros((2, envs), dtype=np.int64),
    }  # fmt: skip


def test_a_kernel_reads_and_writes_the_packed_arrays_by_name():
    values = _values()
    table = DEMO.pack(**values)
    assert bind(_kernel, table, rest=(1.0,))(10.0) == 2
    np.testing.assert_array_equal(values["total"], [12.25, 52.25, 92.25])
    assert values["hit"].all() and values["rows"][1].tolist() == [0, 1, 2]


@pytest.mark.parametrize(
    "name, value, said",
    [
        ("total", np.zeros(4), "envs=4, expected 3"),  # a shape symbol names one length
        ("hit", np.zeros(3), "must be a b1 array"),
        ("q", np.zeros((2, 3)).T, "C-contiguous"),
        ("rows", np.zeros((3, 3), dtype=np.int64), "has 2=3"),
    ],
)
def test_the_packer_refuses_an_array_its_declaration_does_not_describe(name, value, said):
    values = _values() | {name: value}
    assert said in DEMO.mismatch(values)
    with pytest.raises(TableMismatch, match=re.escape(said)):
        DEMO.pack(**values)
    assert DEMO.pack_or_none(**values) is None  # a caller with another path asks for None


def test_the_packer_refuses_a_shape_other_than_the_sizes_it_is_given():
    assert "envs=3, expected 4" in DEMO.mismatch(_values(), {"envs": 4})
    assert DEMO.pack({"envs": 3}, **_values()) is not None


def test_the_packer_refuses_a_missing_or_undeclared_name():
    values = _values()
    del values["q"]
    assert "missing ['q']" in DEMO.mismatch(values | {"p": 1})
    assert "undeclared ['p']" in DEMO.mismatch(values | {"p": 1})


def test_a_kernel_reading_an_undeclared_name_does_not_compile():
    with pytest.raises(TypingError):
        _undeclared(DEMO.pack(**_values()))


@pytest.mark.parametrize("clone", [pickle.loads, copy.deepcopy])
def test_a_copy_of_a_bound_table_binds_its_own_arrays(clone):
    values = _values()
    call = bind(_kernel, DEMO.pack(**values), rest=(1.0,))
    again = clone(pickle.dumps(call)) if clone is pickle.loads else clone(call)
    table = again.args[0]
    assert isinstance(table, Packed) and table.arrays["total"] is not values["total"]
    again(1.0)
    np.testing.assert_array_equal(table.arrays["total"], [3.25, 7.25, 11.25])
    np.testing.assert_array_equal(values["total"], 0.0)  # the original's arrays untouched


AT_LEAST = Table("tests.test_kernel_tables:AT_LEAST", q="f8[envs,2]", rows="f8[envs+,3]")


@numba.njit(nogil=True)
def _rows(t):
    return t.rows.shape[0]


def test_a_field_of_at_least_envs_rows_is_viewed_as_envs_rows():
    q = np.zeros((2, 2))
    assert _rows(AT_LEAST.pack(q=q, rows=np.zeros((5, 3)))) == 2
    assert "at least envs=2" in AT_LEAST.mismatch({"q": q, "rows": np.zeros((1, 3))})


def test_placeholders_are_zeros_of_the_declared_dtypes_and_sizes():
    zeros = DEMO.placeholders(["q", "hit", "rows"], {"envs": 4})
    assert zeros["q"].shape == (4, 1) and zeros["q"].dtype == np.float64  # n unknown: 1
    assert zeros["hit"].dtype == np.bool_ and zeros["rows"].shape == (2, 4)


def test_a_copy_of_an_empty_table_is_empty():
    copied = copy.deepcopy(DEMO.empty())
    assert isinstance(copied, Packed) and copied.table is DEMO and not copied.any()
