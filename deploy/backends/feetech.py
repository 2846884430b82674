"""Feetech STS servos (SO-100 / SO-101 arms) through ``feetech-servo-sdk`` (``scservo_sdk``).

:class:`FeetechBackend` is a :class:`~deploy.backends.servo_bus.ServoBusBackend` (see there for
the open sequence, the tick and the fault handling) on Feetech's SCS/STS protocol (protocol end 0,
little endian), with the STS3215 control table of
:mod:`deploy.backends.servo.control_tables`.

Per tick: one SYNC READ of addresses 56-63 (Present_Position, Present_Velocity, Present_Load,
Present_Voltage, Present_Temperature: 8 contiguous bytes) and one SYNC WRITE of Goal_Position (42)
or Goal_Velocity (46), sign-magnitude with the sign at bit 15. Hardware errors come with every
status packet: its error byte (``scservo_sdk``'s ERRBIT_VOLTAGE 1, ERRBIT_OVERHEAT 4,
ERRBIT_OVERELE 8, ERRBIT_OVERLOAD 32). ERRBIT_ANGLE (2, a goal outside the position limits) is a
command error, not a hardware one, and is not reported.

The SDK's ``GroupSyncRead.rxPacket`` stops at the first missing reply and drops every reply's
error byte; the backend therefore sends the SDK group's SYNC READ and receives the status packets
with the SDK's own ``rxPacket``, assigning each to its servo by ID and keeping its error byte.
The EEPROM writes of ``open()`` are made with the Lock register (55) at 0 and Lock is set to 1
with torque on, as LeRobot's ``FeetechMotorsBus`` does.
"""

from __future__ import annotations

from deploy.backends.servo.control_tables import ServoModel
from deploy.backends.servo_bus import ServoBusBackend, ServoBusError

#: The STS error-byte bits that are hardware errors (ERRBIT_ANGLE, 2, is not).
HARDWARE_ERROR_MASK = 1 | 4 | 8 | 32


def _sdk():
    try:
        import scservo_sdk
    except ImportError as exc:  # the optional dependency
        raise ServoBusError(
            "the feetech backend needs feetech-servo-sdk: pip install '.[servo]'"
        ) from exc
    return scservo_sdk


class FeetechBackend(ServoBusBackend):
    """Feetech STS3215 servo arm on ``port`` (see the module and
    :class:`~deploy.backends.servo_bus.ServoBusBackend` for the arguments)."""

    protocol = "feetech"

    def present_quantities(self, model: ServoModel) -> tuple[str, ...]:
        return (
            "present_position",
            "present_velocity",
            "present_load",
            "present_voltage",
            "present_temperature",
        )

    def _connect(self) -> None:
        scs = self._scs = _sdk()
        self._port = scs.PortHandler(self.port_name)
        try:
            opened = self._port.openPort()
        except Exception as exc:  # pyserial raises SerialException (an OSError) or others
            raise ServoBusError(f"cannot open {self.port_name}: {exc}") from exc
        if not opened or not self._port.setBaudRate(self.baudrate):
            raise ServoBusError(f"cannot open {self.port_name} at {self.baudrate} bit/s")
        self._ph = scs.PacketHandler(0)
        start, length = self.block_start, self.block_length
        self._reader = scs.GroupSyncRead(self._port, self._ph, start, length)
        reg = self.goal_register
        self._writer = scs.GroupSyncWrite(self._port, self._ph, reg.address, reg.size)
        for sid in self.ids:
            self._reader.addParam(sid)
            self._writer.addParam(sid, [0] * reg.size)

    def _ping(self, servo_id: int) -> tuple[int, int]:
        model, result, _ = self._ph.ping(self._port, servo_id)
        return model, result

    def _write_register(self, servo_id: int, address: int, data: bytes) -> tuple[int, int]:
        return self._ph.writeTxRx(self._port, servo_id, address, len(data), list(data))

    def _read_register(self, servo_id: int, address: int, length: int) -> bytes | None:
        data, result, _ = self._ph.readTxRx(self._port, servo_id, address, length)
        return bytes(data) if result == self._scs.COMM_SUCCESS else None

    def _sync_read(self) -> tuple[dict[int, tuple[bytes, int]], int]:
        scs, port = self._scs, self._port
        port.ser.reset_input_buffer()  # a late reply of the last tick is not this tick's
        replies: dict[int, tuple[bytes, int]] = {}
        corrupt = 0
        if self._reader.txPacket() != scs.COMM_SUCCESS:
            return replies, corrupt
        port.setPacketTimeoutMillis(1e3 * self.read_timeout)
        p0, end = scs.PKT_PARAMETER0, scs.PKT_PARAMETER0 + self.block_length
        for _ in range(2 * self.n + 2):  # every reply, plus room for corrupt ones
            packet, result = self._ph.rxPacket(port)
            if result == scs.COMM_SUCCESS:
                sid = packet[scs.PKT_ID]
                if sid in self._reader.data_dict and len(packet) >= end + 1:
                    replies[sid] = (bytes(packet[p0:end]), packet[scs.PKT_ERROR])
            elif result == scs.COMM_RX_CORRUPT:
                corrupt += 1
            else:
                break
            if len(replies) == self.n:
                break
        return replies, corrupt

    def _sync_write(self, data: list[bytes]) -> None:
        for sid, value in zip(self.ids, data, strict=True):
            self._writer.changeParam(sid, list(value))
        self._writer.txPacket()

    def _hardware_error(self, j: int, error_byte: int) -> int:
        return error_byte & HARDWARE_ERROR_MASK

    def _close_port(self) -> None:
        self._port.closePort()

    def _result_text(self, result: int) -> str:
        return self._ph.getTxRxResult(result)

    def disable(self) -> None:
        """Torque off, then Lock 0 (EEPROM writable), every servo that answers."""
        super().disable()
        for j, sid in enumerate(self.ids):
            if self.models[j].has("Lock"):
                reg = self.models[j].register("Lock")
                self._write_register(sid, reg.address, reg.encode(0))

    def enable(self) -> None:
        """Torque on (goal = present pose first), then Lock 1, as LeRobot does."""
        super().enable()
        for j in range(self.n):
            if self.models[j].has("Lock"):
                self._set(j, "Lock", 1)
