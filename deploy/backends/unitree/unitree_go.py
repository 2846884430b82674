"""The ``unitree_go`` low-level messages (Go2, Go1, B2, H1) as Cyclone DDS IDL types.

Written from Unitree's public IDL (``unitree_go/msg/LowCmd_.idl`` and its members, as the
unitree_sdk2 and unitree_sdk2_python packages ship them): the same type names
(``unitree_go::msg::dds_::LowCmd_``), the same members in the same order and of the same types,
so that Unitree's tools and robots read our messages and we read theirs. ``@final`` structs,
serialised as XCDR1 (plain CDR, little endian), as Unitree's own types.

Units as the robot reports them: rad, rad/s, N m, degC; ``foot_force`` in the sensor's raw
counts. Every field defaults to zero (arrays to zeros of their length).
"""

# no ``from __future__ import annotations``: Cyclone DDS reads the member types at run time
from dataclasses import dataclass, field

import cyclonedds.idl.types as types
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import autoid, final

#: Motor slots in a ``unitree_go`` LowCmd_ / LowState_ (the robot uses the first 12 on a Go2).
MOTORS = 20


def _zeros(n: int):
    return field(default_factory=lambda: [0] * n)


@dataclass
@final
@autoid("sequential")
class MotorCmd_(IdlStruct, typename="unitree_go.msg.dds_.MotorCmd_"):
    """One motor's command: ``tau = tau + kp (q - q_m) + kd (dq - dq_m)`` on its driver.
    ``mode``: 0x01 servo (FOC) on, 0x00 off."""

    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    tau: types.float32 = 0.0
    kp: types.float32 = 0.0
    kd: types.float32 = 0.0
    reserve: types.array[types.uint32, 3] = _zeros(3)


@dataclass
@final
@autoid("sequential")
class BmsCmd_(IdlStruct, typename="unitree_go.msg.dds_.BmsCmd_"):
    off: types.uint8 = 0
    reserve: types.array[types.uint8, 3] = _zeros(3)


@dataclass
@final
@autoid("sequential")
class LowCmd_(IdlStruct, typename="unitree_go.msg.dds_.LowCmd_"):
    """The low-level command on ``rt/lowcmd``: ``head`` 0xFE 0xEF, ``level_flag`` 0xFF (low
    level), one :class:`MotorCmd_` per motor slot, ``crc`` over the rest (:mod:`.crc`)."""

    head: types.array[types.uint8, 2] = _zeros(2)
    level_flag: types.uint8 = 0
    frame_reserve: types.uint8 = 0
    sn: types.array[types.uint32, 2] = _zeros(2)
    version: types.array[types.uint32, 2] = _zeros(2)
    bandwidth: types.uint16 = 0
    motor_cmd: types.array[MotorCmd_, MOTORS] = field(
        default_factory=lambda: [MotorCmd_() for _ in range(MOTORS)]
    )
    bms_cmd: BmsCmd_ = field(default_factory=BmsCmd_)
    wireless_remote: types.array[types.uint8, 40] = _zeros(40)
    led: types.array[types.uint8, 12] = _zeros(12)
    fan: types.array[types.uint8, 2] = _zeros(2)
    gpio: types.uint8 = 0
    reserve: types.uint32 = 0
    crc: types.uint32 = 0


@dataclass
@final
@autoid("sequential")
class MotorState_(IdlStruct, typename="unitree_go.msg.dds_.MotorState_"):
    """One motor's state: ``q`` rad, ``dq`` rad/s, ``tau_est`` N m, ``temperature`` degC,
    ``lost`` the packets lost between the board and the motor (a running count)."""

    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    ddq: types.float32 = 0.0
    tau_est: types.float32 = 0.0
    q_raw: types.float32 = 0.0
    dq_raw: types.float32 = 0.0
    ddq_raw: types.float32 = 0.0
    temperature: types.uint8 = 0
    lost: types.uint32 = 0
    reserve: types.array[types.uint32, 2] = _zeros(2)


@dataclass
@final
@autoid("sequential")
class IMUState_(IdlStruct, typename="unitree_go.msg.dds_.IMUState_"):
    """``quaternion`` (w, x, y, z), ``gyroscope`` rad/s, ``accelerometer`` m/s^2, ``rpy`` rad."""

    quaternion: types.array[types.float32, 4] = _zeros(4)
    gyroscope: types.array[types.float32, 3] = _zeros(3)
    accelerometer: types.array[types.float32, 3] = _zeros(3)
    rpy: types.array[types.float32, 3] = _zeros(3)
    temperature: types.uint8 = 0


@dataclass
@final
@autoid("sequential")
class BmsState_(IdlStruct, typename="unitree_go.msg.dds_.BmsState_"):
    version_high: types.uint8 = 0
    version_low: types.uint8 = 0
    status: types.uint8 = 0
    soc: types.uint8 = 0
    current: types.int32 = 0
    cycle: types.uint16 = 0
    bq_ntc: types.array[types.uint8, 2] = _zeros(2)
    mcu_ntc: types.array[types.uint8, 2] = _zeros(2)
    cell_vol: types.array[types.uint16, 15] = _zeros(15)


@dataclass
@final
@autoid("sequential")
class LowState_(IdlStruct, typename="unitree_go.msg.dds_.LowState_"):
    """The low-level state on ``rt/lowstate``: IMU, one :class:`MotorState_` per motor slot,
    ``foot_force`` (raw counts), ``tick`` (ms, the board's clock), ``crc`` over the rest."""

    head: types.array[types.uint8, 2] = _zeros(2)
    level_flag: types.uint8 = 0
    frame_reserve: types.uint8 = 0
    sn: types.array[types.uint32, 2] = _zeros(2)
    version: types.array[types.uint32, 2] = _zeros(2)
    bandwidth: types.uint16 = 0
    imu_state: IMUState_ = field(default_factory=IMUState_)
    motor_state: types.array[MotorState_, MOTORS] = field(
        default_factory=lambda: [MotorState_() for _ in range(MOTORS)]
    )
    bms_state: BmsState_ = field(default_factory=BmsState_)
    foot_force: types.array[types.int16, 4] = _zeros(4)
    foot_force_est: types.array[types.int16, 4] = _zeros(4)
    tick: types.uint32 = 0
    wireless_remote: types.array[types.uint8, 40] = _zeros(40)
    bit_flag: types.uint8 = 0
    adc_reel: types.float32 = 0.0
    temperature_ntc1: types.uint8 = 0
    temperature_ntc2: types.uint8 = 0
    power_v: types.float32 = 0.0
    power_a: types.float32 = 0.0
    fan_frequency: types.array[types.uint16, 4] = _zeros(4)
    reserve: types.uint32 = 0
    crc: types.uint32 = 0
