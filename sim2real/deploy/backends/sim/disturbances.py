"""External disturbances of the MuJoCo plant: pushes of a floating base and constant forces.

:class:`SimDisturbances` is a stage of :class:`~sim2real.deploy.backends.sim.plant.SimBackend` (the
fault hooks of :class:`~sim2real.deploy.core.backend.SimulatedPlant`, which the plant delegates to
it) over the plant's ``models`` and ``datas`` (lists it shares), or over one bare model and data
(the push benchmark's own loops); it keeps no state of its own. A push is a wrench over a short
window (:meth:`SimDisturbances.push_wrench`), spread over the robot's bodies so that it changes the
whole robot's velocity as a training push does, its joints' speeds untouched
(:meth:`SimDisturbances.set_push_wrench`), which the IMU (MuJoCo's accelerometer and gyro) feels as
a real shove; changing the base's velocity at once (legged_gym's and mjlab's pushes:
:meth:`SimDisturbances.set_base_velocity`, :meth:`SimDisturbances.push_base`) happens between
physics steps and hides the push from the IMU.
A force acts on a body until it is changed.
"""

from __future__ import annotations

import mujoco
import numpy as np


class SimDisturbances:
    """The external disturbances of ``robot``'s envs simulated in ``models`` and ``datas`` (one
    ``MjModel`` and ``MjData`` per env; module docstring)."""

    def __init__(self, robot, models: list, datas: list):
        self.robot, self.models, self.datas = robot, models, datas

    @property
    def free_base(self) -> bool:
        """The plant's model begins with MuJoCo's free joint (the MJCF's floating base): its
        base moves and is pushed, its sensor frame carries an IMU and the feet's contacts."""
        m = self.models[0]
        return m.njnt > 0 and int(m.jnt_type[0]) == mujoco.mjtJoint.mjJNT_FREE

    def _pushable(self) -> None:
        """Raises ValueError: the plant's robot has no floating base (:attr:`free_base`)."""
        if not self.free_base:
            raise ValueError(f"robot {self.robot.name} has no floating base to push")

    def set_base_velocity(self, env: int, velocity_xy: np.ndarray) -> None:
        """Set the floating base's horizontal velocity of ``env`` to ``velocity_xy`` (2,) m/s,
        world frame, at once: legged_gym's push (its ``LeggedRobot`` push sets the root's x
        and y velocity to a random value), a shove the robot must recover from.

        Raises:
            ValueError: a fixed-base robot.
        """
        self._pushable()
        self.datas[env].qvel[:2] = velocity_xy

    def push_base(self, env: int, twist: np.ndarray, add: bool = False) -> None:
        """Change the floating base's velocity of ``env`` at once: ``twist`` (6,) is linear
        x, y, z (m/s, world frame) and angular roll, pitch, yaw (rad/s about the world axes);
        ``add``: added to the base's present velocity (mjlab's ``push_by_setting_velocity``),
        else the horizontal velocity is set to ``twist[:2]`` (legged_gym's push; the other
        entries must be 0). The free joint's angular velocity is in the body frame: the world
        twist is turned into it.

        Raises:
            ValueError: a fixed-base robot, or ``add`` False with a vertical or angular entry.
        """
        self._pushable()
        twist = np.asarray(twist, dtype=float)
        d = self.datas[env]
        if not add:
            if np.any(twist[2:]):
                raise ValueError("push_base: setting the velocity sets x and y only; use add")
            d.qvel[:2] = twist[:2]
            return
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, d.qpos[3:7])
        d.qvel[:3] += twist[:3]
        d.qvel[3:6] += rot.reshape(3, 3).T @ twist[3:6]

    def push_wrench(self, env: int, twist: np.ndarray, add: bool, duration: float) -> np.ndarray:
        """(6,) the wrench on the floating base of ``env`` (force N, torque N m, world frame, at
        the base's centre of mass: ``xfrc_applied``) that changes the robot's velocity as
        :meth:`push_base` does at once, applied for ``duration`` s: ``F = m dv / duration``
        with ``m`` the robot's whole mass (the free joint's linear block of MuJoCo's mass
        matrix: a training push moves the whole robot, its joints' speeds unchanged) and ``dv``
        the change :meth:`push_base` would make (``add``: ``twist[:3]``; else ``twist[:2]``
        less the base's present horizontal velocity), and ``tau = R I R^T dw / duration``
        with ``I`` the free joint's angular block (the robot's rotational inertia about the
        base, base frame) and ``dw = twist[3:]`` (world axes; ``add`` only). Friction with the
        floor acts over the window too, as on a real robot.

        Raises:
            ValueError: a fixed-base robot, ``duration <= 0``, or ``add`` False with a vertical
                or angular entry.
        """
        self._pushable()
        if not duration > 0:
            raise ValueError(f"push_wrench: expected a duration > 0 s, got {duration}")
        twist = np.asarray(twist, dtype=float)
        if not add and np.any(twist[2:]):
            raise ValueError("push_wrench: setting the velocity sets x and y only; use add")
        m, d = self.models[env], self.datas[env]
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)  # as of the last step (its mass matrix, mj_crb)
        dv = twist[:3].copy() if add else np.array([*(twist[:2] - d.qvel[:2]), 0.0])
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, d.qpos[3:7])
        rot = rot.reshape(3, 3)
        wrench = np.zeros(6)
        wrench[:3] = full[:3, :3] @ dv / duration
        wrench[3:] = rot @ (full[3:6, 3:6] @ (rot.T @ twist[3:6])) / duration
        return wrench

    def set_push_wrench(self, env: int, wrench: np.ndarray) -> np.ndarray:
        """Apply a push's whole ``wrench`` (6,) (:meth:`push_wrench`'s: force N and torque N m,
        world frame) to ``env`` spread over the robot's bodies as the rigid motion it starts:
        the linear acceleration ``a = F / m`` (``m`` the robot's mass) and the angular
        acceleration ``alpha`` (world) with ``R I R^T alpha = tau`` (``I`` the free joint's
        angular block of the mass matrix), each body ``b`` (mass ``m_b``, its centre of mass
        ``r_b`` from the base's origin, rotational inertia ``I_b`` about it, world frame) taking
        ``f_b = m_b (a + alpha x r_b)`` and ``tau_b = I_b alpha`` in its ``xfrc_applied`` row (at
        its centre of mass). Their generalized force is the mass matrix times the free joint's
        velocity change over the window: the robot moves as a whole, as under a training push
        (legged_gym's and mjlab's, which set the root's velocity and leave the joints' speeds),
        where a force on the base alone would swing the legs about their joints. Zeros remove
        the push (every body's row but the base's is cleared; the base's row is set to zero, as
        :meth:`set_base_wrench` does). Returns (6,) the base's row.

        Raises:
            ValueError: a fixed-base robot.
        """
        self._pushable()
        m, d = self.models[env], self.datas[env]
        base = m.body(self.robot.base_body).id
        bodies = np.flatnonzero(m.body_rootid == m.body_rootid[base])
        bodies = bodies[bodies > 0]
        wrench = np.asarray(wrench, dtype=float)
        if not wrench.any():
            d.xfrc_applied[bodies] = 0.0
            return np.zeros(6)
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, d.qpos[3:7])
        rot = rot.reshape(3, 3)
        a = wrench[:3] / full[0, 0]
        alpha = np.zeros(3)
        if wrench[3:].any():
            alpha = np.linalg.solve(rot @ full[3:6, 3:6] @ rot.T, wrench[3:])
        for b in bodies:
            r = d.xipos[b] - d.xpos[base]
            frame = d.ximat[b].reshape(3, 3)
            d.xfrc_applied[b, :3] = m.body_mass[b] * (a + np.cross(alpha, r))
            d.xfrc_applied[b, 3:] = frame @ (m.body_inertia[b] * (frame.T @ alpha))
        return d.xfrc_applied[base].copy()

    def set_base_wrench(self, env: int, wrench: np.ndarray) -> None:
        """Apply ``wrench`` (6,): force (N) and torque (N m), world frame, at the floating
        base's centre of mass of ``env`` until changed (zeros remove it); the base's
        ``xfrc_applied`` row, which a fault's force (:meth:`set_external_force`) also writes.

        Raises:
            ValueError: a fixed-base robot.
        """
        self._pushable()
        m, d = self.models[env], self.datas[env]
        d.xfrc_applied[m.body(self.robot.base_body).id] = wrench

    def set_external_force(self, env: int, force: np.ndarray, body: str | None = None) -> None:
        """Apply a constant force (N, world frame, shape (3,)) to ``env`` until changed.

        It acts at the centre of mass of ``body`` (default: the body of the end-effector site;
        a floating base's base body); zeros remove it. A push, or a cable pulling on the end
        effector.

        Raises:
            KeyError: ``body`` names no body of the model (MuJoCo's lookup).
        """
        m, d = self.models[env], self.datas[env]
        if body is None and self.free_base:
            body = self.robot.base_body
        bid = m.site_bodyid[self.robot.ee_site_id] if body is None else m.body(body).id
        d.xfrc_applied[bid, :3] = force
