"""Faults the Unitree emulator injects on request, and their command-line spelling.

Times are s after the emulator's first LowCmd (the controller's start: its bring-up comes first).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sim2real.deploy.backends.fault_text import (
    Probabilities,
    heat,
    parse_fault_text,
    probability,
    timed,
)


@dataclass
class EmulatorFaults(Probabilities):
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

    PROBABILITIES = ("lose", "corrupt_state", "corrupt_command")

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


def _delay(faults: EmulatorFaults, value: str) -> None:
    ms, _, window = value.partition("@")
    start, length = _window(window or "0")
    faults.delays.append((start, length, float(ms) / 1000.0))


#: ``--fault`` kind -> how its value is read (``FAULT_HELP``).
KINDS = {
    "lose": probability("lose"),
    "corrupt-state": probability("corrupt_state"),
    "corrupt-command": probability("corrupt_command"),
    "burst": lambda faults, value: faults.bursts.append(_window(value)),
    "delay": _delay,
    "silent": timed("silent"),
    "heat": heat,
}


def parse_fault(text: str, faults: EmulatorFaults) -> None:
    """Add one ``--fault`` argument (``FAULT_HELP``) to ``faults``.

    Raises:
        ValueError: the text names no known fault or its values do not parse.
    """
    parse_fault_text(text, faults, KINDS, FAULT_HELP)
