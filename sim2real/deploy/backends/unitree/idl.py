"""Unitree's IDL structs built from member tables: one definition for every message family.

Unitree's IDL packages (``unitree_go``, ``unitree_hg``, ``unitree_api``) declare plain structs:
``@final`` (XCDR1, plain CDR), members numbered in order, every member zero by default. A
:class:`Package` turns a table of ``(name, type)`` pairs into such a struct, a Cyclone DDS
:class:`~cyclonedds.idl.IdlStruct` dataclass typed ``<package>.msg.dds_.<Name>`` (the type name
Unitree's tools and robots match), the same class the hand-written ``@dataclass @final
@autoid("sequential") class X(IdlStruct, typename=...)`` declaration gives.

The member runs the two low-level families share (a motor's command and state, the IMU) are
tables here; each family module adds its own members around them.
"""

# no ``from __future__ import annotations``: Cyclone DDS reads the member types at run time
import types as pytypes
import typing
from collections.abc import Iterable
from dataclasses import dataclass, field

import cyclonedds.idl.types as types
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import autoid, final

#: One member: its name and its Cyclone DDS type (a primitive, ``types.array[...]``,
#: ``types.sequence[...]``, ``bool``, ``str`` or an IdlStruct class).
Members = Iterable[tuple[str, typing.Any]]

#: What a low-level motor command and a motor state both start with: ``mode``, rad, rad/s.
_MOTOR = (("mode", types.uint8), ("q", types.float32), ("dq", types.float32))
#: What every low-level motor command starts with: ``mode``, the PD targets and gains
#: (``tau = tau + kp (q - q_m) + kd (dq - dq_m)`` on the motor's driver; rad, rad/s, N m).
MOTOR_CMD: tuple = (*_MOTOR, ("tau", types.float32), ("kp", types.float32), ("kd", types.float32))
#: What every low-level motor state starts with: rad, rad/s, rad/s^2, N m.
MOTOR_STATE: tuple = (*_MOTOR, ("ddq", types.float32), ("tau_est", types.float32))
#: An IMU state's vectors: (w, x, y, z), rad/s, m/s^2, rad (its temperature's type differs).
IMU: tuple = (
    ("quaternion", types.array[types.float32, 4]),
    ("gyroscope", types.array[types.float32, 3]),
    ("accelerometer", types.array[types.float32, 3]),
    ("rpy", types.array[types.float32, 3]),
)
IMU_DOC = "``quaternion`` (w, x, y, z), ``gyroscope`` rad/s, ``accelerometer`` m/s^2, ``rpy`` rad."


class Package:
    """The structs of one IDL package (e.g. ``unitree_go``), defined in Python module ``module``.

    Args:
        package: The IDL package; a struct ``Name`` is typed ``<package>.msg.dds_.Name``.
        module: The defining module's ``__name__`` (the classes' ``__module__``).
    """

    def __init__(self, package: str, module: str):
        self.package = package
        self.module = module

    def struct(self, name: str, members: Members, doc: str | None = None) -> type:
        """The ``@final``, sequentially numbered IdlStruct dataclass ``name`` with ``members`` in
        order, each defaulting to zero (numbers 0, arrays of zeros or of default structs, a
        nested struct its default, a sequence empty, a string ``""``, a bool False).

        Raises:
            TypeError: a member type with no zero here.
        """
        members = list(members)

        def body(ns: dict) -> None:
            ns["__module__"] = self.module
            ns["__qualname__"] = name
            ns["__doc__"] = doc
            for member, hint in members:
                ns["__annotations__"][member] = hint
                ns[member] = _zero(name, member, hint)

        typename = f"{self.package}.msg.dds_.{name}"
        cls = pytypes.new_class(name, (IdlStruct,), {"typename": typename}, body)
        return dataclass(final(autoid("sequential")(cls)))


def _zero(struct: str, member: str, hint):
    """The zero default of a member typed ``hint`` (a value or a dataclass field)."""
    if isinstance(hint, type) and issubclass(hint, IdlStruct):
        return field(default_factory=hint)
    if hint is bool:
        return False
    if hint is str:
        return ""
    if typing.get_origin(hint) is typing.Annotated:
        tag = typing.get_args(hint)[1]
        if isinstance(tag, types.array):
            n, sub = tag.length, tag.subtype
            if isinstance(sub, type) and issubclass(sub, IdlStruct):
                return field(default_factory=lambda: [sub() for _ in range(n)])
            return field(default_factory=lambda: [0] * n)
        if isinstance(tag, types.sequence):
            return field(default_factory=list)
        if tag in ("float32", "float64"):
            return 0.0
        if isinstance(tag, str):
            return 0
    raise TypeError(f"{struct}.{member}: no zero default for member type {hint}")
