"""The import says when a description's effort limit is far above its motor's peak torque: a joint
behind a reduction of its own (the Go2's knee linkage) capped to the bare motor's torque halves
the knee's torque, and the Go2 then climbs fewer stairs (docs/soak.md's terrain margin)."""

from pathlib import Path
from types import SimpleNamespace

from sim2real.robots.importer.model import cap_limits
from sim2real.robots.importer.source import JointInfo


def _cap(effort: float) -> list[str]:
    joint = JointInfo("FL_calf_joint", "hinge", "FL_thigh", "FL_calf", -2.72, -0.84, 30.0, effort)
    joint.effort_from = "MJCF <motor name='FL_calf'> ctrlrange"
    source = SimpleNamespace(
        kind="MJCF",
        path=Path("go2.xml"),
        movable=["FL_calf_joint"],
        joints={"FL_calf_joint": joint},
    )
    motor = SimpleNamespace(peak_torque=23.7, max_velocity=30.0)
    lines: list[str] = []
    limits, lowered, _ = cap_limits(
        source, {"FL_calf_joint": "go_m8010_6"}, {"go_m8010_6": motor}, lines.append
    )
    assert limits["FL_calf_joint"][3] == 23.7  # the motor's peak still caps it (the user decides)
    assert lowered == [("FL_calf_joint", "effort", effort, 23.7, "N m")]
    return lines


def test_a_knee_behind_a_linkage_capped_to_its_bare_motor_gets_a_hint():
    (line,) = _cap(45.43)  # Go2 go2.xml's knee ctrlrange against GO-M8010-6's 23.7 N m
    assert "45.43 N m" in line and "-> 23.7 N m" in line
    assert "1.92 x the motor's" in line and "--motor FL_calf_joint=MODEL" in line


def test_a_description_rounding_its_motors_torque_gets_no_hint():
    (line,) = _cap(25.0)
    assert "-> 23.7 N m" in line and "further reduction" not in line
