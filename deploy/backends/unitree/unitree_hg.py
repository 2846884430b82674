"""The ``unitree_hg`` low-level messages (G1, H1-2) as Cyclone DDS IDL types.

Written from Unitree's public IDL (``unitree_hg/msg/LowCmd_.idl`` and its members, as the
unitree_sdk2 and unitree_sdk2_python packages ship them): the same type names
(``unitree_hg::msg::dds_::LowCmd_``), members, order and types; ``@final``, XCDR1. ``mode_pr``
chooses the ankles' and waist's series (pitch/roll, 0) or parallel (A/B, 1) control;
``mode_machine`` is the robot's type as its LowState_ reports it, echoed in every command.

Units: rad, rad/s, N m, degC. Every field defaults to zero.
"""

# no ``from __future__ import annotations``: Cyclone DDS reads the member types at run time
from dataclasses import dataclass, field

import cyclonedds.idl.types as types
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import autoid, final

#: Motor slots in a ``unitree_hg`` LowCmd_ / LowState_ (29 used on a G1, 27 on an H1-2).
MOTORS = 35


def _zeros(n: int):
    return field(default_factory=lambda: [0] * n)


@dataclass
@final
@autoid("sequential")
class MotorCmd_(IdlStruct, typename="unitree_hg.msg.dds_.MotorCmd_"):
    """One motor's command (``mode`` 1 enable, 0 disable), PD on its driver."""

    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    tau: types.float32 = 0.0
    kp: types.float32 = 0.0
    kd: types.float32 = 0.0
    reserve: types.uint32 = 0


@dataclass
@final
@autoid("sequential")
class LowCmd_(IdlStruct, typename="unitree_hg.msg.dds_.LowCmd_"):
    """The low-level command on ``rt/lowcmd``; ``crc`` over the rest (:mod:`.crc`)."""

    mode_pr: types.uint8 = 0
    mode_machine: types.uint8 = 0
    motor_cmd: types.array[MotorCmd_, MOTORS] = field(
        default_factory=lambda: [MotorCmd_() for _ in range(MOTORS)]
    )
    reserve: types.array[types.uint32, 4] = _zeros(4)
    crc: types.uint32 = 0


@dataclass
@final
@autoid("sequential")
class MotorState_(IdlStruct, typename="unitree_hg.msg.dds_.MotorState_"):
    """One motor's state: ``q`` rad, ``dq`` rad/s, ``tau_est`` N m, ``temperature`` degC (two
    sensors), ``vol`` V, ``motorstate`` the driver's state and error bits."""

    mode: types.uint8 = 0
    q: types.float32 = 0.0
    dq: types.float32 = 0.0
    ddq: types.float32 = 0.0
    tau_est: types.float32 = 0.0
    temperature: types.array[types.int16, 2] = _zeros(2)
    vol: types.float32 = 0.0
    sensor: types.array[types.uint32, 2] = _zeros(2)
    motorstate: types.uint32 = 0
    reserve: types.array[types.uint32, 4] = _zeros(4)


@dataclass
@final
@autoid("sequential")
class IMUState_(IdlStruct, typename="unitree_hg.msg.dds_.IMUState_"):
    """``quaternion`` (w, x, y, z), ``gyroscope`` rad/s, ``accelerometer`` m/s^2, ``rpy`` rad."""

    quaternion: types.array[types.float32, 4] = _zeros(4)
    gyroscope: types.array[types.float32, 3] = _zeros(3)
    accelerometer: types.array[types.float32, 3] = _zeros(3)
    rpy: types.array[types.float32, 3] = _zeros(3)
    temperature: types.int16 = 0


@dataclass
@final
@autoid("sequential")
class LowState_(IdlStruct, typename="unitree_hg.msg.dds_.LowState_"):
    """The low-level state on ``rt/lowstate``: ``mode_pr``, ``mode_machine``, ``tick`` (ms),
    IMU, one :class:`MotorState_` per motor slot, ``crc`` over the rest."""

    version: types.array[types.uint32, 2] = _zeros(2)
    mode_pr: types.uint8 = 0
    mode_machine: types.uint8 = 0
    tick: types.uint32 = 0
    imu_state: IMUState_ = field(default_factory=IMUState_)
    motor_state: types.array[MotorState_, MOTORS] = field(
        default_factory=lambda: [MotorState_() for _ in range(MOTORS)]
    )
    wireless_remote: types.array[types.uint8, 40] = _zeros(40)
    reserve: types.array[types.uint32, 4] = _zeros(4)
    crc: types.uint32 = 0
