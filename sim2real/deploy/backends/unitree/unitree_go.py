"""The ``unitree_go`` low-level messages (Go2, Go1, B2, H1) as Cyclone DDS IDL types.

Written from Unitree's public IDL (``unitree_go/msg/LowCmd_.idl`` and its members, as the
unitree_sdk2 and unitree_sdk2_python packages ship them): the same type names
(``unitree_go::msg::dds_::LowCmd_``), the same members in the same order and of the same types,
so that Unitree's tools and robots read our messages and we read theirs. ``@final`` structs,
serialised as XCDR1 (plain CDR, little endian), as Unitree's own types; built from the member
tables below by :class:`sim2real.deploy.backends.unitree.idl.Package`.

Units as the robot reports them: rad, rad/s, N m, degC; ``foot_force`` in the sensor's raw
counts. Every field defaults to zero (arrays to zeros of their length).
"""

# no ``from __future__ import annotations``: Cyclone DDS reads the member types at run time
import cyclonedds.idl.types as types

from sim2real.deploy.backends.unitree.idl import IMU, IMU_DOC, MOTOR_CMD, MOTOR_STATE, Package

#: Motor slots in a ``unitree_go`` LowCmd_ / LowState_ (the robot uses the first 12 on a Go2).
MOTORS = 20

_go = Package("unitree_go", __name__)
u8, u16, u32, f32 = types.uint8, types.uint16, types.uint32, types.float32
arr = types.array

#: The members a LowCmd_ and a LowState_ start with.
_HEADER = (
    ("head", arr[u8, 2]),
    ("level_flag", u8),
    ("frame_reserve", u8),
    ("sn", arr[u32, 2]),
    ("version", arr[u32, 2]),
    ("bandwidth", u16),
)

MotorCmd_ = _go.struct(
    "MotorCmd_",
    [*MOTOR_CMD, ("reserve", arr[u32, 3])],
    """One motor's command: ``tau = tau + kp (q - q_m) + kd (dq - dq_m)`` on its driver.
    ``mode``: 0x01 servo (FOC) on, 0x00 off.""",
)
BmsCmd_ = _go.struct("BmsCmd_", [("off", u8), ("reserve", arr[u8, 3])])
LowCmd_ = _go.struct(
    "LowCmd_",
    [
        *_HEADER,
        ("motor_cmd", arr[MotorCmd_, MOTORS]),
        ("bms_cmd", BmsCmd_),
        ("wireless_remote", arr[u8, 40]),
        ("led", arr[u8, 12]),
        ("fan", arr[u8, 2]),
        ("gpio", u8),
        ("reserve", u32),
        ("crc", u32),
    ],
    """The low-level command on ``rt/lowcmd``: ``head`` 0xFE 0xEF, ``level_flag`` 0xFF (low
    level), one :class:`MotorCmd_` per motor slot, ``crc`` over the rest (:mod:`.crc`).""",
)
MotorState_ = _go.struct(
    "MotorState_",
    [
        *MOTOR_STATE,
        ("q_raw", f32),
        ("dq_raw", f32),
        ("ddq_raw", f32),
        ("temperature", u8),
        ("lost", u32),
        ("reserve", arr[u32, 2]),
    ],
    """One motor's state: ``q`` rad, ``dq`` rad/s, ``tau_est`` N m, ``temperature`` degC,
    ``lost`` the packets lost between the board and the motor (a running count).""",
)
IMUState_ = _go.struct("IMUState_", [*IMU, ("temperature", u8)], IMU_DOC)
BmsState_ = _go.struct(
    "BmsState_",
    [
        ("version_high", u8),
        ("version_low", u8),
        ("status", u8),
        ("soc", u8),
        ("current", types.int32),
        ("cycle", u16),
        ("bq_ntc", arr[u8, 2]),
        ("mcu_ntc", arr[u8, 2]),
        ("cell_vol", arr[u16, 15]),
    ],
)
LowState_ = _go.struct(
    "LowState_",
    [
        *_HEADER,
        ("imu_state", IMUState_),
        ("motor_state", arr[MotorState_, MOTORS]),
        ("bms_state", BmsState_),
        ("foot_force", arr[types.int16, 4]),
        ("foot_force_est", arr[types.int16, 4]),
        ("tick", u32),
        ("wireless_remote", arr[u8, 40]),
        ("bit_flag", u8),
        ("adc_reel", f32),
        ("temperature_ntc1", u8),
        ("temperature_ntc2", u8),
        ("power_v", f32),
        ("power_a", f32),
        ("fan_frequency", arr[u16, 4]),
        ("reserve", u32),
        ("crc", u32),
    ],
    """The low-level state on ``rt/lowstate``: IMU, one :class:`MotorState_` per motor slot,
    ``foot_force`` (raw counts), ``tick`` (ms, the board's clock), ``crc`` over the rest.""",
)
WirelessController_ = _go.struct(
    "WirelessController_",
    [("lx", f32), ("ly", f32), ("rx", f32), ("ry", f32), ("keys", u16)],
    """The wireless remote's state on ``rt/wirelesscontroller`` (unitree_sdk2's
    ``WirelessController_.idl``): the sticks in [-1, 1] (up and right positive) and the 16 button
    bits of LowState's ``wireless_remote`` (:mod:`sim2real.deploy.backends.unitree.remote`).""",
)
