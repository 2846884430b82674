"""Explicit delegation from an owner to one of its stages: data by :func:`delegate`, methods by
:func:`forward`.

An owner composed of stage objects (the simulated plant of its drives, sensors and
disturbances; the runtime of its state machine) keeps the names its callers use as class
attributes that name the stage and the stage's member: ``noise_sigma =
delegate("joint_sensors", "noise_sigma")`` for data (an array, a setting: a property that
reads it, and writes it when ``writable``), ``push_base = forward("disturbances",
"push_base")`` for a method (a method of the owner that calls the stage's). The stage is looked
up on each access, so an owner that replaces a stage (a copy, a new model) is followed. A
delegate of a method is refused where it is read (a bound method is behaviour, not data: forward
it, so that the owner's class says it is a method).
"""

from __future__ import annotations

import types


def delegate(stage: str, name: str, writable: bool = False) -> property:
    """A property of the owner that is ``getattr(owner.<stage>, name)`` (module docstring);
    ``writable``: assigning it sets the stage's attribute.

    Raises (on access):
        TypeError: the stage's member is a method (forward it with :func:`forward`).
        AttributeError: the stage has no such member.
    """

    def get(owner):
        value = getattr(getattr(owner, stage), name)
        if isinstance(value, types.MethodType):
            raise TypeError(
                f"{type(owner).__name__}: delegate('{stage}', '{name}') names a method; "
                "a delegate forwards data: use forward() for a method"
            )
        return value

    def put(owner, value) -> None:
        setattr(getattr(owner, stage), name, value)

    doc = f"The ``{name}`` of the owner's ``{stage}`` (a delegate: see that stage)."
    return property(get, put if writable else None, doc=doc)


def forward(stage: str, name: str):
    """A method of the owner that calls ``owner.<stage>.<name>(*args, **kwargs)`` and returns
    what it returns (module docstring). Raises what the stage's method raises (AttributeError
    for a missing member)."""

    def method(owner, *args, **kwargs):
        return getattr(getattr(owner, stage), name)(*args, **kwargs)

    method.__name__ = name
    method.__doc__ = f"The owner's ``{stage}.{name}`` (forwarded: see that stage's method)."
    return method
