"""The ``unitree_hg`` low-level messages (G1, H1-2) as Cyclone DDS IDL types.

Written from Unitree's public IDL (``unitree_hg/msg/LowCmd_.idl`` and its members, as the
unitree_sdk2 and unitree_sdk2_python packages ship them): the same type names
(``unitree_hg::msg::dds_::LowCmd_``), members, order and types; ``@final``, XCDR1; built from the
member tables below by :class:`sim2real.deploy.backends.unitree.idl.Package`. ``mode_pr`` chooses the
ankles' and waist's series (pitch/roll, 0) or parallel (A/B, 1) control; ``mode_machine`` is the
robot's type as its LowState_ reports it, echoed in every command.

Units: rad, rad/s, N m, degC. Every field defaults to zero.
"""

# no ``from __future__ import annotations``: Cyclone DDS reads the member types at run time
import cyclonedds.idl.types as types

from sim2real.deploy.backends.unitree.idl import IMU, IMU_DOC, MOTOR_CMD, MOTOR_STATE, Package

#: Motor slots in a ``unitree_hg`` LowCmd_ / LowState_ (29 used on a G1, 27 on an H1-2).
MOTORS = 35

_hg = Package("unitree_hg", __name__)
u8, u32, arr = types.uint8, types.uint32, types.array

#: The members a LowCmd_ and a LowState_ end with.
_TRAILER = (("reserve", arr[u32, 4]), ("crc", u32))
_MODES = (("mode_pr", u8), ("mode_machine", u8))

MotorCmd_ = _hg.struct(
    "MotorCmd_",
    [*MOTOR_CMD, ("reserve", u32)],
    """One motor's command (``mode`` 1 enable, 0 disable), PD on its driver.""",
)
LowCmd_ = _hg.struct(
    "LowCmd_",
    [*_MODES, ("motor_cmd", arr[MotorCmd_, MOTORS]), *_TRAILER],
    """The low-level command on ``rt/lowcmd``; ``crc`` over the rest (:mod:`.crc`).""",
)
MotorState_ = _hg.struct(
    "MotorState_",
    [
        *MOTOR_STATE,
        ("temperature", arr[types.int16, 2]),
        ("vol", types.float32),
        ("sensor", arr[u32, 2]),
        ("motorstate", u32),
        ("reserve", arr[u32, 4]),
    ],
    """One motor's state: ``q`` rad, ``dq`` rad/s, ``tau_est`` N m, ``temperature`` degC (two
    sensors), ``vol`` V, ``motorstate`` the driver's state and error bits.""",
)
IMUState_ = _hg.struct("IMUState_", [*IMU, ("temperature", types.int16)], IMU_DOC)
LowState_ = _hg.struct(
    "LowState_",
    [
        ("version", arr[u32, 2]),
        *_MODES,
        ("tick", u32),
        ("imu_state", IMUState_),
        ("motor_state", arr[MotorState_, MOTORS]),
        ("wireless_remote", arr[u8, 40]),
        *_TRAILER,
    ],
    """The low-level state on ``rt/lowstate``: ``mode_pr``, ``mode_machine``, ``tick`` (ms),
    IMU, one :class:`MotorState_` per motor slot, ``crc`` over the rest.""",
)
