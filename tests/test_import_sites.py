"""A site named like its body (``<body name="pelvis"><site name="pelvis"/>``, as published
humanoid MJCFs write their IMU) made Pinocchio raise "Several frames match the filter" for the
name at deploy-run time; robot-import renames it ``pelvis_site`` and ``--imu pelvis`` follows."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from sim2real.deploy.cli.robot_import import main
from sim2real.robots import load_robot
from tests.test_import_humanoid import FLAGS, write_humanoid

pytest.importorskip("coal")

SITE = '<site name="pelvis" pos="0.03 0 0.05"/>'


def test_untyped_lookup_of_a_site_named_like_its_body_is_ambiguous_in_pinocchio(tmp_path):
    """The failure the rename avoids, reproduced on Pinocchio's parser alone."""
    path = tmp_path / "m.xml"
    path.write_text(
        '<mujoco><worldbody><body name="pelvis"><freejoint/><geom size="0.1"/>'
        f"{SITE}</body></worldbody></mujoco>"
    )
    model = pin.buildModelFromMJCF(str(path))
    with pytest.raises(Exception, match="Several frames match"):
        model.getFrameId("pelvis")
    assert model.frames[model.getFrameId("pelvis", pin.FrameType.BODY)].type == pin.BODY


def test_a_site_named_like_its_body_is_renamed_and_the_imu_flag_follows(tmp_path, capsys):
    source = write_humanoid(tmp_path)
    text = source.read_text()
    at = text.index('<joint name="floating_base_joint"')
    source.write_text(text[:at] + SITE + "\n      " + text[at:])
    out = tmp_path / "robots" / "tiny"
    assert main([str(source), "--out", str(out), *FLAGS, "--imu", "pelvis"]) == 0
    assert "renamed {'pelvis': 'pelvis_site'}" in capsys.readouterr().out
    robot = load_robot(out)
    model = robot.pin_model
    assert [f.name for f in model.frames].count("pelvis") == 1  # the body's frame alone
    assert model.frames[model.getFrameId("pelvis")].type == pin.FrameType.BODY
    # the IMU sits where the MJCF's site was (the --imu flag named the site, not the body)
    mj = robot.mj_model
    np.testing.assert_allclose(mj.site("imu").pos, [0.03, 0.0, 0.05], atol=1e-9)
    assert mj.body(int(mj.site("imu").bodyid[0])).name == "pelvis"
