"""RobotState: what the estimator and the kinematics stage know of a batch of robots, and
BaseState: a floating base's estimate within it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from sim2real.deploy.core.attitude import quaternion_to_matrix, tilt_of
from sim2real.robots import Robot


@dataclass
class BaseState:
    """The base estimate of ``envs`` robots at ``frame.time``.

    Attributes:
        orientation: (envs, 4) base-to-world unit quaternion ``[w, x, y, z]`` (yaw unobserved).
        projected_gravity: (envs, 3) unit vector, gravity's direction in the base frame.
        angular_velocity: (envs, 3) rad/s, base frame, gyroscope bias removed.
        linear_velocity: (envs, 3) m/s, base frame.
        linear_velocity_world: (envs, 3) m/s, in the (yaw-drifting) world frame of the filter.
    """

    orientation: np.ndarray
    projected_gravity: np.ndarray
    angular_velocity: np.ndarray
    linear_velocity: np.ndarray
    linear_velocity_world: np.ndarray

    @classmethod
    def zeros(cls, envs: int) -> BaseState:
        q = np.zeros((envs, 4))
        q[:, 0] = 1.0
        g = np.zeros((envs, 3))
        g[:, 2] = -1.0
        return cls(q, g, np.zeros((envs, 3)), np.zeros((envs, 3)), np.zeros((envs, 3)))

    def set_truth(self, truth: np.ndarray) -> BaseState:
        """Fill every field from a simulated base's true state (evaluation, parity replays and
        training rewards): ``truth`` (envs, 13) as :meth:`sim2real.deploy.backends.sim.plant.SimBackend.
        true_base_state` gives it (position m, quaternion ``[w, x, y, z]``, linear velocity m/s
        world, angular velocity rad/s base frame). Returns self."""
        rot = quaternion_to_matrix(truth[:, 3:7])
        velocity = truth[:, 7:10]
        self.orientation[:] = truth[:, 3:7]
        self.projected_gravity[:] = -rot[:, 2]
        self.angular_velocity[:] = truth[:, 10:13]
        self.linear_velocity_world[:] = velocity
        self.linear_velocity[:] = np.matmul(rot.transpose(0, 2, 1), velocity[:, :, None])[:, :, 0]
        return self

    @property
    def tilt(self) -> np.ndarray:
        """(envs,) rad, angle between the base's z axis and the world's up (:func:`tilt_of`)."""
        return tilt_of(self.projected_gravity)


@dataclass
class RobotState:
    """Estimated state of ``envs`` robots, preallocated once and updated in place.

    Attributes:
        q: (envs, n) rad, joint positions.
        dq: (envs, n) rad/s, joint velocities.
        ee_position: (envs, 3) m, end-effector site in the base frame.
        ee_rotation: (envs, 3, 3), end-effector site orientation (base frame).
        winding_temperature: (envs, n) degC, as last reported by the drives.
        last_action: (envs, n), the policy's previous action in [-1, 1] (0 before the first).
        base: Floating-base robots: the base estimate
            (:class:`sim2real.deploy.core.state.BaseState`); None for a fixed-base arm.
        foot_contact: Floating-base robots: (envs, n_feet) 1.0 where a foot touches, else 0.0.
        command: Floating-base robots: (envs, 3) the velocity command (vx, vy m/s, yaw rate
            rad/s, base frame).
        clock: (envs,) s, the runtime's time (the gait phase's clock).
    """

    q: np.ndarray
    dq: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    winding_temperature: np.ndarray
    last_action: np.ndarray
    base: object = None
    foot_contact: np.ndarray | None = None
    command: np.ndarray | None = None
    clock: np.ndarray | None = None

    @classmethod
    def zeros(cls, envs: int, n_joints: int, ambient: float = 25.0) -> RobotState:
        return cls(
            q=np.zeros((envs, n_joints)),
            dq=np.zeros((envs, n_joints)),
            ee_position=np.zeros((envs, 3)),
            ee_rotation=np.tile(np.eye(3), (envs, 1, 1)),
            winding_temperature=np.full((envs, n_joints), ambient),
            last_action=np.zeros((envs, n_joints)),
        )

    @classmethod
    def legged(cls, envs: int, n_joints: int, n_feet: int, ambient: float = 25.0) -> RobotState:
        """A floating-base robot's state: :meth:`zeros` with the base estimate upright at rest,
        no foot contact, a zero command and the clock at 0."""
        from sim2real.deploy.core.state import BaseState

        state = cls.zeros(envs, n_joints, ambient)
        state.base = BaseState.zeros(envs)
        state.foot_contact = np.zeros((envs, n_feet))
        state.command = np.zeros((envs, 3))
        state.clock = np.zeros(envs)
        return state


class Kinematics:
    """End-effector forward kinematics with Pinocchio for a batch (one ``pin.Data``, reused)."""

    def __init__(self, robot: Robot):
        self.model = robot.pin_model
        self.data = self.model.createData()
        self.frame_id = robot.ee_frame_id

    def update(self, state: RobotState) -> RobotState:
        """Fill ``state.ee_position`` and ``state.ee_rotation`` from ``state.q``; returns state."""
        model, data, frame, q = self.model, self.data, self.frame_id, state.q
        if frame < 0:  # no end effector (a legged robot): nothing to compute
            return state
        position, rotation = state.ee_position, state.ee_rotation
        for e in range(q.shape[0]):
            pin.forwardKinematics(model, data, q[e])
            placement = pin.updateFramePlacement(model, data, frame)  # this frame only
            h = placement.homogeneous
            position[e] = h[:3, 3]
            rotation[e] = h[:3, :3]
        return state

    def reach(self) -> float:
        """Upper bound of the distance from the first joint to the end effector, m: the sum of
        the distances between consecutive joint origins and from the last joint to the site."""
        q0 = pin.neutral(self.model)
        pin.framesForwardKinematics(self.model, self.data, q0)
        points = [self.data.oMi[j].translation for j in range(1, self.model.njoints)]
        points.append(self.data.oMf[self.frame_id].translation)
        return float(sum(np.linalg.norm(b - a) for a, b in zip(points, points[1:], strict=False)))
