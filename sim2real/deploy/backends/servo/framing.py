"""What the two serial-bus protocols share: a decoded packet and the splitting of a byte stream
into packets after a header, resynchronising after noise.

:mod:`sim2real.deploy.backends.servo.feetech_protocol` and
:mod:`sim2real.deploy.backends.servo.dynamixel_protocol` each derive a :class:`PacketParser` that says where
its packets end (:meth:`PacketParser.frame`) and how one decodes (:meth:`PacketParser.decode`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar


@dataclass(frozen=True)
class Packet:
    """A decoded packet.

    Attributes:
        servo_id: Packet ID (0xFE: broadcast).
        code: The instruction byte (Feetech: the error byte of a status packet; Dynamixel: 0x55
            for a status packet).
        params: The parameters (Dynamixel: unstuffed; a status packet's start with its error
            byte).
        valid: False when the checksum / CRC did not match (a servo ignores such a packet).
    """

    servo_id: int
    code: int
    params: bytes
    valid: bool = True


class PacketParser:
    """Splits a byte stream into packets, resynchronising on the header after noise.

    ``feed(data)`` returns the packets completed by ``data``; incomplete bytes wait for more.
    Bytes before a header are dropped; a packet whose checksum or CRC fails is returned with
    ``valid=False``. A protocol sets ``HEADER`` and defines :meth:`frame` and :meth:`decode`.
    """

    HEADER: ClassVar[bytes] = b""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[Packet]:
        """Append ``data`` and return the packets completed (possibly none)."""
        buf = self._buf
        buf += data
        out: list[Packet] = []
        while True:
            start = buf.find(self.HEADER)
            if start < 0:
                del buf[: max(0, len(buf) - (len(self.HEADER) - 1))]  # a partial header stays
                return out
            del buf[:start]
            end = self.frame(buf)
            if end is None:
                return out
            if end == 0:  # a header that starts no packet: slide by one
                del buf[0]
                continue
            packet = bytes(buf[:end])
            del buf[:end]
            out.append(self.decode(packet))

    def frame(self, buf: bytearray) -> int | None:
        """The length of the packet ``buf`` starts with (it starts with ``HEADER``), 0 when the
        header starts no packet, None when more bytes are needed to tell."""
        raise NotImplementedError

    def decode(self, packet: bytes) -> Packet:
        """The packet of the bytes :meth:`frame` delimited."""
        raise NotImplementedError
