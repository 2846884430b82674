"""Feetech STS servos (SO-100 / SO-101 arms) through ``feetech-servo-sdk`` (``scservo_sdk``).

:class:`FeetechBackend` is a :class:`~sim2real.deploy.backends.servo.servo_bus.ServoBusBackend` (see
there for the open sequence, the tick and the fault handling) on Feetech's SCS/STS protocol
(protocol end 0, little endian), with the STS3215 control table of
:mod:`sim2real.deploy.backends.servo.control_tables`.

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

from sim2real.deploy.backends.servo.control_tables import ServoModel
from sim2real.deploy.backends.servo.sdk_bus import SdkServoBus

#: The STS error-byte bits that are hardware errors (ERRBIT_ANGLE, 2, is not).
HARDWARE_ERROR_MASK = 1 | 4 | 8 | 32


class FeetechBackend(SdkServoBus):
    """Feetech STS3215 servo arm on ``port`` (see the module and
    :class:`~sim2real.deploy.backends.servo.servo_bus.ServoBusBackend` for the arguments)."""

    protocol = "feetech"

    def present_quantities(self, model: ServoModel) -> tuple[str, ...]:
        return (
            "present_position",
            "present_velocity",
            "present_load",
            "present_voltage",
            "present_temperature",
        )

    packet_protocol = 0  # protocol end 0: little endian (STS)
    sdk_module, sdk_package = "scservo_sdk", "feetech-servo-sdk"
    status_trailer = 1  # checksum

    def _parameter_start(self, sdk) -> int:
        return sdk.PKT_PARAMETER0

    def _hardware_error(self, j: int, error_byte: int) -> int:
        return error_byte & HARDWARE_ERROR_MASK

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
