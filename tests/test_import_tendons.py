"""robot-import keeps a fixed tendon with limits (a 4-bar ankle's limits written over its
hinges, as Unitree's G1 and H1-2 MJCFs do) when its joints survive; other tendons are dropped
with the printed note."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import SimBackend
from sim2real.robots import load_robot
from tests.import_fixtures import humanoid_with, import_tiny

pytest.importorskip("coal")

TENDONS = """<tendon>
  <fixed name="left_ankle_limit" limited="true" range="-0.6 0.4">
    <joint joint="left_knee_joint" coef="0.5"/><joint joint="left_ankle_joint" coef="1"/>
  </fixed>
  <fixed name="right_free">
    <joint joint="right_knee_joint" coef="1"/><joint joint="right_ankle_joint" coef="1"/>
  </fixed>
</tendon>"""


def test_a_limited_fixed_tendon_is_kept_and_the_plant_enforces_it(tmp_path, capsys):
    code, out = import_tiny(humanoid_with(tmp_path, TENDONS), tmp_path)
    assert code == 0
    printed = capsys.readouterr().out
    assert "1 limited fixed tendons ['left_ankle_limit'] kept" in printed
    assert "1 tendons ['right_free'] dropped" in printed
    robot = load_robot(out)  # Pinocchio parses the file with its tendon
    model = SimBackend(robot, envs=1).models[0]
    assert model.ntendon == 1 and model.tendon_limited[model.tendon("left_ankle_limit").id]
    np.testing.assert_allclose(model.tendon_range[0], [-0.6, 0.4])
    # the limit acts in the plant: a pose past it gets a tendon-limit constraint
    import mujoco

    data = mujoco.MjData(model)
    data.qpos[:] = np.concatenate([[0, 0, 1, 1, 0, 0, 0], robot.home])
    data.qpos[7 + robot.joint_names.index("left_knee_joint")] = 1.5
    data.qpos[7 + robot.joint_names.index("left_ankle_joint")] = 0.0
    mujoco.mj_forward(model, data)
    types = data.efc_type[: data.nefc]
    assert mujoco.mjtConstraint.mjCNSTR_LIMIT_TENDON in set(types.tolist())
