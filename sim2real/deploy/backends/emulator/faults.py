"""Wire faults the emulator injects on request, and their command-line spelling."""

from __future__ import annotations

from dataclasses import dataclass, field

from sim2real.deploy.backends.fault_text import (
    Probabilities,
    heat,
    parse_fault_text,
    probability,
    timed,
)


@dataclass
class WireFaults(Probabilities):
    """What goes wrong on the emulated bus. Change the fields at any time (the bus reads them
    for every reply).

    Attributes:
        drop: Probability that a servo's reply is never sent (per status packet).
        corrupt: Probability that a reply's checksum (Feetech) or CRC (Dynamixel) is corrupted
            (per status packet; the bytes arrive, the host must reject them).
        unplug: Servo ID -> time (s since the emulator started) after which that servo answers
            nothing more, and its torque is off (its power and signal are gone).
        overload: Servo ID -> time (s) from which that servo reports an overload (error bit 5 on
            both vendors); it cuts its torque as its model does on overload.
        temperature_limit: Servo ID -> degC written to its temperature-limit register at start
            (so the winding model reaches it sooner: the over-temperature shutdown).
        heat: Servo ID -> ``(watts, time)``: from ``time`` (s since start) that servo's winding
            takes ``watts`` of extra loss on top of its copper loss while its torque is on (a
            binding gearbox, a shorted winding turn): the modelled winding climbs toward both
            thermal limits, the runtime's and the servo's own.
    """

    drop: float = 0.0
    corrupt: float = 0.0
    unplug: dict[int, float] = field(default_factory=dict)
    overload: dict[int, float] = field(default_factory=dict)
    temperature_limit: dict[int, int] = field(default_factory=dict)
    heat: dict[int, tuple[float, float]] = field(default_factory=dict)

    PROBABILITIES = ("drop", "corrupt")


FAULT_HELP = (
    "drop:P (drop a fraction P of replies), corrupt:P (corrupt the checksum/CRC of a fraction P), "
    "unplug:ID@T (servo ID stops answering T s after start), overload:ID[@T] (overload error "
    "bit from T s, default 0), temperature-limit:ID=DEGC (lower the servo's temperature limit "
    "register; the servo shuts down when its modelled winding passes it), heat:ID=W[@T] (W watts "
    "of extra winding loss in servo ID from T s, default 0)"
)


def _temperature_limit(faults: WireFaults, value: str) -> None:
    servo, _, degc = value.partition("=")
    faults.temperature_limit[int(servo)] = int(degc)


#: ``--fault`` kind -> how its value is read (``FAULT_HELP``).
KINDS = {
    "drop": probability("drop"),
    "corrupt": probability("corrupt"),
    "unplug": timed("unplug"),
    "overload": timed("overload"),
    "heat": heat,
    "temperature-limit": _temperature_limit,
}


def parse_fault(text: str, faults: WireFaults) -> None:
    """Add one ``--fault`` argument (``FAULT_HELP``) to ``faults``.

    Raises:
        ValueError: the text names no known fault or its values do not parse.
    """
    parse_fault_text(text, faults, KINDS, FAULT_HELP)
