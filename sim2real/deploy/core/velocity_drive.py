"""Velocity-driven joints (wheels) among a robot's PD position targets: :class:`VelocityDrives`.

A wheel-legged robot's policy drives its legs by PD position targets and its wheels by speed
targets (robot.toml ``drive = "velocity"``, ``kp`` 0: ``tau = kd (v_target - dq)``; the plant's
actuator: :meth:`sim2real.robots.robot.Robot.mjspec`). In position mode the command array holds,
per joint, what that joint's drive takes: rad for a position drive, rad/s for a velocity drive.
The stages that shape position targets leave a wheel's column to this module:

- the smoother (:meth:`VelocityDrives.hold_goal`, :meth:`VelocityDrives.command`): Ruckig's
  wheel DoFs are held at rest (a speed is no position to plan toward); the command is the speed
  target clamped to the soft velocity limit (the guard's speed check of a continuous joint,
  which has no position limit to check), zero in a safe stop (the wheel's ``kd`` brakes it);
  unclamped for a policy trained with its speed targets as emitted (the runtime's ``follow``);
- a damped stop (:meth:`VelocityDrives.damp`): wheel speed 0 (legs: their measured pose);
- the ramp to the home pose (:meth:`VelocityDrives.damp` too): wheels at speed 0.

A robot without velocity drives gets None from :func:`velocity_drives`, and no stage changes.
"""

from __future__ import annotations

import numpy as np


class VelocityDrives:
    """The velocity-driven columns of ``envs`` robots' commands.

    Args:
        robot: The Robot (``velocity_driven``, ``soft_velocity_limit`` rad/s).
        envs: Batch size.

    Attributes:
        columns: (k,) int, joint indices of the velocity drives.
        limit: (k,) rad/s, their speed bound (the soft velocity limit).
        clamps: (envs,) int, speed targets clamped to ``limit`` since construction.
    """

    def __init__(self, robot, envs: int):
        self.columns = np.flatnonzero(robot.velocity_driven)
        self.limit = np.asarray(robot.soft_velocity_limit, dtype=np.float64)[self.columns]
        n = robot.n_joints
        self.dofs = (np.arange(envs)[:, None] * n + self.columns[None, :]).ravel()
        self.clamps = np.zeros(envs, dtype=np.int64)
        self._last = np.zeros((envs, self.columns.size))

    def hold_goal(self, goal: np.ndarray, position: np.ndarray) -> None:
        """Ruckig's goal ``goal`` (envs * n,) of the wheel DoFs set to its own ``position``
        ((envs, n) rad): they stay at rest, never planned toward a speed."""
        goal[self.dofs] = position.reshape(-1)[self.dofs]

    def command(
        self,
        target: np.ndarray | None,
        out: np.ndarray,
        stopping: np.ndarray,
        counts: np.ndarray | None = None,
        free: np.ndarray | None = None,
    ) -> None:
        """The wheels' columns of ``out`` (envs, n): ``target``'s speeds (rad/s; None: the last
        ones; non-finite: the last one) clamped to :attr:`limit`, 0 for the envs of ``stopping``
        ((envs,) bool); each clamp counted in :attr:`clamps` and in ``counts`` ((envs, n) int,
        the smoother's per-joint clamp counter) when given. The envs of ``free`` ((envs,) bool)
        take their speeds unclamped: a policy trained with its speed targets as emitted (the
        drive's ``kd (v_target - dq)`` is a torque request), its wheels judged on their speed."""
        last = self._last
        if target is not None:
            speeds = target[:, self.columns]
            ok = np.isfinite(speeds)
            over = ok & (np.abs(speeds) > self.limit)
            clipped = np.clip(speeds, -self.limit, self.limit)
            if free is not None and free.any():
                over &= ~free[:, None]
                np.copyto(clipped, speeds, where=free[:, None])
            self.clamps += over.sum(axis=1)
            if counts is not None:
                counts[:, self.columns] += over
            np.copyto(last, clipped, where=ok)
        last[stopping] = 0.0
        out[:, self.columns] = last

    def damp(self, cmd: np.ndarray, envs: np.ndarray) -> None:
        """Zero speed for the wheels of the envs of ``envs`` ((envs,) bool) in ``cmd``."""
        rows = np.flatnonzero(envs)
        cmd[np.ix_(rows, self.columns)] = 0.0
        self._last[rows] = 0.0


def velocity_drives(robot, envs: int, mode: str = "position") -> VelocityDrives | None:
    """:class:`VelocityDrives` of a robot with velocity-driven joints in position mode, else
    None."""
    if mode != "position" or not robot.velocity_driven.any():
        return None
    return VelocityDrives(robot, envs)
