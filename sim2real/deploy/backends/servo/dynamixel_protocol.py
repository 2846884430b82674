"""Dynamixel Protocol 2.0: packet framing, byte stuffing and CRC-16.

As ``dynamixel-sdk`` (``protocol2_packet_handler.py``) and the ROBOTIS e-Manual (Protocol 2.0)
define it::

    instruction: FF FF FD 00  ID  LEN_L LEN_H  INST  PARAM_1 ... PARAM_N  CRC_L CRC_H
    status:      FF FF FD 00  ID  LEN_L LEN_H  0x55  ERROR  PARAM_1 ... PARAM_N  CRC_L CRC_H

LEN counts the bytes after it (INST, parameters after stuffing, CRC). Byte stuffing: wherever
FF FF FD appears from INST to the last parameter, an extra FD follows (FF FF FD FD), so a header
never appears inside a packet; LEN and the CRC are computed on the stuffed packet. CRC-16: the
polynomial 0x8005 (CRC-16/BUYPASS: no reflection, initial value 0), over the whole packet but the
CRC itself (the SDK's ``updateCRC`` table).

Instructions: PING 0x01 (status parameters: model number L, H, firmware version), READ 0x02
(address L, H, length L, H), WRITE 0x03 (address L, H, data...), SYNC READ 0x82 (address, length,
id...), SYNC WRITE 0x83 (address, length, then per servo: id, data...). Status error byte: bit 7
"Alert" (see Hardware Error Status), bits 0-6 an error number
(:data:`sim2real.deploy.backends.servo.control_tables.DYNAMIXEL_ERRNUM`). Decoded as a
:class:`sim2real.deploy.backends.servo.framing.Packet` (``code``: INST).
"""

from __future__ import annotations

from sim2real.deploy.backends.servo import framing
from sim2real.deploy.backends.servo.framing import Packet

HEADER = b"\xff\xff\xfd"
BROADCAST_ID = 0xFE
PING, READ, WRITE, REG_WRITE, ACTION, REBOOT = 0x01, 0x02, 0x03, 0x04, 0x05, 0x08
SYNC_READ, SYNC_WRITE, STATUS = 0x82, 0x83, 0x55
#: Largest packet the SDK sends or accepts (``TXPACKET_MAX_LEN``), bytes.
MAX_PACKET = 1024


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes, crc: int = 0) -> int:
    """CRC-16 (poly 0x8005, init 0, MSB first) of ``data``: the SDK's ``updateCRC``."""
    table = _CRC_TABLE
    for byte in data:
        crc = ((crc << 8) ^ table[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(payload: bytes, before: bytes = b"\x00\x00") -> bytes:
    """Byte-stuff ``payload`` (INST .. last parameter): FF FF FD -> FF FF FD FD.

    ``before``: the two bytes preceding the payload in the packet (LEN_L, LEN_H), which the SDK
    takes into account at the start of the payload.
    """
    raw = bytes(before[-2:]) + bytes(payload)
    out = bytearray()
    for i in range(2, len(raw)):
        out.append(raw[i])
        if raw[i] == 0xFD and raw[i - 1] == 0xFF and raw[i - 2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(payload: bytes, before: bytes = b"\x00\x00") -> bytes:
    """Inverse of :func:`stuff`: FF FF FD FD -> FF FF FD."""
    raw = bytes(before[-2:]) + bytes(payload)
    out = bytearray()
    i = 2
    while i < len(raw):
        out.append(raw[i])
        if raw[i] == 0xFD and raw[i - 1] == 0xFF and raw[i - 2] == 0xFF and i + 1 < len(raw):
            if raw[i + 1] == 0xFD:
                i += 1  # drop the stuffed byte
        i += 1
    return bytes(out)


def _encode(servo_id: int, payload: bytes) -> bytes:
    if not 0 <= servo_id <= BROADCAST_ID:
        raise ValueError(f"servo ID {servo_id} out of 0..254")
    # The SDK stuffs with the unstuffed LEN in the two preceding bytes, then corrects LEN.
    length = len(payload) + 2
    stuffed = stuff(payload, bytes((length & 0xFF, length >> 8)))
    length = len(stuffed) + 2
    packet = HEADER + bytes((0x00, servo_id, length & 0xFF, length >> 8)) + stuffed
    if len(packet) + 2 > MAX_PACKET:
        raise ValueError(f"packet of {len(packet) + 2} bytes exceeds {MAX_PACKET}")
    crc = crc16(packet)
    return packet + bytes((crc & 0xFF, crc >> 8))


def encode_instruction(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """An instruction packet (bytes on the wire, stuffed, with its CRC).

    Raises:
        ValueError: ID out of 0..254 or the packet longer than ``MAX_PACKET``.
    """
    return _encode(servo_id, bytes((instruction,)) + bytes(params))


def encode_status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet (instruction 0x55) with the error byte ``error`` and ``params``.

    Raises:
        ValueError: ID out of 0..254 or the packet longer than ``MAX_PACKET``.
    """
    return _encode(servo_id, bytes((STATUS, error)) + bytes(params))


class PacketParser(framing.PacketParser):
    """Splits a byte stream into Protocol 2.0 packets (:class:`sim2real.deploy.backends.servo.framing.
    PacketParser`); a packet's ``code`` is its INST (0x55: status), its parameters unstuffed."""

    HEADER = HEADER

    def frame(self, buf: bytearray) -> int | None:
        """``7 + LEN`` bytes (module docstring); 0 for stuffing (FF FF FD FD) or a LEN out of
        range."""
        if len(buf) < 7:
            return None
        if buf[3] != 0x00:  # FF FF FD FD is stuffing, not a header
            return 0
        length = buf[5] | (buf[6] << 8)
        if length < 3 or 7 + length > MAX_PACKET:
            return 0
        return 7 + length if len(buf) >= 7 + length else None

    def decode(self, packet: bytes) -> Packet:
        """The packet, unstuffed, ``valid`` when its CRC matches."""
        valid = crc16(packet[:-2]) == (packet[-2] | (packet[-1] << 8))
        payload = unstuff(packet[7:-2], packet[5:7])
        return Packet(packet[4], payload[0], payload[1:], valid)
