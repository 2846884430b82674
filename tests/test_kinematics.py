"""The end-effector kinematics (:class:`sim2real.deploy.core.state.Kinematics`): its compiled chain
gives Pinocchio's placements bit for bit, and it falls back to Pinocchio where it would not."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from sim2real.deploy.core import kinematics_kernel as kk
from sim2real.deploy.core.state import Kinematics, RobotState
from sim2real.robots import load_robot


def _pinocchio_placements(robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(envs, 3) and (envs, 3, 3): Pinocchio's ``forwardKinematics`` + ``updateFramePlacement``."""
    model = robot.pin_model
    data = model.createData()
    position, rotation = np.zeros((len(q), 3)), np.zeros((len(q), 3, 3))
    for e, row in enumerate(q):
        pin.forwardKinematics(model, data, row)
        placement = pin.updateFramePlacement(model, data, robot.ee_frame_id)
        position[e], rotation[e] = placement.translation, placement.rotation
    return position, rotation


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a).view(np.int64)  # signed zeros and NaNs compared too


@pytest.mark.parametrize("name", ["arm3", "arm6", "so101", "ur5"])
def test_the_compiled_chain_equals_pinocchio_bit_for_bit(name):
    robot = load_robot(name)
    kinematics = Kinematics(robot)
    assert kinematics.compiled
    state = RobotState.zeros(2000, robot.n_joints)
    state.q[:] = np.random.default_rng(7).uniform(-7.0, 7.0, state.q.shape)
    state.q[0] = 0.0
    state.q[1] = robot.home
    state.q[2, 0] = np.pi / 2
    assert kinematics.update(state) is state
    position, rotation = _pinocchio_placements(robot, state.q)
    np.testing.assert_array_equal(_bits(state.ee_position), _bits(position))
    np.testing.assert_array_equal(_bits(state.ee_rotation), _bits(rotation))


def test_a_chain_that_differs_from_pinocchio_falls_back_to_it(monkeypatch):
    robot = load_robot("arm3")
    compiled = kk.chain_fk

    def off_by_one_bit(q, *args):
        compiled(q, *args)
        args[-2][:] = np.nextafter(args[-2], np.inf)

    monkeypatch.setattr(kk, "chain_fk", off_by_one_bit)
    kinematics = Kinematics(robot)
    assert not kinematics.compiled
    state = RobotState.zeros(3, robot.n_joints)
    state.q[:] = np.random.default_rng(1).uniform(-3.0, 3.0, state.q.shape)
    kinematics.update(state)
    position, rotation = _pinocchio_placements(robot, state.q)
    np.testing.assert_array_equal(_bits(state.ee_position), _bits(position))
    np.testing.assert_array_equal(_bits(state.ee_rotation), _bits(rotation))


def test_a_robot_without_an_end_effector_computes_nothing(go2):
    kinematics = Kinematics(go2)
    assert not kinematics.compiled
    state = RobotState.zeros(1, go2.n_joints)
    before = state.ee_rotation.copy()
    kinematics.update(state)
    np.testing.assert_array_equal(state.ee_rotation, before)
