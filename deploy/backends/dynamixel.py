"""Dynamixel X servos (Koch, OpenManipulator-X arms) through ``dynamixel-sdk``, Protocol 2.0.

:class:`DynamixelBackend` is a :class:`~deploy.backends.servo_bus.ServoBusBackend` (see there for
the open sequence, the tick and the fault handling) on Dynamixel Protocol 2.0, with the
XM430-W350 / XL430-W250 control tables of :mod:`deploy.backends.servo.control_tables`
(ROBOTIS e-Manual).

Per tick: one SYNC READ of addresses 126-146 (Present_Current or Present_Load, Present_Velocity,
Present_Position, ..., Present_Input_Voltage, Present_Temperature: 21 contiguous bytes) and one
SYNC WRITE of Goal_Position (116) or Goal_Velocity (104), 4 bytes two's complement. Hardware
errors: a status packet's error byte has bit 7 ("Alert") set while Hardware_Error_Status (70) is
not 0 (e-Manual, Protocol 2.0 Status Packet); only then the backend reads that register of that
servo (one extra READ), so the tick stays one SYNC READ. Hardware_Error_Status bits: 1 input
voltage, 4 overheating, 8 motor encoder, 16 electrical shock, 32 overload (e-Manual, Shutdown).

Replies are received with the SDK's own ``rxPacket`` and assigned to their servo by ID (the SDK's
``GroupSyncRead`` stops at the first missing reply and drops the error bytes).
"""

from __future__ import annotations

from deploy.backends.servo.control_tables import DYNAMIXEL_ALERT, ServoModel
from deploy.backends.servo_bus import ServoBusBackend, ServoBusError

#: Reported when the Alert bit is set but Hardware_Error_Status could not be read.
UNKNOWN_HARDWARE_ERROR = DYNAMIXEL_ALERT


def _sdk():
    try:
        import dynamixel_sdk
    except ImportError as exc:  # the optional dependency
        raise ServoBusError(
            "the dynamixel backend needs dynamixel-sdk: pip install '.[servo]'"
        ) from exc
    return dynamixel_sdk


class DynamixelBackend(ServoBusBackend):
    """Dynamixel X servo arm on ``port`` in Protocol 2.0 (see the module and
    :class:`~deploy.backends.servo_bus.ServoBusBackend` for the arguments)."""

    protocol = "dynamixel"

    def present_quantities(self, model: ServoModel) -> tuple[str, ...]:
        effort = "present_current" if model.has("present_current") else "present_load"
        return (
            effort,
            "present_velocity",
            "present_position",
            "present_voltage",
            "present_temperature",
        )

    def _connect(self) -> None:
        dxl = self._dxl = _sdk()
        self._port = dxl.PortHandler(self.port_name)
        try:
            opened = self._port.openPort()
        except Exception as exc:  # pyserial raises SerialException (an OSError) or others
            raise ServoBusError(f"cannot open {self.port_name}: {exc}") from exc
        if not opened or not self._port.setBaudRate(self.baudrate):
            raise ServoBusError(f"cannot open {self.port_name} at {self.baudrate} bit/s")
        self._ph = dxl.PacketHandler(2.0)
        start, length = self.block_start, self.block_length
        self._reader = dxl.GroupSyncRead(self._port, self._ph, start, length)
        reg = self.goal_register
        self._writer = dxl.GroupSyncWrite(self._port, self._ph, reg.address, reg.size)
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
        return bytes(data) if result == self._dxl.COMM_SUCCESS else None

    def _sync_read(self) -> tuple[dict[int, tuple[bytes, int]], int]:
        dxl, port = self._dxl, self._port
        port.ser.reset_input_buffer()  # a late reply of the last tick is not this tick's
        replies: dict[int, tuple[bytes, int]] = {}
        corrupt = 0
        if self._reader.txPacket() != dxl.COMM_SUCCESS:
            return replies, corrupt
        port.setPacketTimeoutMillis(1e3 * self.read_timeout)
        # status packet: header(4) id len_l len_h instruction(0x55) error params... crc(2)
        p0 = dxl.PKT_ERROR + 1
        end = p0 + self.block_length
        for _ in range(2 * self.n + 2):  # every reply, plus room for corrupt ones
            packet, result = self._ph.rxPacket(port, False)
            if result == dxl.COMM_SUCCESS:
                sid = packet[dxl.PKT_ID]
                if sid in self._reader.data_dict and len(packet) >= end + 2:
                    replies[sid] = (bytes(packet[p0:end]), packet[dxl.PKT_ERROR])
            elif result == dxl.COMM_RX_CORRUPT:
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
        if not error_byte & DYNAMIXEL_ALERT:
            return 0  # an instruction error number (bits 0-6), not a hardware error
        reg = self.models[j].register("hardware_error")
        data = self._read_register(self.ids[j], reg.address, reg.size)
        bits = reg.decode(data) if data is not None else 0
        return bits or UNKNOWN_HARDWARE_ERROR

    def _close_port(self) -> None:
        self._port.closePort()

    def _result_text(self, result: int) -> str:
        return self._ph.getTxRxResult(result)
