"""References the Unitree tests build independently of the code under test: a bitwise CRC
written from its definition, the C struct of a ``unitree_go`` LowCmd_ packed with
:mod:`struct` from the IDL's member list, and the LowCmd_ built field by field."""

from __future__ import annotations

import struct

POLY = 0x04C11DB7


def _msb_first(values, bits: int) -> int:
    """CRC-32 (polynomial 0x04C11DB7, initial 0xFFFFFFFF, no reflection, no final XOR) of
    ``bits``-bit values, each fed most significant bit first, bit by bit."""
    crc = 0xFFFFFFFF
    for value in values:
        for bit in range(bits - 1, -1, -1):
            feedback = ((crc >> 31) ^ (value >> bit)) & 1
            crc = (crc << 1) & 0xFFFFFFFF
            if feedback:
                crc ^= POLY
    return crc


def crc_bitwise(words: list[int]) -> int:
    """CRC-32 of 32-bit words, each fed most significant bit first: polynomial 0x04C11DB7,
    initial 0xFFFFFFFF, no reflection, no final XOR (the STM32 CRC unit Unitree's boards use)."""
    return _msb_first(words, 32)


def mpeg2_bytes(data: bytes) -> int:
    """CRC-32/MPEG-2 of a byte string, bit by bit (its catalogue check: '123456789' ->
    0x0376E6E7)."""
    return _msb_first(data, 8)


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


def go_lowcmd_object(motors, crc: int, gpio: int = 0, reserve: int = 0):
    """unitree_go LowCmd_ built field by field as a Cyclone DDS object: the Go2's head 0xFE 0xEF
    and level flag 0xFF, one MotorCmd_ per ``(mode, q, dq, tau, kp, kd)`` of ``motors``."""
    from sim2real.deploy.backends.unitree import unitree_go

    return unitree_go.LowCmd_(
        head=[0xFE, 0xEF],
        level_flag=0xFF,
        motor_cmd=[
            unitree_go.MotorCmd_(mode=mode, q=q, dq=dq, tau=tau, kp=kp, kd=kd)
            for mode, q, dq, tau, kp, kd in motors
        ],
        gpio=gpio,
        reserve=reserve,
        crc=crc,
    )
