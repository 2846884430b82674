"""Control tables of the serial-bus servos we support, and their units.

A servo is a little memory of registers ("control table"): the host reads and writes byte ranges of
it by address. This module names every register we use (address, size, factory default, access,
encoding, unit) and converts between register values and SI units, for the wire-protocol emulator
and for the servo backends alike.

Sources:
    Feetech STS3215: Feetech STS memory table ("Magnetic Encoder STS Servo - Memory Table
    Analysis") and LeRobot's Feetech control table (huggingface/lerobot,
    ``src/lerobot/motors/feetech/tables.py``: addresses, sizes, the sign-magnitude bits of Homing
    Offset (bit 11) and Goal/Present Velocity (bit 15), model number 777). The official Feetech
    SDK reads Present Position and Present Current with bit 15 and Present Load with bit 10 as the
    sign (``SMS_STS::ReadPos / ReadCurrent / ReadLoad``). Status error bits: ``scservo_sdk``
    (``ERRBIT_VOLTAGE`` 1, ``ERRBIT_ANGLE`` 2, ``ERRBIT_OVERHEAT`` 4, ``ERRBIT_OVERELE`` 8,
    ``ERRBIT_OVERLOAD`` 32). Byte order little endian (the SDK's ``SCS_END = 0`` for STS).
    Dynamixel XM430-W350 / XL430-W250: ROBOTIS e-Manual control tables (ROBOTIS-GIT/emanual,
    ``docs/en/dxl/x/xm430-w350.md``, ``xl430-w250.md``); values are little endian, signed values
    two's complement.

Angles: a servo's position register counts encoder ticks, ``resolution`` per output turn, with
``resolution / 2`` (2048 of 4096) at 0 rad (the middle of the servo's single-turn range).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

#: Register encodings: unsigned, two's complement, or sign-magnitude with the sign at bit ``n``.
UNSIGNED, TWOS_COMPLEMENT = "unsigned", "twos"


@dataclass(frozen=True)
class Register:
    """One register of a control table.

    Attributes:
        name: Register name (LeRobot's / the e-Manual's spelling with underscores).
        address: Byte address in the control table.
        size: Bytes (1, 2 or 4), little endian.
        default: Factory value (raw register units).
        writable: False for read-only (feedback) registers.
        eeprom: True for the EEPROM area (Dynamixel: writable only with torque off).
        encoding: ``UNSIGNED``, ``TWOS_COMPLEMENT`` or ``"sign_magnitude:<bit>"``.
        unit: Unit of one count, for people.
    """

    name: str
    address: int
    size: int
    default: int = 0
    writable: bool = True
    eeprom: bool = False
    encoding: str = UNSIGNED
    unit: str = ""

    def encode(self, value: int) -> bytes:
        """``value`` (a signed integer in register counts) as the register's bytes.

        Raises:
            ValueError: the value does not fit the register.
        """
        value = int(value)
        bits = 8 * self.size
        if self.encoding == TWOS_COMPLEMENT:
            if not -(1 << (bits - 1)) <= value < (1 << (bits - 1)):
                raise ValueError(f"{self.name}: {value} does not fit {bits} signed bits")
            raw = value & ((1 << bits) - 1)
        elif self.encoding.startswith("sign_magnitude:"):
            raw = encode_sign_magnitude(value, int(self.encoding.split(":")[1]))
        else:
            if not 0 <= value < (1 << bits):
                raise ValueError(f"{self.name}: {value} does not fit {bits} unsigned bits")
            raw = value
        return raw.to_bytes(self.size, "little")

    def decode(self, data: bytes) -> int:
        """The register's bytes (``size`` of them, little endian) as a signed integer."""
        raw = int.from_bytes(bytes(data[: self.size]), "little")
        if self.encoding == TWOS_COMPLEMENT:
            bits = 8 * self.size
            return raw - (1 << bits) if raw & (1 << (bits - 1)) else raw
        if self.encoding.startswith("sign_magnitude:"):
            return decode_sign_magnitude(raw, int(self.encoding.split(":")[1]))
        return raw


