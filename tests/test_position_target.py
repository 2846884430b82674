"""A motor file decides whether the plant clamps a position target; without ``[position_target]``
the drive takes any target, as a Unitree motor's PD law does.

A user who brings a quadruped with motor files of their own (the catalog's ``go_m8010_6`` figures
without its ``[position_target]`` table) trained a policy whose PD targets pass the joints'
ranges (legged_gym, Isaac Lab and mjlab leave them unbounded): the plant must run the PD law on
those targets, not clamp them to the range as a servo's firmware would. The description is
unitree_mujoco's go2.xml layout (tests/go2_layout.py), here also with MuJoCo
``<position>`` actuators whose ``ctrlrange`` is the joint's range (``inheritrange``), as a
training simulator's file often has.
"""

from __future__ import annotations

import re

import mujoco
import numpy as np
import pytest

from sim2real.deploy.cli.robot_import import main as robot_import
from sim2real.robots import load_robot
from sim2real.robots.loading import MOTORS_DIR
from tests.go2_layout import write_go2

KP, KD = 25.0, 0.5


def user_motor(folder, clamped: bool | None):
    """``go_m8010_6.toml``'s figures as the user's own file ``my_motor.toml``, its
    ``[position_target]`` table removed (None) or saying ``clamped``."""
    text = (MOTORS_DIR / "go_m8010_6.toml").read_text()
    text = re.sub(r"\n\[position_target\]\n(.*\n)*?(?=\n\[|\Z)", "\n", text + "\n")
    assert "[position_target]" not in text
    if clamped is not None:
        text += (
            f"\n[position_target]\nclamped = {str(clamped).lower()}\n"
            "source = \"the drive's manual, position mode (a test's)\"\n"
        )
    path = folder / "my_motor.toml"
    path.write_text(text)
    return path


def position_actuators(source):
    """The layout's motors replaced by ``<position>`` servos over each joint's range."""
    text = source.read_text()
    head, _, rest = text.partition("  <actuator>\n")
    _, _, tail = rest.partition("  </actuator>\n")
    joints = re.findall(r'<joint name="(\w+_joint)"', head)
    servos = "".join(
        f'    <position name="{j}_servo" joint="{j}" kp="{KP}" kv="{KD}" inheritrange="1" />\n'
        for j in joints
    )
    source.write_text(f"{head}  <actuator>\n{servos}  </actuator>\n{tail}")
    return source


@pytest.mark.parametrize("clamped", [None, True])
def test_a_user_motor_file_without_the_key_leaves_targets_unclamped(tmp_path, capsys, clamped):
    """No ``[position_target]``: robot-import says the drive takes any target, the plant's
    position actuators have no control range, and a target 0.5 rad past a knee's stop pulls
    with ``kp`` times the whole error; ``clamped = true``: the range bounds it (before, both
    clamped)."""
    source = position_actuators(write_go2(tmp_path))
    motor = user_motor(tmp_path, clamped)
    out = tmp_path / "robots" / "go2"
    args = [str(source), "--out", str(out), "--floating-base", "--motor", f"*={motor}"]
    assert robot_import(args) == 0
    printed = capsys.readouterr()
    err = printed.out + printed.err
    assert "ctrlrange equal to the joint's range for" in err
    said = f"motor file {motor.resolve()}: no [position_target]: its drive takes any" in err
    assert said == (clamped is None)
    robot = load_robot(out)
    assert robot.clamps_position_target == (bool(clamped),) * robot.n_joints
    model = robot.plant_model("position")
    data = mujoco.MjData(model)
    knee = robot.joint_names.index("FL_calf_joint")
    a = model.actuator("FL_calf_joint_position").id
    assert bool(model.actuator_ctrllimited[a]) == bool(clamped)
    q = float(robot.position_lower[knee])  # resting at the stop
    data.qpos[model.jnt_qposadr[model.joint("FL_calf_joint").id]] = q
    data.ctrl[a] = q - 0.5  # a target past the stop
    mujoco.mj_forward(model, data)
    kp = robot.config.joints[knee].kp
    expected = kp * (0.0 if clamped else -0.5)
    assert data.actuator_force[a] == pytest.approx(
        np.clip(expected, -robot.effort_limit[knee], robot.effort_limit[knee]), abs=1e-6
    )
