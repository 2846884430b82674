"""RobotState: what the estimator and the kinematics stage know of a batch of robots, and
BaseState: a floating base's estimate within it."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import pinocchio as pin

from sim2real.deploy.core import kinematics_kernel as kk
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
        motion: A motion-tracking task's reference for this tick (envs, 2n + 4): the clip's
            joint angles (n) rad and velocities (n) rad/s in the robot's joint order, then its
            anchor quaternion ``w x y z`` in the world frame, yaw-aligned; None without one
            (:mod:`sim2real.deploy.spec.motion_blocks`).
        motion_time: A phase-clocked policy's (a ``motion_phase`` block): (envs,) s since its
            motion started, the runtime's clock
            (:class:`sim2real.deploy.core.phase_clock.MotionPhaseClock`); else None.
        height_scan: A policy with a ``height_scan`` block: (envs, points) m, the sensor's
            height above the terrain at each point of its scan, the last map that arrived
            (:class:`sim2real.deploy.runtime.height_map.HeightMap`); else None.
        sensed_orientation: A floating base whose IMU sends its own attitude (robot.toml
            ``[sensors.imu] orientation_sigma`` set): (envs, 4) the base-to-world unit
            quaternion ``[w, x, y, z]`` that attitude gives (the IMU site's turned into the
            base's; the IMU's own heading, not the estimator's), the last reading that arrived
            (:class:`sim2real.deploy.kinds.legged_tick.LeggedTick`); else None.
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
    motion: np.ndarray | None = None
    motion_time: np.ndarray | None = None
    height_scan: np.ndarray | None = None
    sensed_orientation: np.ndarray | None = None

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


@numba.njit(cache=True, nogil=True, _nrt=False)
def _put_pose(h: np.ndarray, e: int, position: np.ndarray, rotation: np.ndarray) -> None:
    """Copy the homogeneous transform ``h`` (4, 4) into ``position[e]`` (3,) and
    ``rotation[e]`` (3, 3)."""
    for r in range(3):
        position[e, r] = h[r, 3]
        for k in range(3):
            rotation[e, r, k] = h[r, k]


#: Seeded random poses (uniform in [-pi, pi]) on which :class:`Kinematics` checks its compiled
#: chain against Pinocchio, besides the zero pose.
CHECK_POSES = 64


class Kinematics:
    """End-effector forward kinematics of a batch: Pinocchio's, or the same numbers compiled.

    For a serial chain of revolute joints about their frames' x, y or z axes (every arm robot
    we ship) the placement is computed by one compiled call
    (:func:`sim2real.deploy.core.kinematics_kernel.chain_fk`), used only if it equals Pinocchio's
    ``forwardKinematics`` + ``updateFramePlacement`` bit for bit on the zero pose and
    ``CHECK_POSES`` random ones here (``compiled`` says which); otherwise, and for other joint
    models, Pinocchio's two calls per env (one ``pin.Data``, reused).
    """

    def __init__(self, robot: Robot):
        self.model = robot.pin_model
        self.data = self.model.createData()
        self.frame_id = robot.ee_frame_id
        self._state: RobotState | None = None  # the state whose rows _rows holds
        self._q: np.ndarray | None = None
        self._rows: tuple[np.ndarray, ...] = ()
        _put_pose(np.eye(4), 0, np.zeros((1, 3)), np.zeros((1, 3, 3)))
        #: the compiled chain's arguments (chain, placements, work), or None: Pinocchio's calls
        self.chain: tuple[np.ndarray, ...] | None = None
        if self.frame_id >= 0:
            self.chain = self._compile_chain()

    @property
    def compiled(self) -> bool:
        """Whether :meth:`update` runs the compiled chain (else Pinocchio)."""
        return self.chain is not None

    def _compile_chain(self) -> tuple[np.ndarray, ...] | None:
        """The compiled chain's arguments, if the model is such a chain and the kernel equals
        Pinocchio bit for bit on the check poses; else None."""
        model = self.model
        joints = model.njoints - 1
        kinds = [model.joints[i].shortname() for i in range(1, model.njoints)]
        if joints < 1 or any(k not in kk.AXES for k in kinds) or model.nq != joints:
            return None
        frame = model.frames[self.frame_id]
        chain = np.array(
            [
                [kk.AXES[kinds[i - 1]], model.parents[i] - 1, model.joints[i].idx_q]
                for i in range(1, model.njoints)
            ]
            + [[-1, frame.parentJoint - 1, -1]],
            dtype=np.int64,
        )
        placements = np.array(
            [
                np.hstack([m.rotation, m.translation[:, None]])
                for m in [*list(model.jointPlacements)[1:], frame.placement]
            ],
            dtype=np.float64,
        )
        args = (chain, placements, np.zeros((joints + 1, 3, 4)))
        poses = np.random.default_rng(0).uniform(-np.pi, np.pi, (CHECK_POSES + 1, joints))
        poses[0] = 0.0
        state = RobotState.zeros(len(poses), joints)
        state.q[:] = poses
        kk.chain_fk(state.q, *args, state.ee_position, state.ee_rotation)
        position, rotation = state.ee_position.copy(), state.ee_rotation.copy()
        self._pinocchio(state)
        same = np.array_equal(position.view(np.int64), state.ee_position.view(np.int64))
        same &= np.array_equal(rotation.view(np.int64), state.ee_rotation.view(np.int64))
        return args if same else None

    def update(self, state: RobotState) -> RobotState:
        """Fill ``state.ee_position`` ((envs, 3) m) and ``state.ee_rotation`` ((envs, 3, 3)),
        base frame, from ``state.q`` ((envs, n) rad); returns state (nothing to do without an
        end effector, a legged robot)."""
        if self.chain is not None:
            kk.chain_fk(state.q, *self.chain, state.ee_position, state.ee_rotation)
            return state
        if self.frame_id < 0:  # no end effector (a legged robot): nothing to compute
            return state
        return self._pinocchio(state)

    def _pinocchio(self, state: RobotState) -> RobotState:
        """:meth:`update` with Pinocchio's calls: the rows of ``state.q`` are views made once per
        state, the placement copied by one compiled call (:func:`_put_pose`)."""
        q = state.q
        if state is not self._state or q is not self._q:
            self._state, self._q, self._rows = state, q, tuple(q)
        model, data, frame = self.model, self.data, self.frame_id
        fk, place = pin.forwardKinematics, pin.updateFramePlacement
        position, rotation = state.ee_position, state.ee_rotation
        for e, row in enumerate(self._rows):
            fk(model, data, row)
            _put_pose(place(model, data, frame).homogeneous, e, position, rotation)
        return state

    def reach(self) -> float:
        """Upper bound of the distance from the first joint to the end effector, m: the sum of
        the distances between consecutive joint origins and from the last joint to the site."""
        q0 = pin.neutral(self.model)
        pin.framesForwardKinematics(self.model, self.data, q0)
        points = [self.data.oMi[j].translation for j in range(1, self.model.njoints)]
        points.append(self.data.oMf[self.frame_id].translation)
        return float(sum(np.linalg.norm(b - a) for a, b in zip(points, points[1:], strict=False)))
