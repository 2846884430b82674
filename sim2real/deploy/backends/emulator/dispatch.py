"""What the servos on a bus do with each instruction packet, per protocol.

A dispatcher decodes the host's byte stream (:mod:`sim2real.deploy.backends.servo.feetech_protocol` or
:mod:`sim2real.deploy.backends.servo.dynamixel_protocol`), applies each instruction to the addressed servos
(:class:`.servo.EmulatedServo`) and returns the status packets they send, in bus order. Timing,
dropped and corrupted replies are the bus's business (:mod:`.bus`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

from sim2real.deploy.backends.emulator.servo import EmulatedServo, WriteResult
from sim2real.deploy.backends.servo import dynamixel_protocol as dxl
from sim2real.deploy.backends.servo import feetech_protocol as ft
from sim2real.deploy.backends.servo.control_tables import DYNAMIXEL_ERRNUM
from sim2real.deploy.backends.servo.framing import Packet, PacketParser

#: Called after a host's write reached a servo (the bus reacts to mode and torque changes).
OnWrite = Callable[[EmulatedServo, WriteResult], None]


@dataclass(frozen=True)
class Reply:
    """A status packet ``packet`` (bytes on the wire) that ``servo`` sends."""

    servo: EmulatedServo
    packet: bytes


@dataclass(frozen=True)
class Exchange:
    """One instruction packet and the replies to it.

    Attributes:
        instruction_bytes: Length of the instruction packet on the wire (for its byte time).
        replies: The status packets, in the order the servos send them.
        valid: False when the instruction's checksum / CRC failed.
    """

    instruction_bytes: int
    replies: list[Reply]
    valid: bool = True


def _sync_chunks(params: bytes, head: int, length: int) -> list[tuple[int, bytes]]:
    """SYNC WRITE parameters after the ``head`` bytes: (id, data of ``length`` bytes) per servo."""
    body, step = params[head:], length + 1
    return [(body[i], body[i + 1 : i + step]) for i in range(0, len(body) - length, step)]


class Dispatcher:
    """A protocol's dispatcher: its ``PARSER`` decodes the stream, its ``_handle`` answers each
    packet; ``on_write`` is called after every write that reaches a servo."""

    PARSER: type[PacketParser] = PacketParser

    def __init__(self, on_write: OnWrite):
        self._parser = self.PARSER()
        self._on_write = on_write

    def feed(self, data: bytes, servos: Mapping[int, EmulatedServo]) -> list[Exchange]:
        """Decode ``data`` and apply every completed packet to ``servos`` (ID -> answering
        servo)."""
        return [self._handle(p, servos) for p in self._parser.feed(data)]

    def _handle(self, p: Packet, servos: Mapping[int, EmulatedServo]) -> Exchange:
        raise NotImplementedError


class FeetechDispatcher(Dispatcher):
    """Feetech SCS/STS protocol: PING, READ, WRITE, REG WRITE, ACTION, SYNC READ, SYNC WRITE.

    A packet with a bad checksum is ignored (no reply). Broadcast (ID 254) WRITE and SYNC WRITE
    get no reply; a broadcast PING is answered by every servo in ID order.
    """

    PARSER = ft.PacketParser

    def _status(self, servo: EmulatedServo, params: bytes = b"") -> Reply:
        return Reply(servo, ft.encode_status(servo.servo_id, servo.error_byte(), params))

    def _write(self, servo: EmulatedServo, address: int, data: bytes) -> None:
        self._on_write(servo, servo.write(address, data))

    def _handle(self, p: Packet, servos: Mapping[int, EmulatedServo]) -> Exchange:
        size = len(p.params) + 6
        if not p.valid:
            return Exchange(size, [], valid=False)
        inst, params = p.code, p.params
        if p.servo_id == ft.BROADCAST_ID:
            targets = [servos[i] for i in sorted(servos)]
        else:
            targets = [servos[p.servo_id]] if p.servo_id in servos else []
        replies: list[Reply] = []
        if inst == ft.SYNC_WRITE and len(params) >= 2:
            for sid, data in _sync_chunks(params, 2, params[1]):
                if sid in servos:
                    self._write(servos[sid], params[0], data)
        elif inst == ft.SYNC_READ and len(params) >= 2:
            for sid in params[2:]:
                if sid in servos:
                    s = servos[sid]
                    replies.append(self._status(s, s.read(params[0], params[1])))
        elif inst == ft.PING:
            replies = [self._status(s) for s in targets]
        elif inst == ft.READ and len(params) >= 2 and p.servo_id != ft.BROADCAST_ID:
            replies = [self._status(s, s.read(params[0], params[1])) for s in targets]
        elif inst in (ft.WRITE, ft.REG_WRITE, ft.ACTION):
            for s in targets:
                if inst == ft.WRITE and params:
                    self._write(s, params[0], params[1:])
                elif inst == ft.REG_WRITE and params:
                    s.register_write(params[0], params[1:])
                elif inst == ft.ACTION and (result := s.action()) is not None:
                    self._on_write(s, result)
            if p.servo_id != ft.BROADCAST_ID:
                replies = [self._status(s) for s in targets if s.answers("write")]
        return Exchange(size, replies)


class DynamixelDispatcher(Dispatcher):
    """Dynamixel Protocol 2.0: PING, READ, WRITE, REG WRITE, ACTION, REBOOT, SYNC READ,
    SYNC WRITE.

    A unicast packet with a bad CRC is answered with the CRC error number (e-Manual, Status
    Packet); an unknown instruction with the instruction error. Broadcast WRITE / SYNC WRITE get
    no reply; a broadcast PING is answered by every servo in ID order.
    """

    PARSER = dxl.PacketParser

    @staticmethod
    def _status(servo: EmulatedServo, params: bytes = b"", errnum: int = 0) -> Reply:
        return Reply(servo, dxl.encode_status(servo.servo_id, servo.error_byte(errnum), params))

    def _write(self, servo: EmulatedServo, address: int, data: bytes) -> int:
        result = servo.write(address, data)
        self._on_write(servo, result)
        return DYNAMIXEL_ERRNUM[result.error] if result.error else 0

    def _handle(self, p: Packet, servos: Mapping[int, EmulatedServo]) -> Exchange:
        size = len(p.params) + 10
        unicast = p.servo_id != dxl.BROADCAST_ID
        target = servos.get(p.servo_id)
        if not p.valid:
            replies = [self._status(target, errnum=DYNAMIXEL_ERRNUM["crc"])] if target else []
            return Exchange(size, replies, valid=False)
        inst, params = p.code, p.params
        targets = [servos[i] for i in sorted(servos)] if not unicast else [target] if target else []
        replies: list[Reply] = []
        word = (lambda i: params[i] | (params[i + 1] << 8)) if len(params) >= 4 else None
        if inst == dxl.PING:
            model = [s.model for s in targets]
            replies = [
                self._status(s, bytes((m.model_number & 0xFF, m.model_number >> 8, m.firmware)))
                for s, m in zip(targets, model, strict=True)
            ]
        elif inst == dxl.SYNC_WRITE and word is not None:
            for sid, data in _sync_chunks(params, 4, word(2)):
                if sid in servos:
                    self._write(servos[sid], word(0), data)
        elif inst == dxl.SYNC_READ and word is not None:
            for sid in params[4:]:
                if sid in servos:
                    replies.append(self._status(servos[sid], servos[sid].read(word(0), word(2))))
        elif not unicast:
            if inst == dxl.WRITE and len(params) >= 2:
                for s in targets:
                    self._write(s, params[0] | (params[1] << 8), params[2:])
        elif target is None:
            pass
        elif inst == dxl.READ and word is not None:
            if target.answers("read"):
                replies = [self._status(target, target.read(word(0), word(2)))]
        elif inst in (dxl.WRITE, dxl.REG_WRITE) and len(params) >= 2:
            address, data = params[0] | (params[1] << 8), params[2:]
            errnum = 0
            if inst == dxl.WRITE:
                errnum = self._write(target, address, data)
            else:
                target.register_write(address, data)
            if target.answers("write"):
                replies = [self._status(target, errnum=errnum)]
        elif inst == dxl.ACTION:
            if (result := target.action()) is not None:
                self._on_write(target, result)
            if target.answers("write"):
                replies = [self._status(target)]
        elif inst == dxl.REBOOT:
            target.clear_faults()
            target.set("torque_enable", 0)
            if target.answers("write"):
                replies = [self._status(target)]
        else:
            replies = [self._status(target, errnum=DYNAMIXEL_ERRNUM["instruction"])]
        return Exchange(size, replies)
