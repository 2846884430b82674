"""The Feetech SCS/STS serial-bus protocol: packet framing and checksum.

As ``feetech-servo-sdk`` (``scservo_sdk``, ``protocol_packet_handler.py``) speaks it, and as
Dynamixel Protocol 1.0 does (the same layout)::

    instruction: 0xFF 0xFF  ID  LENGTH  INSTRUCTION  PARAM_1 ... PARAM_N  CHECKSUM
    status:      0xFF 0xFF  ID  LENGTH  ERROR        PARAM_1 ... PARAM_N  CHECKSUM

LENGTH = N + 2; CHECKSUM = ~(ID + LENGTH + INSTRUCTION/ERROR + PARAMs) & 0xFF. ID 0xFE (254) is the
broadcast ID: no servo answers it except in SYNC READ, where every listed servo answers in turn
with its own status packet. Multi-byte values are little endian on STS servos.

Instructions (parameters): PING (none); READ (address, length); WRITE (address, data...);
SYNC READ 0x82 (address, length, id...); SYNC WRITE 0x83 (address, length, then per servo: id,
data...). A status packet's parameters are the data read (READ, SYNC READ) or none.
"""

from __future__ import annotations

from dataclasses import dataclass

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
PING, READ, WRITE, REG_WRITE, ACTION = 0x01, 0x02, 0x03, 0x04, 0x05
SYNC_READ, SYNC_WRITE = 0x82, 0x83
#: Largest packet the SDK sends or accepts (``TXPACKET_MAX_LEN``), bytes.
MAX_PACKET = 250


def checksum(body: bytes) -> int:
    """Checksum of ``body`` = ID .. last parameter: ``~sum & 0xFF``."""
    return ~sum(body) & 0xFF


def encode_instruction(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction packet (bytes on the wire).

    Raises:
        ValueError: ID out of 0..254 or the packet longer than ``MAX_PACKET``.
    """
    return _encode(servo_id, instruction, params)


def encode_status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet: ``error`` is the servo's error byte (bits: ``ServoModel.error_bits``).

    Raises:
        ValueError: ID out of 0..254 or the packet longer than ``MAX_PACKET``.
    """
    return _encode(servo_id, error, params)


def _encode(servo_id: int, code: int, params: bytes) -> bytes:
    if not 0 <= servo_id <= BROADCAST_ID:
        raise ValueError(f"servo ID {servo_id} out of 0..254")
    body = bytes((servo_id, len(params) + 2, code)) + bytes(params)
    if len(body) + 3 > MAX_PACKET:
        raise ValueError(f"packet of {len(body) + 3} bytes exceeds {MAX_PACKET}")
    return HEADER + body + bytes((checksum(body),))


@dataclass(frozen=True)
class Packet:
    """A decoded packet.

    Attributes:
        servo_id: Packet ID (0xFE: broadcast).
        code: The instruction (instruction packet) or the error byte (status packet).
        params: The parameters.
        valid: False when the checksum did not match (a servo ignores such a packet).
    """

    servo_id: int
    code: int
    params: bytes
    valid: bool = True


class PacketParser:
    """Splits a byte stream into packets, resynchronising on the header after noise.

    ``feed(data)`` returns the packets completed by ``data``; incomplete bytes wait for more.
    Bytes before a header are dropped; a packet whose checksum fails is returned with
    ``valid=False``.
    """

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[Packet]:
        """Append ``data`` and return the packets completed (possibly none)."""
        buf = self._buf
        buf += data
        out: list[Packet] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                del buf[: max(0, len(buf) - 1)]  # keep a trailing 0xFF
                return out
            del buf[:start]
            if len(buf) < 4:
                return out
            servo_id, length = buf[2], buf[3]
            if servo_id == 0xFF or length < 2:  # 0xFF 0xFF 0xFF ... or nonsense: slide by one
                del buf[0]
                continue
            end = 4 + length
            if len(buf) < end:
                return out
            body = bytes(buf[2 : end - 1])
            out.append(Packet(servo_id, body[2], body[3:], valid=checksum(body) == buf[end - 1]))
            del buf[:end]
