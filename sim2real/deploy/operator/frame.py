"""The operator's input seam: one frame type (:class:`OperatorFrame`), one protocol
(:class:`OperatorInput`) every source implements, and the button and axis vocabulary of each
source (:data:`VOCABULARY`), which a mapping file's names are checked against.

The Unitree wireless remote's 40 bytes are laid out in
:mod:`sim2real.deploy.backends.unitree.remote` (its emulator plays scripted ones);
:func:`decode_unitree_remote` makes a frame of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from sim2real.deploy.backends.unitree.remote import AXES, BUTTONS, decode_remote

#: Names of a ROS 2 ``sensor_msgs/Joy`` message's entries: ``button<i>`` and ``axis<i>``.
JOY_MAX = 32
#: Keys the terminal keyboard source reports (one character each, and these names).
KEYBOARD_NAMED = ("space", "enter", "esc", "tab", "backspace")

#: The names a mapping file may use, by source (evdev: every EV_KEY and EV_ABS code name of the
#: kernel's input-event-codes.h, checked by :func:`known_name`).
VOCABULARY: dict[str, tuple[str, ...]] = {
    "unitree": BUTTONS + tuple(AXES),
    "joy": tuple(f"button{i}" for i in range(JOY_MAX)) + tuple(f"axis{i}" for i in range(JOY_MAX)),
    "keyboard": KEYBOARD_NAMED,
    "evdev": (),
}
SOURCES = tuple(VOCABULARY)


def known_name(source: str, name: str) -> bool:
    """Whether ``name`` is a button or axis name of ``source`` (``unitree``, ``joy``, ``evdev``,
    ``keyboard``): the keyboard takes any one printable character too; evdev takes ``BTN_*``,
    ``KEY_*`` and ``ABS_*`` names (the kernel's; checked against python-evdev's table when it is
    installed)."""
    if source == "keyboard":
        return name in KEYBOARD_NAMED or (len(name) == 1 and name.isprintable() and name != " ")
    if source == "evdev":
        if not name.startswith(("BTN_", "KEY_", "ABS_")):
            return False
        try:
            from evdev import ecodes
        except ImportError:
            return True
        return name in ecodes.ecodes
    return name in VOCABULARY.get(source, ())


def expected_names(source: str, kind: str) -> str:
    """What a mapping of ``source`` may name as a ``kind`` (``button``, ``axis`` or ``key``),
    for an error message: ``"an evdev button (BTN_*, KEY_* or ABS_*, ...)"``."""
    if source == "evdev":
        what = "BTN_*, KEY_* or ABS_* names of the kernel's input-event-codes.h"
    elif source == "keyboard":
        what = "one printable character or " + ", ".join(KEYBOARD_NAMED)
    elif source == "joy":
        what = f"{'axis' if kind == 'axis' else 'button'}0..{JOY_MAX - 1}"
    else:  # the Unitree remote
        what = ", ".join(AXES if kind == "axis" else BUTTONS)
    article = "an" if source == "evdev" else "a"
    return f"{article} {source} {kind} ({what})"


@dataclass(frozen=True)
class OperatorFrame:
    """What an operator's device says at one moment.

    Attributes:
        buttons: Names of the buttons held down (the source's vocabulary, :data:`VOCABULARY`).
        axes: Axis name -> position in [-1, 1] (sticks: up and right positive where the device
            says so; a mapping's per-axis scale sets the sign of the command).
        stamp: s, the run's clock when the source last heard from the device (a dead-man rule
            compares it with now).
        presses: Buttons pressed since the previous frame even if released again before it (a
            keyboard's keys, a tap between two polls); a subset of what fires a rising edge.
    """

    buttons: frozenset[str] = frozenset()
    axes: dict[str, float] = field(default_factory=dict)
    stamp: float = -np.inf
    presses: frozenset[str] = frozenset()


class OperatorInput(Protocol):
    """A source of operator frames (the Unitree remote, ``sensor_msgs/Joy``, an evdev gamepad or
    its recorded stream, the terminal keyboard).

    Attributes:
        source: Its vocabulary's name (``unitree``, ``joy``, ``evdev``, ``keyboard``), also the
            name the operator configuration's authority lists give it.
    """

    source: str

    def poll(self, now: float) -> OperatorFrame | None:
        """The newest frame at the run's time ``now`` (s); None while the device said nothing."""
        ...

    def close(self) -> None:
        """Release the device (idempotent)."""
        ...


def decode_unitree_remote(data, stamp: float) -> OperatorFrame:
    """The frame of the remote's 40 bytes ``data``
    (:func:`sim2real.deploy.backends.unitree.remote.decode_remote`), stamped ``stamp`` s.

    Raises:
        ValueError: ``data`` is not 40 bytes.
    """
    buttons, axes = decode_remote(data)
    return OperatorFrame(buttons, axes, stamp)
