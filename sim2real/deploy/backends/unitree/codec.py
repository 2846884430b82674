"""Encode and decode one low-level message type without building Python objects per message.

Cyclone DDS's Python serializer walks a LowState_ member by member (milliseconds per message, more
than the robot's 2 ms period). A :class:`MessageCodec` keeps the message in one numpy record of
its C layout (:func:`sim2real.deploy.backends.unitree.layout.c_dtype`) that the caller fills or reads in
place (``codec.message["motor_cmd"]["q"][3] = 0.8``), and converts it to and from the XCDR1
sample DDS carries with one gather: the same bytes Cyclone DDS's own serializer produces for the
same values (``tests/test_unitree_messages.py``), tens of microseconds.

Wire format: the 4-byte encapsulation header ``00 01 00 00`` (CDR, little endian; OMG DDS-XTypes
1.3, section 7.6.3.1.2), then the body. The CRC (:mod:`sim2real.deploy.backends.unitree.crc`) is set by
:meth:`MessageCodec.encode` and checked by :meth:`MessageCodec.decode`.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.unitree.crc import message_crc
from sim2real.deploy.backends.unitree.layout import c_dtype, cdr_gather

#: The encapsulation header of a little-endian plain CDR (XCDR1) sample.
CDR_LE = b"\x00\x01\x00\x00"


class MessageCodec:
    """One message type's record and its wire conversions.

    Args:
        cls: The IdlStruct type (e.g. :class:`sim2real.deploy.backends.unitree.unitree_go.LowCmd_`); its
            last member must be its ``uint32 crc``.

    Attributes:
        dtype: The C-layout numpy dtype. message: A 0-d record of it (the buffer the codec
            encodes from and decodes into; fields are views). size: bytes of a sample on the wire.

    Raises:
        ValueError: a type whose last member is not ``crc``.
    """

    def __init__(self, cls: type):
        self.cls = cls
        self.dtype = c_dtype(cls)
        if self.dtype.names[-1] != "crc" or self.dtype.fields["crc"][1] != self.dtype.itemsize - 4:
            raise ValueError(f"{cls.__name__}: the last member must be its uint32 crc")
        n = self.dtype.itemsize
        self._ext = np.zeros(n + 1, dtype=np.uint8)  # the C bytes and one zero (padding source)
        self.buffer = self._ext[:n]
        self.message = self.buffer.view(self.dtype).reshape(())
        gather = cdr_gather(cls)
        self._gather = np.where(gather >= 0, gather, n)
        self._src = np.flatnonzero(gather >= 0)
        self._dst = gather[self._src]
        self.size = len(CDR_LE) + len(gather)

    def clear(self) -> None:
        """Zero every field."""
        self.buffer.fill(0)

    def crc(self) -> int:
        """The CRC of the record as it stands (its ``crc`` field excluded)."""
        return message_crc(self.buffer)

    def encode(self, crc: bool = True) -> bytes:
        """The record as a DDS sample (header and XCDR1 body), its ``crc`` field set first
        (``crc=False``: left 0, as Unitree's simulation bridges publish their states)."""
        self.message["crc"] = message_crc(self.buffer) if crc else 0
        return CDR_LE + self._ext[self._gather].tobytes()

    def decode(self, sample: bytes) -> bool:
        """Read a DDS sample into the record; True when its CRC matches its contents.

        Raises:
            ValueError: not a little-endian plain CDR sample of this type (header or length).
        """
        if sample[:2] != CDR_LE[:2] or len(sample) < self.size:
            raise ValueError(
                f"{self.cls.__name__}: expected a {self.size}-byte little-endian CDR sample, "
                f"got {len(sample)} bytes starting {bytes(sample[:4]).hex()}"
            )
        body = np.frombuffer(sample, dtype=np.uint8, count=self.size - 4, offset=4)
        self.buffer[self._dst] = body[self._src]
        return int(self.message["crc"]) == message_crc(self.buffer)
