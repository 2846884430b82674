"""Explicit delegation from an owner to one of its stages (:func:`delegate`).

An owner composed of stage objects (the simulated plant of its drives, sensors and
disturbances; the runtime of its state machine) keeps the names its callers use as class
attributes that name the stage and the stage's member: ``noise_sigma =
delegate("joint_sensors", "noise_sigma")``. Reading the owner's attribute reads the stage's at
that moment (an array, a method bound to the stage); writing it writes the stage's (a
``writable`` delegate only). The stage is looked up on each access, so an owner that replaces a
stage (a copy, a new model) is followed.
"""

from __future__ import annotations


def delegate(stage: str, name: str, writable: bool = False) -> property:
    """A property of the owner that is ``getattr(owner.<stage>, name)`` (module docstring);
    ``writable``: assigning it sets the stage's attribute. Raises nothing here; an access
    raises what the stage's does (AttributeError for a missing member)."""

    def get(owner):
        return getattr(getattr(owner, stage), name)

    def put(owner, value) -> None:
        setattr(getattr(owner, stage), name, value)

    doc = f"The ``{name}`` of the owner's ``{stage}`` (a delegate: see that stage)."
    return property(get, put if writable else None, doc=doc)
