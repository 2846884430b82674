"""One emulated servo: its control-table memory, the side effects of writes, its faults.

The servo knows nothing of the plant or the wire: the bus (:mod:`.bus`) fills its present
registers from the plant, reads its goal registers back, and frames its replies.
"""

from __future__ import annotations

from dataclasses import dataclass

from sim2real.deploy.backends.servo.control_tables import DYNAMIXEL_ALERT, Register, ServoModel
from sim2real.robots import MotorConfig


@dataclass
class WriteResult:
    """Outcome of a write: ``error`` names a refusal (``'access'``: read-only register, or the
    EEPROM area with torque on, on a Dynamixel); ``touched`` the registers written."""

    error: str | None
    touched: tuple[str, ...]


class EmulatedServo:
    """The control table of one servo, bound to joint ``joint`` of the plant.

    Args:
        model: The servo model (control table, units).
        servo_id: Bus ID (written to the ID register).
        joint: Index of the plant joint it drives.
        motor: The joint's motor catalog entry: its ``encoder_resolution`` (ticks per output turn;
            default the model's) and its ``protection.registers`` (defaults written over the
            model's where a register of that name exists).
        baudrate: Bus baud rate, bit/s; written to Baud_Rate when the model has a code for it.

    Attributes:
        faults: Names of the latched faults (``ServoModel.error_bits`` keys).
        unplugged: True once the servo has stopped answering (cable pulled).
    """

    def __init__(
        self, model: ServoModel, servo_id: int, joint: int, motor: MotorConfig, baudrate: int
    ):
        self.model = model
        self.joint = joint
        self.resolution = motor.encoder_resolution or model.resolution
        self.memory = bytearray(model.memory_size)
        for reg in model.registers:
            self._store(reg, reg.default)
        if motor.protection is not None:
            for name, reg in motor.protection.registers.items():
                if model.has(name) and model.register(name).address == reg.address:
                    self._store(model.register(name), reg.default)
        self.set("id", servo_id)
        if baudrate in model.baud_codes:
            self.set("baud_rate", model.baud_codes[baudrate])
        self.faults: set[str] = set()
        self.unplugged = False
        self._registered: tuple[int, bytes] | None = None  # REG WRITE awaiting ACTION

    # ------------------------------------------------------------------ registers
    @property
    def servo_id(self) -> int:
        """Present bus ID (the ID register)."""
        return self.get("id")

    def _store(self, reg: Register, value: int) -> None:
        self.memory[reg.address : reg.address + reg.size] = reg.encode(value)

    def get(self, name: str) -> int:
        """Value of register ``name`` (or common quantity, see ``ServoModel.names``), counts.

        Raises:
            KeyError: the model has no such register.
        """
        reg = self.model.register(name)
        return reg.decode(self.memory[reg.address : reg.address + reg.size])

    def set(self, name: str, value: int) -> None:
        """Store ``value`` (counts) in register ``name``, bypassing access rules (the servo's own
        firmware: present values, torque off on a fault).

        Raises:
            KeyError: no such register. ValueError: the value does not fit.
        """
        self._store(self.model.register(name), value)

    def set_clipped(self, name: str, value: float) -> None:
        """Store ``value`` rounded and clipped to what register ``name`` can hold."""
        reg = self.model.register(name)
        bits = 8 * reg.size
        if reg.encoding.startswith("sign_magnitude:"):
            top = (1 << int(reg.encoding.split(":")[1])) - 1
            lo, hi = -top, top
        elif reg.encoding == "twos":
            lo, hi = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        else:
            lo, hi = 0, (1 << bits) - 1
        self._store(reg, min(max(int(round(value)), lo), hi))

    def read(self, address: int, length: int) -> bytes:
        """``length`` bytes of the control table from ``address`` (zeros past its end)."""
        data = bytes(self.memory[address : address + length])
        return data + bytes(length - len(data))

    def write(self, address: int, data: bytes) -> WriteResult:
        """A host's WRITE of ``data`` at ``address``, with the servo's access rules.

        Dynamixel: a byte of a read-only register, or of the EEPROM area while torque is on, makes
        the whole write fail (``error='access'``, e-Manual "Status Packet" Access Error). Feetech:
        read-only bytes are ignored. Bytes past the table are ignored. Torque cannot be enabled
        while a fault that cut it persists (see :meth:`update_protection`).
        """
        end = address + len(data)
        touched = [
            r for r in self.model.registers if r.address < end and address < r.address + r.size
        ]
        if self.model.protocol == "dynamixel":
            torque_on = self.get("torque_enable") != 0
            if any(not r.writable or (r.eeprom and torque_on) for r in touched):
                return WriteResult("access", ())
        for i, byte in enumerate(data):
            a = address + i
            if a >= len(self.memory):
                break
            reg = next((r for r in touched if r.address <= a < r.address + r.size), None)
            if reg is not None and not reg.writable:
                continue
            self.memory[a] = byte
        names = tuple(r.name for r in touched if r.writable)
        if self.model.names["torque_enable"] in names and self.get("torque_enable"):
            if any(f in self.model.torque_off_on for f in self.faults):
                self.set("torque_enable", 0)
        return WriteResult(None, names)

    def register_write(self, address: int, data: bytes) -> None:
        """REG WRITE: keep the write until ACTION."""
        self._registered = (address, bytes(data))

    def action(self) -> WriteResult | None:
        """ACTION: perform the registered write, if any."""
        pending, self._registered = self._registered, None
        return None if pending is None else self.write(*pending)

    # ------------------------------------------------------------------ faults
    def trip(self, fault: str) -> None:
        """Latch ``fault`` (an ``error_bits`` key); cut torque if the model does on that fault."""
        self.faults.add(fault)
        if fault in self.model.torque_off_on:
            self.set("torque_enable", 0)
        if self.model.has("hardware_error"):
            self.set("hardware_error", self._fault_bits())

    def clear_faults(self) -> None:
        """Forget the latched faults (a Dynamixel REBOOT, a Feetech power cycle); the conditions
        are checked again at the next :meth:`update_protection`."""
        self.faults.clear()
        if self.model.has("hardware_error"):
            self.set("hardware_error", 0)

    def update_protection(self, winding_temperature: float) -> None:
        """The servo's over-temperature protection: past its temperature-limit register (degC)
        the winding trips ``overheat`` (torque off, error bit). A Feetech servo clears the bit
        once cooled below the limit (torque stays off until enabled again); a Dynamixel keeps it
        until REBOOT (e-Manual, Shutdown(63))."""
        hot = winding_temperature > self.get("temperature_limit")
        if hot and "overheat" not in self.faults:
            self.trip("overheat")
        elif not hot and "overheat" in self.faults and self.model.protocol == "feetech":
            self.faults.discard("overheat")

    def _fault_bits(self) -> int:
        bits = self.model.error_bits
        return sum(bits[f] for f in self.faults if f in bits)

    def error_byte(self, errnum: int = 0) -> int:
        """The error byte of the servo's next status packet.

        Feetech: the bits of the latched faults. Dynamixel: ``errnum`` (the instruction's result,
        ``DYNAMIXEL_ERRNUM``) with the Alert bit 7 when Hardware_Error_Status is not 0.
        """
        if self.model.protocol == "feetech":
            return self._fault_bits()
        return errnum | (DYNAMIXEL_ALERT if self._fault_bits() else 0)

    def reply_delay(self) -> float:
        """Return_Delay_Time in s (register counts x the model's unit)."""
        return self.get("return_delay") * self.model.return_delay_unit

    def answers(self, instruction: str) -> bool:
        """Whether the status-return level lets the servo answer ``instruction`` ('ping',
        'read' or 'write'). Feetech Response_Status_Level 0: PING and READ only; Dynamixel Status
        Return Level 0: PING only, 1: PING and READ, 2: all (e-Manual)."""
        level = self.get("status_return")
        if self.model.protocol == "feetech":
            return level >= 1 or instruction in ("ping", "read")
        return {"ping": 0, "read": 1}.get(instruction, 2) <= level
