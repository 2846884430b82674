"""Fall detection of a floating-base (legged) robot, from what the robot itself measures.

A robot has fallen when its base is tilted past ``safety.fall_tilt`` (rad, the angle between the
base's z axis and the world's up, from the attitude filter's projected gravity) or when, with a
foot on the ground, its base has stayed lower than ``safety.fall_height`` (m) above the feet in
contact for ``FALL_HEIGHT_TIME`` s: the kinematic base height, ``max_i -(R p_i)_z`` over the feet
``i`` in contact, ``p_i`` the foot position in the base frame (Pinocchio, joint estimate) and ``R``
the estimated orientation. The tilt trips at once; the height must persist, because a low trot
on one foot in contact dips under the limit for a tick while a collapsed base stays down. A third
signal needs neither the feet nor the tilt: the estimated base sinking faster than
``FALL_SPEED`` for ``FALL_SPEED_TIME`` s (the kinematic height falls with the feet, a base can
drop upright). No ground truth is read: the same check runs on hardware.

The runtime's response (:mod:`sim2real.deploy.runtime`, cause ``fall``): a safe stop whose command is
joint damping (position mode: the target follows the measured pose, so the PD servo applies
``-kd dq`` only; what Unitree's deploy code does after a fall), latched in FAULTED until an
operator's reset. Every other safe stop of a legged robot damps the same way: holding a stance
against gravity is what overheats its motors.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from sim2real.deploy.core.attitude import quaternion_to_matrix, tilt_of
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.core.stateful import check, put, take
from sim2real.deploy.estimation.base import require_floating_base
from sim2real.robots import Robot

#: Default tilt limit, rad (our choice): a walking quadruped's base stays within ~0.3 rad of
#: upright; past 1 rad (57 deg) it cannot catch itself.
FALL_TILT = 1.0
#: Default height limit, m (our choice): about half a Go2's calf (0.21 m), the base near the floor.
FALL_HEIGHT = 0.12
#: How long the base must stay under the height limit, s (our choice): ten ticks at 50 Hz. A
#: collapsed base stays down for far longer; a one-tick dip of a walking robot's estimate does not.
FALL_HEIGHT_TIME = 0.2
#: Sinking speed, m/s, and for how long, s (our choice): a walking base's vertical velocity
#: stays within about 0.3 m/s; a base in free fall passes 1 m/s after 0.1 s and is then 5 cm
#: lower. Five ticks at 50 Hz.
FALL_SPEED = 1.0
FALL_SPEED_TIME = 0.1
#: The three signals of a fall, the columns of :attr:`FallDetector.signals`.
SIGNALS = ("tilt", "height", "sinking")


class FallDetector:
    """The fall check of ``robot`` (module docstring).

    Args:
        robot: A floating-base robot; ``robot.config.safety.fall_tilt`` (rad) and
            ``fall_height`` (m) are its limits (default ``FALL_TILT``, ``FALL_HEIGHT``).
        envs: Batch size.

    Attributes:
        tilt_limit: rad. height_limit: m (0 disables the height check).
        height_ticks: control ticks the height must stay under ``height_limit``
            (``FALL_HEIGHT_TIME`` over the robot's control period, rounded up).
        height: (envs,) m, the last kinematic base height (NaN with no foot in contact).
        low_ticks: (envs,) int64, consecutive checks so far with ``height`` under the limit.
        speed_ticks: control ticks the base must sink faster than ``FALL_SPEED``.
        sinking_ticks: (envs,) int64, consecutive checks so far with the base sinking so.
        signals: (envs, 3) bool, which signal of the last :meth:`check` fired, columns in
            :data:`SIGNALS` order (for the logs: a fall record says why it was called).

    Raises:
        ValueError: a fixed-base robot.
    """

    def __init__(self, robot: Robot, envs: int):
        require_floating_base(robot, "fall detection")
        s = robot.config.safety
        self.tilt_limit = float(FALL_TILT if s.fall_tilt is None else s.fall_tilt)
        self.height_limit = float(FALL_HEIGHT if s.fall_height is None else s.fall_height)
        self.model = robot.fixed_base_model
        self.data = self.model.createData()
        # the foot sites' frames in the fixed-base model (same names as in pin_model)
        frames = [robot.pin_model.frames[f] for f in robot.foot_frame_ids]
        self.feet = [self.model.getFrameId(f.name, f.type) for f in frames]
        self.height = np.full(envs, np.nan)
        self.height_ticks = max(1, int(np.ceil(FALL_HEIGHT_TIME / robot.control_period - 1e-9)))
        self.low_ticks = np.zeros(envs, dtype=np.int64)
        self.speed_ticks = max(1, int(np.ceil(FALL_SPEED_TIME / robot.control_period - 1e-9)))
        self.sinking_ticks = np.zeros(envs, dtype=np.int64)
        self.signals = np.zeros((envs, len(SIGNALS)), dtype=bool)

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """``height`` (envs,) m, ``low_ticks`` and ``sinking_ticks`` (envs,) int64 (copies;
        conventions of :mod:`sim2real.deploy.core.stateful`; the env axis has length 1 for one env
        ``env``)."""
        return take(self._fields(), env)

    def _fields(self) -> dict[str, np.ndarray]:
        return {
            "height": self.height,
            "low_ticks": self.low_ticks,
            "sinking_ticks": self.sinking_ticks,
        }

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        check(self._fields(), state, env)
        put(self._fields(), state, env)

    def check(self, state: RobotState) -> np.ndarray:
        """(envs,) bool: the envs whose estimated base is tilted, low or sinking past the
        limits.

        Args:
            state: A floating-base robot's estimate (``RobotState.legged``: ``base``,
                ``foot_contact``, ``q``).
        """
        signals = self.signals
        signals[:] = False
        signals[:, 0] = tilt_of(state.base.projected_gravity) > self.tilt_limit
        sinking = state.base.linear_velocity_world[:, 2] < -FALL_SPEED
        self.sinking_ticks[:] = np.where(sinking, self.sinking_ticks + 1, 0)
        signals[:, 2] = self.sinking_ticks >= self.speed_ticks
        if self.height_limit > 0.0:
            contact = state.foot_contact > 0.5
            self.height[:] = np.nan
            for e in np.flatnonzero(contact.any(axis=1)):
                pin.forwardKinematics(self.model, self.data, state.q[e])
                rot = quaternion_to_matrix(state.base.orientation[e])
                below = [
                    -(rot @ pin.updateFramePlacement(self.model, self.data, f).translation)[2]
                    for f, touching in zip(self.feet, contact[e], strict=True)
                    if touching
                ]
                self.height[e] = max(below)
            low = self.height < self.height_limit  # NaN (no contact) compares False
            self.low_ticks[:] = np.where(low, self.low_ticks + 1, 0)
            signals[:, 1] = self.low_ticks >= self.height_ticks
        return signals.any(axis=1)
