"""Dynamixel X servos (Koch, OpenManipulator-X arms) through ``dynamixel-sdk``, Protocol 2.0.

:class:`DynamixelBackend` is a :class:`~sim2real.deploy.backends.servo.servo_bus.ServoBusBackend` (see
there for the open sequence, the tick and the fault handling) on Dynamixel Protocol 2.0, with the
XM430-W350 / XL430-W250 control tables of :mod:`sim2real.deploy.backends.servo.control_tables`
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

from sim2real.deploy.backends.servo.control_tables import DYNAMIXEL_ALERT, ServoModel
from sim2real.deploy.backends.servo.sdk_bus import SdkServoBus

#: Reported when the Alert bit is set but Hardware_Error_Status could not be read.
UNKNOWN_HARDWARE_ERROR = DYNAMIXEL_ALERT
#: Attempts at reading Hardware_Error_Status after a status packet's alert bit (our choice: the
#: servo has just latched a fault and the runtime may stop reading once it latches too; a loaded
#: bus or host drops a reply now and then, 3 tries cost ~1 ms only when a fault happens).
HARDWARE_ERROR_READS = 3


class DynamixelBackend(SdkServoBus):
    """Dynamixel X servo arm on ``port`` in Protocol 2.0 (see the module and
    :class:`~sim2real.deploy.backends.servo.servo_bus.ServoBusBackend` for the arguments)."""

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

    packet_protocol = 2.0
    sdk_module, sdk_package = "dynamixel_sdk", "dynamixel-sdk"
    status_trailer = 2  # CRC-16

    def _parameter_start(self, sdk) -> int:
        # status packet: header(4) id len_l len_h instruction(0x55) error params... crc(2)
        return sdk.PKT_ERROR + 1

    def _receive(self, port):
        return self._ph.rxPacket(port, False)

    def _hardware_error(self, j: int, error_byte: int) -> int:
        if not error_byte & DYNAMIXEL_ALERT:
            return 0  # an instruction error number (bits 0-6), not a hardware error
        reg = self.models[j].register("hardware_error")
        for _ in range(HARDWARE_ERROR_READS):  # a dropped reply must not lose the diagnosis
            data = self._read_register(self.ids[j], reg.address, reg.size)
            if data is not None:
                return reg.decode(data) or UNKNOWN_HARDWARE_ERROR
        return UNKNOWN_HARDWARE_ERROR
