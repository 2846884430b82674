"""The Unitree low-level messages without a network: our IDL types against Cyclone DDS's own
serializer, the C layout the robot's CRC covers, the CRC against a reference written here from
its definition, the Go2's motor slots, the emulator's fault spelling.

The references are built here, independently of the code under test: a bitwise CRC from the
polynomial, the C structs packed with :mod:`struct` from the IDL's member list, messages built
field by field as Cyclone DDS objects and serialized by Cyclone DDS.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

pytest.importorskip("cyclonedds", reason="pip install '.[unitree]'")

from sim2real.deploy.backends.unitree import unitree_go, unitree_hg  # noqa: E402
from sim2real.deploy.backends.unitree.codec import MessageCodec  # noqa: E402
from sim2real.deploy.backends.unitree.crc import crc32_words, message_crc  # noqa: E402
from sim2real.deploy.backends.unitree.emulator.faults import EmulatorFaults, parse_fault  # noqa: E402
from sim2real.deploy.backends.unitree.layout import c_dtype  # noqa: E402
from tests.unitree_reference import (  # noqa: E402
    crc_bitwise,
    go_lowcmd_c_struct,
    go_lowcmd_object,
    le_words,
    mpeg2_bytes,
)


def test_crc_matches_a_bitwise_reference_and_the_mpeg2_catalogue():
    assert mpeg2_bytes(b"123456789") == 0x0376E6E7  # the reference itself, against the catalogue
    # a word fed MSB first is its four bytes fed big-endian: the robot's CRC of the little-endian
    # words of b"4321" b"8765" is CRC-32/MPEG-2 of "12345678"
    assert crc32_words(b"43218765") == mpeg2_bytes(b"12345678")
    rng = np.random.default_rng(7)
    for data in (b"\x00" * 4, b"\xff" * 8, bytes(range(64)), rng.bytes(812), rng.bytes(2092)):
        assert crc32_words(data) == crc_bitwise(le_words(data)), len(data)
    # not the reflected CRC-32 of zlib on the same bytes (a plausible wrong implementation)
    assert crc32_words(bytes(range(64))) != zlib.crc32(bytes(range(64)))
    with pytest.raises(ValueError, match="32-bit words"):
        crc32_words(b"abc")


def test_lowcmd_is_byte_identical_to_cyclone_dds_and_its_crc_covers_the_c_struct():
    rng = np.random.default_rng(3)
    motors = [
        (1, *(float(np.float32(v)) for v in rng.normal(size=5))) if i < 12 else (0, 0, 0, 0, 0, 0)
        for i in range(20)
    ]
    codec = MessageCodec(unitree_go.LowCmd_)
    m = codec.message
    m["head"], m["level_flag"], m["gpio"], m["reserve"] = (0xFE, 0xEF), 0xFF, 5, 77
    mc = m["motor_cmd"]
    for i, (mode, q, dq, tau, kp, kd) in enumerate(motors):
        mc[i]["mode"], mc[i]["q"], mc[i]["dq"], mc[i]["tau"] = mode, q, dq, tau
        mc[i]["kp"], mc[i]["kd"] = kp, kd
    wire = codec.encode()

    # the CRC: the reference CRC over the C struct packed here, the crc word excluded
    c_struct = go_lowcmd_c_struct((0xFE, 0xEF), 0xFF, motors, 5, 77, 0)
    assert len(c_struct) == 812 == c_dtype(unitree_go.LowCmd_).itemsize
    expected_crc = crc_bitwise(le_words(c_struct[:-4]))
    assert int(m["crc"]) == expected_crc
    assert codec.buffer.tobytes() == c_struct[:-4] + struct.pack("<I", expected_crc)

    # on the wire: Cyclone DDS's own serializer of the message built field by field
    built = go_lowcmd_object(motors, expected_crc, gpio=5, reserve=77)
    assert wire == built.serialize()
    assert wire[:4] == b"\x00\x01\x00\x00"  # XCDR1, little endian, as Unitree's types
    # and back: our decode of Cyclone DDS's bytes checks the CRC; one flipped byte fails it
    other = MessageCodec(unitree_go.LowCmd_)
    assert other.decode(built.serialize())
    assert np.array_equal(other.buffer, codec.buffer)
    damaged = bytearray(wire)
    damaged[40] ^= 0x10
    assert not other.decode(bytes(damaged))


@pytest.mark.parametrize(
    "cls, c_size",
    [  # the C struct sizes unitree_sdk2_python's utils/crc.py packs
        (unitree_go.LowCmd_, 812),
        (unitree_go.LowState_, 1180),
        (unitree_hg.LowCmd_, 1004),
        (unitree_hg.LowState_, 2092),
    ],
)
def test_every_message_round_trips_through_cyclone_dds_bytes(cls, c_size):
    """Random values in every member: our encoding equals Cyclone DDS's serialization of the
    object Cyclone DDS decodes from it, and decodes back to the same record."""
    codec = MessageCodec(cls)
    assert codec.dtype.itemsize == c_size
    rng = np.random.default_rng(c_size)
    raw = rng.integers(0, 256, size=c_size, dtype=np.uint8)
    for name in codec.dtype.names:  # random bytes, then sane floats (NaN != NaN)
        codec.message[name] = np.frombuffer(raw.tobytes(), dtype=codec.dtype)[0][name]
    _finite(codec.message)
    wire = codec.encode()
    obj = cls.deserialize(wire)
    assert obj.serialize() == wire
    assert obj.crc == message_crc(codec.buffer)
    back = MessageCodec(cls)
    assert back.decode(obj.serialize())
    assert back.buffer.tobytes() == _without_padding(codec)


def _finite(record) -> None:
    for name in record.dtype.names:
        field = record[name]
        if field.dtype.names:
            _finite(field)
        elif field.dtype.kind == "f":
            field[...] = np.nan_to_num(field, nan=1.5, posinf=2.5, neginf=-2.5)


def _without_padding(codec: MessageCodec) -> bytes:
    """The record's bytes with the C padding zeroed (DDS does not carry padding)."""
    clean = MessageCodec(codec.cls)
    for name in codec.dtype.names:
        clean.message[name] = codec.message[name]
    return clean.buffer.tobytes()


