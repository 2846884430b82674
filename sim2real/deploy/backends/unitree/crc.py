"""The CRC-32 a Unitree robot checks on every low-level command (and sets on every state).

The STM32 hardware CRC unit's algorithm, as Unitree's SDKs compute it (unitree_sdk2
``crc32_core``; unitree_sdk2_python ``utils/crc.py``): the message's C struct
(:func:`sim2real.deploy.backends.unitree.layout.c_dtype`) read as little-endian 32-bit words, all but the
last (the ``crc`` member itself), each word fed most significant bit first into a CRC with the
IEEE 802.3 polynomial 0x04C11DB7, initial value 0xFFFFFFFF, no reflection and no final XOR (the
CRC-32/MPEG-2 parameters, applied to the words' big-endian bytes).

Computed through :func:`zlib.crc32` (the reflected CRC-32 of the same polynomial) on the
bit-reversed bytes, its output XORed back and bit-reversed: the same number in C, a few
microseconds for a LowState_.
"""

from __future__ import annotations

import zlib

import numpy as np

#: Byte -> the byte with its bits in reverse order.
_REVERSED = bytes(int(f"{b:08b}"[::-1], 2) for b in range(256))


def _reverse32(x: int) -> int:
    return int(f"{x:032b}"[::-1], 2)


def crc32_words(words: bytes | np.ndarray) -> int:
    """The CRC-32 (module docstring) of ``words``: little-endian 32-bit words (a length that is
    a multiple of 4 bytes), all of them fed to the CRC.

    Raises:
        ValueError: a length that is not a multiple of 4.
    """
    data = memoryview(words).cast("B") if isinstance(words, np.ndarray) else memoryview(words)
    if len(data) % 4:
        raise ValueError(f"crc32_words: {len(data)} bytes is not a whole number of 32-bit words")
    big_endian = np.frombuffer(data, dtype="<u4").astype(">u4").tobytes()
    raw = zlib.crc32(big_endian.translate(_REVERSED)) ^ 0xFFFFFFFF
    return _reverse32(raw)


def message_crc(c_bytes: bytes | np.ndarray) -> int:
    """The CRC of a message in its C layout: every 32-bit word but the last (the ``crc``)."""
    data = memoryview(c_bytes).cast("B") if isinstance(c_bytes, np.ndarray) else c_bytes
    return crc32_words(data[: (len(data) // 4 - 1) * 4])
