"""What the emulators' fault sets share: their probabilities' check and the ``--fault`` spelling.

A fault set (:class:`sim2real.deploy.backends.emulator.faults.WireFaults`,
:class:`sim2real.deploy.backends.unitree.emulator.faults.EmulatorFaults`) is a dataclass deriving from
:class:`Probabilities`, which checks its probability fields. Its ``parse_fault`` reads one
``--fault KIND:VALUE`` text through :func:`parse_fault_text` and a table of kinds; the value
forms two emulators share are read by :func:`probability`, :func:`timed` and :func:`heat`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar

#: One kind of ``--fault``: reads its value text into the fault set (ValueError when it can't).
Kind = Callable[[Any, str], None]


class Probabilities:
    """A dataclass mixin: its fields named in ``PROBABILITIES`` must lie in [0, 1].

    Raises:
        ValueError: (on construction, or :meth:`check`) a probability outside [0, 1].
    """

    PROBABILITIES: ClassVar[tuple[str, ...]] = ()

    def __post_init__(self) -> None:
        self.check()

    def check(self) -> None:
        """Raise ValueError unless every probability field lies in [0, 1]."""
        for name in self.PROBABILITIES:
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name}: a probability in [0, 1] is expected, got {p}")


def parse_fault_text(text: str, faults: Any, kinds: Mapping[str, Kind], spelling: str) -> None:
    """Read one ``--fault`` text ``KIND:VALUE`` into ``faults`` by ``kinds[KIND]``.

    Raises:
        ValueError: an unknown kind or a value its kind refuses, the text and ``spelling`` (the
            faults' help) in the message.
    """
    kind, _, value = text.partition(":")
    try:
        if kind not in kinds:
            raise ValueError(f"unknown fault kind '{kind}'")
        kinds[kind](faults, value)
    except ValueError as err:
        raise ValueError(f"--fault {text!r}: {err}; expected one of: {spelling}") from None


def probability(field: str) -> Kind:
    """The kind ``P``: sets the fault set's ``field`` to the probability P (checked)."""

    def read(faults: Probabilities, value: str) -> None:
        setattr(faults, field, float(value))
        faults.check()

    return read


def timed(field: str) -> Kind:
    """The kind ``ID[@T]``: the fault set's dict ``field`` maps servo or motor ID to T (s,
    default 0)."""

    def read(faults: Any, value: str) -> None:
        key, _, at = value.partition("@")
        getattr(faults, field)[int(key)] = float(at or 0.0)

    return read


def heat(faults: Any, value: str) -> None:
    """The kind ``heat:ID=W[@T]``: ``faults.heat`` maps ID to (W watts >= 0, T s, default 0)."""
    key, _, rest = value.partition("=")
    watts, _, at = rest.partition("@")
    if float(watts) < 0:
        raise ValueError(f"heat: watts must be >= 0, got {watts}")
    faults.heat[int(key)] = (float(watts), float(at or 0.0))
