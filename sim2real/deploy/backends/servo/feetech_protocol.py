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
data...). A status packet's parameters are the data read (READ, SYNC READ) or none. Decoded as a
:class:`sim2real.deploy.backends.servo.framing.Packet`.
"""

from __future__ import annotations

from sim2real.deploy.backends.servo import framing
from sim2real.deploy.backends.servo.framing import Packet

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


class PacketParser(framing.PacketParser):
    """Splits a byte stream into Feetech packets (:class:`sim2real.deploy.backends.servo.framing.
    PacketParser`); a packet's ``code`` is its instruction, or a status packet's error byte."""

    HEADER = HEADER

    def frame(self, buf: bytearray) -> int | None:
        """``4 + LENGTH`` bytes (module docstring); 0 for ID 0xFF or LENGTH < 2."""
        if len(buf) < 4:
            return None
        servo_id, length = buf[2], buf[3]
        if servo_id == 0xFF or length < 2:  # 0xFF 0xFF 0xFF ... or nonsense
            return 0
        return 4 + length if len(buf) >= 4 + length else None

    def decode(self, packet: bytes) -> Packet:
        """The packet, ``valid`` when its checksum matches."""
        body = packet[2:-1]
        return Packet(body[0], body[2], body[3:], valid=checksum(body) == packet[-1])