def encode_sign_magnitude(value: int, sign_bit: int) -> int:
    """Feetech's negative numbers: ``|value|`` with bit ``sign_bit`` set when negative
    (``scservo_sdk.SCS_TOSCS``).

    Raises:
        ValueError: ``|value|`` needs the sign bit or more.
    """
    magnitude = abs(int(value))
    if magnitude >= 1 << sign_bit:
        raise ValueError(f"|{value}| does not fit below sign bit {sign_bit}")
    return magnitude | (1 << sign_bit) if value < 0 else magnitude


def decode_sign_magnitude(raw: int, sign_bit: int) -> int:
    """Inverse of :func:`encode_sign_magnitude` (``scservo_sdk.SCS_TOHOST``)."""
    return -(raw & ~(1 << sign_bit)) if raw & (1 << sign_bit) else raw


@dataclass(frozen=True)
class ServoModel:
    """A servo model: its protocol, identity, control table and the units of its registers.

    Attributes:
        name: Motor catalog name (``sim2real/robots/motors/<name>.toml``).
        protocol: ``"feetech"`` (SCS/STS protocol) or ``"dynamixel"`` (Protocol 2.0).
        model_number: Value of the Model_Number register.
        firmware: Firmware version the emulator reports.
        registers: The control table.
        resolution: Encoder ticks per output turn (datasheet).
        velocity_unit: rad/s per count of the velocity registers.
        current_unit: A per count of the current registers (None: the model has none).
        load_unit: Fraction of the peak torque per count of a load register (None: none).
        voltage_unit: V per count of the present voltage register.
        return_delay_unit: s per count of Return_Delay_Time.
        baud_codes: Baud_Rate register value of each baud rate (bit/s).
        error_bits: Bit of each fault in the servo's error report (Feetech: the status packet's
            error byte; Dynamixel: Hardware_Error_Status): keys ``voltage``, ``overheat``,
            ``overload`` (and others the model has).
        operating_modes: Operating_Mode register value of the plant control modes it supports.
        torque_off_on: Faults after which the servo switches its torque off by itself.
        names: The register names of the common quantities (keys ``goal_position``,
            ``goal_velocity``, ``present_position``, ``present_velocity``, ``present_current``
            or ``present_load``, ``present_voltage``, ``present_temperature``, ``torque_enable``,
            ``operating_mode``, ``temperature_limit``, ``return_delay``, ``status_return``,
            ``min_position``, ``max_position``, ``moving``, ``id``, ``baud_rate``).
    """

    name: str
    protocol: str
    model_number: int
    firmware: int
    registers: tuple[Register, ...]
    resolution: int
    velocity_unit: float
    current_unit: float | None
    load_unit: float | None
    voltage_unit: float
    return_delay_unit: float
    baud_codes: Mapping[int, int]
    error_bits: Mapping[str, int]
    operating_modes: Mapping[str, int]
    torque_off_on: tuple[str, ...]
    names: Mapping[str, str]
    _by_name: dict[str, Register] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_name", {r.name: r for r in self.registers})

    @property
    def memory_size(self) -> int:
        """Bytes of control table the emulator keeps (past the last register)."""
        return max(r.address + r.size for r in self.registers)

    def register(self, name: str) -> Register:
        """The register ``name`` or the register of a common quantity (``names`` key).

        Raises:
            KeyError: the model has no such register.
        """
        name = self.names.get(name, name)
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"{self.name} has no register '{name}'") from None

    def has(self, name: str) -> bool:
        """Whether the model has register ``name`` (or the common quantity ``name``)."""
        return self.names.get(name, name) in self._by_name

    # -------------------------------------------------------------- conversions
    @staticmethod
    def rad_to_ticks(angle: float, resolution: int) -> int:
        """Angle (rad, 0 at the middle of the range) -> position register (ticks, nearest)."""
        return int(round(angle * resolution / (2.0 * math.pi))) + resolution // 2

    @staticmethod
    def ticks_to_rad(ticks: int, resolution: int) -> float:
        """Position register (ticks) -> angle (rad, 0 at ``resolution / 2`` ticks)."""
        return (ticks - resolution // 2) * 2.0 * math.pi / resolution

    def velocity_to_counts(self, velocity: float) -> int:
        """Joint velocity (rad/s) -> velocity register counts (nearest)."""
        return int(round(velocity / self.velocity_unit))

    def counts_to_velocity(self, counts: int) -> float:
        """Velocity register counts -> rad/s."""
        return counts * self.velocity_unit


_TWO_PI = 2.0 * math.pi
_FEETECH_ERRORS = {"voltage": 1, "angle": 2, "overheat": 4, "overcurrent": 8, "overload": 32}
#: Hardware_Error_Status bits (e-Manual "Shutdown(63)"): 0 input voltage, 2 overheating,
#: 3 motor encoder, 4 electrical shock, 5 overload.
_DYNAMIXEL_ERRORS = {
    "voltage": 1,
    "overheat": 4,
    "encoder": 8,
    "electrical_shock": 16,
    "overload": 32,
}
#: Protocol 2.0 status packet error byte: bit 7 "Alert" (Hardware_Error_Status is not 0),
#: bits 0-6 an error number (e-Manual, Protocol 2.0 "Status Packet").
DYNAMIXEL_ALERT = 0x80
DYNAMIXEL_ERRNUM = {
    "result_fail": 1,
    "instruction": 2,
    "crc": 3,
    "data_range": 4,
    "data_length": 5,
    "data_limit": 6,
    "access": 7,
}


def _baud_codes(*rates: int) -> dict[int, int]:
    """bit/s -> Baud_Rate code, the rates given in code order (0, 1, 2, ...)."""
    return {rate: code for code, rate in enumerate(rates)}


#: Our register names -> the control table's, where Feetech's and the e-Manual's spellings agree.
_COMMON_NAMES = {
    "id": "ID",
    "baud_rate": "Baud_Rate",
    "return_delay": "Return_Delay_Time",
    "min_position": "Min_Position_Limit",
    "max_position": "Max_Position_Limit",
    "operating_mode": "Operating_Mode",
    "torque_enable": "Torque_Enable",
    "goal_position": "Goal_Position",
    "goal_velocity": "Goal_Velocity",
    "present_position": "Present_Position",
    "present_velocity": "Present_Velocity",
    "present_temperature": "Present_Temperature",
    "moving": "Moving",
}

_R = Register
_STS_SM15 = "sign_magnitude:15"
STS3215 = ServoModel(
    name="sts3215",
    protocol="feetech",
    model_number=777,  # LeRobot MODEL_NUMBER_TABLE["sts3215"]
    firmware=3,
    registers=(
        _R("Firmware_Major_Version", 0, 1, 3, writable=False, eeprom=True),
        _R("Firmware_Minor_Version", 1, 1, 10, writable=False, eeprom=True),
        _R("Model_Number", 3, 2, 777, writable=False, eeprom=True),
        _R("ID", 5, 1, 1, eeprom=True),
        _R("Baud_Rate", 6, 1, 0, eeprom=True, unit="code: 0 = 1 Mbit/s"),
        # LeRobot (feetech.py, configure_motors): "By default, Feetech motors have a 500 us delay
        # response time (a value of 250)"; Feetech's STS memory table lists address 7 as reserved.
        _R("Return_Delay_Time", 7, 1, 250, eeprom=True, unit="2 us"),
        _R("Response_Status_Level", 8, 1, 1, eeprom=True, unit="0: PING/READ only, 1: all"),
        _R("Min_Position_Limit", 9, 2, 0, eeprom=True, unit="tick"),
        _R("Max_Position_Limit", 11, 2, 4095, eeprom=True, unit="tick"),
        _R("Max_Temperature_Limit", 13, 1, 70, eeprom=True, unit="degC"),
        # Defaults of addresses 14-27 and 30: our guesses, NOT from a datasheet (the emulator only
        # reports them; read them back from your servo before relying on them).
        _R("Max_Voltage_Limit", 14, 1, 140, eeprom=True, unit="0.1 V"),
        _R("Min_Voltage_Limit", 15, 1, 40, eeprom=True, unit="0.1 V"),
        _R("Max_Torque_Limit", 16, 2, 1000, eeprom=True, unit="0.1 %"),
        _R("Phase", 18, 1, 0, eeprom=True),
        _R("Unloading_Condition", 19, 1, 44, eeprom=True, unit="error bits that cut torque"),
        _R("LED_Alarm_Condition", 20, 1, 47, eeprom=True),
        _R("P_Coefficient", 21, 1, 32, eeprom=True),
        _R("D_Coefficient", 22, 1, 32, eeprom=True),
        _R("I_Coefficient", 23, 1, 0, eeprom=True),
        _R("Minimum_Startup_Force", 24, 2, 16, eeprom=True),
        _R("CW_Dead_Zone", 26, 1, 1, eeprom=True),
        _R("CCW_Dead_Zone", 27, 1, 1, eeprom=True),
        # 28, 34-36: sim2real/robots/motors/sts3215.toml [protection] (also recalled, not re-read).
        _R("Protection_Current", 28, 2, 500, eeprom=True, unit="6.5 mA"),
        _R("Angular_Resolution", 30, 1, 1, eeprom=True),
        _R("Homing_Offset", 31, 2, 0, eeprom=True, encoding="sign_magnitude:11", unit="tick"),
        _R("Operating_Mode", 33, 1, 0, eeprom=True, unit="0 position, 1 velocity"),
        _R("Protective_Torque", 34, 1, 20, eeprom=True, unit="%"),
        _R("Protection_Time", 35, 1, 200, eeprom=True, unit="10 ms"),
        _R("Overload_Torque", 36, 1, 80, eeprom=True, unit="%"),
        _R("Torque_Enable", 40, 1, 0),
        _R("Acceleration", 41, 1, 0, unit="100 step/s^2"),
        _R("Goal_Position", 42, 2, 0, encoding=_STS_SM15, unit="tick"),
        _R("Goal_Time", 44, 2, 0, unit="ms"),
        _R("Goal_Velocity", 46, 2, 0, encoding=_STS_SM15, unit="step/s"),
        _R("Torque_Limit", 48, 2, 1000, unit="0.1 %"),
        _R("Lock", 55, 1, 0),
        _R("Present_Position", 56, 2, 0, writable=False, encoding=_STS_SM15, unit="tick"),
        _R("Present_Velocity", 58, 2, 0, writable=False, encoding=_STS_SM15, unit="step/s"),
        _R("Present_Load", 60, 2, 0, writable=False, encoding="sign_magnitude:10", unit="0.1 %"),
        _R("Present_Voltage", 62, 1, 120, writable=False, unit="0.1 V"),
        _R("Present_Temperature", 63, 1, 25, writable=False, unit="degC"),
        _R("Status", 65, 1, 0, writable=False, unit="error bits"),
        _R("Moving", 66, 1, 0, writable=False),
        _R("Present_Current", 69, 2, 0, writable=False, encoding=_STS_SM15, unit="6.5 mA"),
    ),
    resolution=4096,
    velocity_unit=_TWO_PI / 4096,  # 1 step/s (Feetech SDK examples: speed in step/s)
    current_unit=0.0065,  # 6.5 mA per count (Feetech memory table)
    load_unit=0.001,  # 0.1 % of the maximum torque per count
    voltage_unit=0.1,
    return_delay_unit=2e-6,
    # Feetech STS memory table, address 6 (LeRobot's table has 57600 at 5 and 38400 at 6).
    baud_codes=_baud_codes(1_000_000, 500_000, 250_000, 128_000, 115_200, 76_800, 57_600, 38_400),
    error_bits=_FEETECH_ERRORS,
    operating_modes={"position": 0, "velocity": 1},
    # Unloading_Condition (19): which error bits cut the torque. We assume overheat and overload
    # (the real default is not verified here; read it back from your servo).
    torque_off_on=("overheat", "overload"),
    names={
        **_COMMON_NAMES,
        "status_return": "Response_Status_Level",
        "temperature_limit": "Max_Temperature_Limit",
        "present_load": "Present_Load",
        "present_voltage": "Present_Voltage",
        "present_current": "Present_Current",
    },
)


def _dynamixel_x(
    name: str,
    model_number: int,
    temperature_limit: int,
    velocity_limit: int,
    max_voltage: int,
    min_voltage: int,
    current: bool,
) -> ServoModel:
    """A Dynamixel X-series (Protocol 2.0) model: the e-Manual control table (see module)."""
    eeprom = [
        _R("Model_Number", 0, 2, model_number, writable=False, eeprom=True),
        _R("Model_Information", 2, 4, 0, writable=False, eeprom=True),
        _R("Firmware_Version", 6, 1, 46, writable=False, eeprom=True),
        _R("ID", 7, 1, 1, eeprom=True),
        _R("Baud_Rate", 8, 1, 1, eeprom=True, unit="code: 1 = 57600, 3 = 1 Mbit/s"),
        _R("Return_Delay_Time", 9, 1, 250, eeprom=True, unit="2 us"),
        _R("Drive_Mode", 10, 1, 0, eeprom=True),
        _R("Operating_Mode", 11, 1, 3, eeprom=True, unit="1 velocity, 3 position"),
        _R("Secondary_ID", 12, 1, 255, eeprom=True),
        _R("Protocol_Type", 13, 1, 2, eeprom=True),
        _R("Homing_Offset", 20, 4, 0, eeprom=True, encoding=TWOS_COMPLEMENT, unit="tick"),
        _R("Moving_Threshold", 24, 4, 10, eeprom=True, unit="0.229 rpm"),
        _R("Temperature_Limit", 31, 1, temperature_limit, eeprom=True, unit="degC"),
        _R("Max_Voltage_Limit", 32, 2, max_voltage, eeprom=True, unit="0.1 V"),
        _R("Min_Voltage_Limit", 34, 2, min_voltage, eeprom=True, unit="0.1 V"),
        _R("PWM_Limit", 36, 2, 885, eeprom=True, unit="0.113 %"),
        _R("Acceleration_Limit", 40, 4, 32767, eeprom=True, unit="214.577 rev/min^2"),
        _R("Velocity_Limit", 44, 4, velocity_limit, eeprom=True, unit="0.229 rpm"),
        _R("Max_Position_Limit", 48, 4, 4095, eeprom=True, unit="tick"),
        _R("Min_Position_Limit", 52, 4, 0, eeprom=True, unit="tick"),
        _R("Shutdown", 63, 1, 52, eeprom=True, unit="Hardware_Error_Status bits"),
    ]
    if current:
        eeprom.append(_R("Current_Limit", 38, 2, 1193, eeprom=True, unit="2.69 mA"))
    ram = [
        _R("Torque_Enable", 64, 1, 0),
        _R("LED", 65, 1, 0),
        _R("Status_Return_Level", 68, 1, 2, unit="0 PING, 1 PING+READ, 2 all"),
        _R("Registered_Instruction", 69, 1, 0, writable=False),
        _R("Hardware_Error_Status", 70, 1, 0, writable=False),
        _R("Velocity_I_Gain", 76, 2, 1920),
        _R("Velocity_P_Gain", 78, 2, 100),
        _R("Position_D_Gain", 80, 2, 0),
        _R("Position_I_Gain", 82, 2, 0),
        _R("Position_P_Gain", 84, 2, 800),
        _R("Feedforward_2nd_Gain", 88, 2, 0),
        _R("Feedforward_1st_Gain", 90, 2, 0),
        _R("Bus_Watchdog", 98, 1, 0),
        _R("Goal_PWM", 100, 2, 0, encoding=TWOS_COMPLEMENT),
        _R("Goal_Velocity", 104, 4, 0, encoding=TWOS_COMPLEMENT, unit="0.229 rpm"),
        _R("Profile_Acceleration", 108, 4, 0),
        _R("Profile_Velocity", 112, 4, 0),
        _R("Goal_Position", 116, 4, 0, encoding=TWOS_COMPLEMENT, unit="tick"),
        _R("Realtime_Tick", 120, 2, 0, writable=False, unit="ms"),
        _R("Moving", 122, 1, 0, writable=False),
        _R("Moving_Status", 123, 1, 0, writable=False),
        _R("Present_PWM", 124, 2, 0, writable=False, encoding=TWOS_COMPLEMENT),
        _R("Present_Velocity", 128, 4, 0, writable=False, encoding=TWOS_COMPLEMENT),
        _R("Present_Position", 132, 4, 0, writable=False, encoding=TWOS_COMPLEMENT),
        _R("Velocity_Trajectory", 136, 4, 0, writable=False, encoding=TWOS_COMPLEMENT),
        _R("Position_Trajectory", 140, 4, 0, writable=False, encoding=TWOS_COMPLEMENT),
        _R("Present_Input_Voltage", 144, 2, 120, writable=False, unit="0.1 V"),
        _R("Present_Temperature", 146, 1, 25, writable=False, unit="degC"),
    ]
    if current:
        ram.append(_R("Goal_Current", 102, 2, 0, encoding=TWOS_COMPLEMENT, unit="2.69 mA"))
        ram.append(
            _R(
                "Present_Current",
                126,
                2,
                0,
                writable=False,
                encoding=TWOS_COMPLEMENT,
                unit="2.69 mA",
            )
        )
    else:
        ram.append(
            _R("Present_Load", 126, 2, 0, writable=False, encoding=TWOS_COMPLEMENT, unit="0.1 %")
        )
    names = {
        **_COMMON_NAMES,
        "status_return": "Status_Return_Level",
        "temperature_limit": "Temperature_Limit",
        "present_voltage": "Present_Input_Voltage",
        "hardware_error": "Hardware_Error_Status",
        "velocity_limit": "Velocity_Limit",
    }
    names["present_current" if current else "present_load"] = (
        "Present_Current" if current else "Present_Load"
    )
    return ServoModel(
        name=name,
        protocol="dynamixel",
        model_number=model_number,
        firmware=46,
        registers=tuple(sorted(eeprom + ram, key=lambda r: r.address)),
        resolution=4096,
        velocity_unit=0.229 * _TWO_PI / 60.0,  # 0.229 rpm per count (e-Manual, Goal Velocity)
        current_unit=0.00269 if current else None,  # about 2.69 mA (e-Manual, Current Limit)
        load_unit=None if current else 0.001,  # 0.1 % (e-Manual XL430, Present Load)
        voltage_unit=0.1,
        return_delay_unit=2e-6,
        # e-Manual "Baud Rate(8)"
        baud_codes=_baud_codes(
            9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000
        ),
        error_bits=_DYNAMIXEL_ERRORS,
        operating_modes={"velocity": 1, "position": 3},
        torque_off_on=("overheat", "electrical_shock", "overload"),  # Shutdown (63) default 52
        names=names,
    )


#: e-Manual XM430-W350: model 1020, Temperature Limit 80, Velocity Limit 350 (e-Manual table
#: above; 265 on older firmware), voltage limits 160 / 95.
XM430_W350 = _dynamixel_x("xm430_w350", 1020, 80, 350, 160, 95, current=True)
#: e-Manual XL430-W250: model 1060, Temperature Limit 72, Velocity Limit 265, voltage limits
#: 140 / 60, Present Load instead of Present Current.
XL430_W250 = _dynamixel_x("xl430_w250", 1060, 72, 265, 140, 60, current=False)

#: Servo models by motor catalog name (``sim2real/robots/motors/<name>.toml``).
MODELS: dict[str, ServoModel] = {m.name: m for m in (STS3215, XM430_W350, XL430_W250)}


def model_for_motor(motor: str) -> ServoModel:
    """The servo model of motor catalog entry ``motor``.

    Raises:
        KeyError: the motor is not a serial-bus servo we know (names the known ones).
    """
    try:
        return MODELS[motor]
    except KeyError:
        raise KeyError(
            f"motor '{motor}' is not a serial-bus servo with a known control table "
            f"(known: {sorted(MODELS)})"
        ) from None
