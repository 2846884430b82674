"""References the Unitree tests build independently of the code under test: a bitwise CRC
written from its definition and the C struct of a ``unitree_go`` LowCmd_ packed with
:mod:`struct` from the IDL's member list."""

from __future__ import annotations

import struct

POLY = 0x04C11DB7


def crc_bitwise(words: list[int]) -> int:
    """CRC-32 of 32-bit words, each fed most significant bit first: polynomial 0x04C11DB7,
    initial 0xFFFFFFFF, no reflection, no final XOR (the STM32 CRC unit Unitree's boards use)."""
    crc = 0xFFFFFFFF
    for word in words:
        for bit in range(31, -1, -1):
            feedback = ((crc >> 31) ^ (word >> bit)) & 1
            crc = (crc << 1) & 0xFFFFFFFF
            if feedback:
                crc ^= POLY
    return crc


def mpeg2_bytes(data: bytes) -> int:
    """CRC-32/MPEG-2 of a byte string, bit by bit (its catalogue check: '123456789' ->
    0x0376E6E7)."""
    crc = 0xFFFFFFFF
    for byte in data:
        for bit in range(7, -1, -1):
            feedback = ((crc >> 31) ^ (byte >> bit)) & 1
            crc = (crc << 1) & 0xFFFFFFFF
            if feedback:
                crc ^= POLY
    return crc


def le_words(data: bytes) -> list[int]:
    return [int.from_bytes(data[i : i + 4], "little") for i in range(0, len(data), 4)]


def go_lowcmd_c_struct(head, level, motors, gpio, reserve, crc) -> bytes:
    """unitree_go LowCmd_ as its C struct (natural alignment, packed here from the IDL's members):
    head[2] u8, level_flag u8, frame_reserve u8, sn[2] u32, version[2] u32, bandwidth u16 (+2),
    20 x MotorCmd_ (mode u8 +3, q dq tau kp kd f32, reserve[3] u32), BmsCmd_ (off u8,
    reserve[3] u8), wireless_remote[40] u8, led[12] u8, fan[2] u8, gpio u8 (+1), reserve u32,
    crc u32."""
    out = struct.pack("<2BBB2I2IH2x", *head, level, 0, 0, 0, 0, 0, 0)
    for mode, q, dq, tau, kp, kd in motors:
        out += struct.pack("<B3x5f3I", mode, q, dq, tau, kp, kd, 0, 0, 0)
    out += struct.pack("<4B", 0, 0, 0, 0) + bytes(40 + 12 + 2)
    return out + struct.pack("<Bx2I", gpio, reserve, crc)