def test_hg_lowcmd_carries_mode_machine_and_mode_pr_first():
    codec = MessageCodec(unitree_hg.LowCmd_)
    codec.message["mode_pr"], codec.message["mode_machine"] = 0, 5
    codec.message["motor_cmd"]["mode"][:29] = 1
    wire = codec.encode()
    obj = unitree_hg.LowCmd_.deserialize(wire)
    assert (obj.mode_pr, obj.mode_machine) == (0, 5)
    assert [c.mode for c in obj.motor_cmd] == [1] * 29 + [0] * 6
    assert wire[4:6] == b"\x00\x05"  # the first two bytes of the body


def test_go2_motor_slots_follow_unitree_leg_order(go2):
    """unitree_sdk2 numbers the Go2's motors FR, FL, RR, RL (hip, thigh, calf); its description's
    joints run FL, FR, RL, RR."""
    slot = dict(zip(go2.joint_names, go2.config.unitree.motor_index, strict=True))
    assert slot["FR_hip_joint"] == 0 and slot["FR_calf_joint"] == 2
    assert slot["FL_hip_joint"] == 3 and slot["FL_thigh_joint"] == 4
    assert slot["RR_hip_joint"] == 6 and slot["RL_calf_joint"] == 11
    feet = dict(zip(go2.config.base.feet, go2.config.unitree.foot_index, strict=True))
    assert feet == {"FR_foot": 0, "FL_foot": 1, "RR_foot": 2, "RL_foot": 3}


def test_emulator_faults_parse_and_refuse_nonsense():
    faults = EmulatorFaults()
    for text in ("lose:0.01", "burst:3", "burst:2:0.5", "delay:20@1:2", "corrupt-state:0.1"):
        parse_fault(text, faults)
    parse_fault("silent:3@2", faults)
    parse_fault("heat:4=1500@1", faults)
    assert faults.lose == 0.01 and faults.corrupt_state == 0.1
    assert faults.in_burst(3.5) and faults.in_burst(2.2) and not faults.in_burst(2.6)
    assert faults.delay(1.5) == pytest.approx(0.02) and faults.delay(3.5) == 0
    assert faults.silent == {3: 2.0} and faults.heat == {4: (1500.0, 1.0)}
    for bad in ("lose:2", "warp:1", "heat:4=-1", "silent:x"):
        with pytest.raises(ValueError, match="--fault"):
            parse_fault(bad, EmulatorFaults())


def test_importer_derives_unitree_slots_from_the_joint_names_and_refuses_others():
    from sim2real.robots.importer.source import RobotImportError
    from sim2real.robots.importer.unitree import foot_slot, motor_slot

    assert [motor_slot(j) for j in ("FR_hip_joint", "FL_calf_joint", "RL_thigh_joint")] == [
        0,
        5,
        10,
    ]
    assert foot_slot("RR_foot") == 2
    with pytest.raises(RobotImportError, match="left_knee_joint.*<LEG>_<part>_joint"):
        motor_slot("left_knee_joint")
