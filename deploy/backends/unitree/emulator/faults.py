"""Faults the Unitree emulator injects on request, and their command-line spelling.

Times are s after the emulator's first LowCmd (the controller's start: its bring-up comes first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class EmulatorFaults:
    """What goes wrong between the emulated robot and its controller. Change the fields at any
    time (the emulator reads them every physics step).

    Attributes:
        lose: Probability that a LowState is never published (per state).
        bursts: ``(start, duration)`` windows (s) without any LowState; ``duration`` inf: the
            LowState stops for good.
        delays: ``(start, duration, delay)`` windows (s) in which each LowState is published
            ``delay`` s late (the ones due meanwhile keep their order).
        corrupt_state: Probability that a published LowState's CRC is wrong.
        corrupt_command: Probability that a received LowCmd arrives with one byte altered (its
            CRC fails: the robot drops it and counts it).
        silent: Motor slot -> time (s) from which that motor answers nothing more: its
            ``lost`` count grows every cycle, its reading freezes, its torque is off.
        heat: Motor slot -> ``(watts, time)``: from ``time`` that motor's winding takes ``watts``
            of extra loss while it is enabled (a binding gearbox, a shorted turn): the modelled
            winding climbs toward the runtime's thermal stop and then the driver's cut-off.
    """

    lose: float = 0.0
    bursts: list[tuple[float, float]] = field(default_factory=list)
    delays: list[tuple[float, float, float]] = field(default_factory=list)
    corrupt_state: float = 0.0
    corrupt_command: float = 0.0
    silent: dict[int, float] = field(default_factory=dict)
    heat: dict[int, tuple[float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in ("lose", "corrupt_state", "corrupt_command"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name}: a probability in [0, 1] is expected, got {p}")

    def in_burst(self, t: float) -> bool:
        """Whether ``t`` (s) falls in a burst without LowState."""
        return any(start <= t < start + length for start, length in self.bursts)

    def delay(self, t: float) -> float:
        """The LowState delay at ``t`` (s; 0 outside every window)."""
        return max((d for s, n, d in self.delays if s <= t < s + n), default=0.0)


FAULT_HELP = (
    "lose:P (lose a fraction P of LowState), burst:T[:D] (no LowState from T s for D s; no D: "
    "it stops for good), delay:MS@T[:D] (LowState MS ms late from T s for D s), "
    "corrupt-state:P (a fraction P of LowState with a wrong CRC), corrupt-command:P (a fraction "
    "P of LowCmd altered on the way: the robot drops them), silent:SLOT@T (motor SLOT stops "
    "answering from T s), heat:SLOT=W[@T] (W watts of extra winding loss in motor SLOT from T "
    "s); times after the first LowCmd"
)


def _window(text: str) -> tuple[float, float]:
    start, _, length = text.partition(":")
    return float(start), float(length) if length else math.inf


def parse_fault(text: str, faults: EmulatorFaults) -> None:
    """Add one ``--fault`` argument (``FAULT_HELP``) to ``faults``.

    Raises:
        ValueError: the text names no known fault or its values do not parse.
    """
    kind, _, value = text.partition(":")
    try:
        if kind in ("lose", "corrupt-state", "corrupt-command"):
            setattr(faults, kind.replace("-", "_"), float(value))
            faults.__post_init__()
        elif kind == "burst":
            faults.bursts.append(_window(value))
        elif kind == "delay":
            ms, _, window = value.partition("@")
            start, length = _window(window or "0")
            faults.delays.append((start, length, float(ms) / 1000.0))
        elif kind == "silent":
            slot, _, at = value.partition("@")
            faults.silent[int(slot)] = float(at or 0.0)
        elif kind == "heat":
            slot, _, rest = value.partition("=")
            watts, _, at = rest.partition("@")
            if float(watts) < 0:
                raise ValueError(f"heat: watts must be >= 0, got {watts}")
            faults.heat[int(slot)] = (float(watts), float(at or 0.0))
        else:
            raise ValueError(f"unknown fault kind '{kind}'")
    except ValueError as err:
        raise ValueError(f"--fault {text!r}: {err}; expected one of: {FAULT_HELP}") from None
