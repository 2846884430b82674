"""What a command means to each joint's drive (:class:`DriveTargets`), the object a robot kind
hands the guard, the smoother and the runtime (:meth:`sim2real.deploy.robot_kind.RobotKind.targets`)
instead of flags to look up: they ask it for the bounds of a target, the rows of their checks,
the joint filters' input and the tolerances, per joint.

Two meanings of a position target, per joint:

- a drive that follows its command (an arm's servo): the target is bounded by the hard limits
  and clamped to the soft ones, the joint filter takes the commanded acceleration, a command
  far from the measured pose is re-anchored, the guard certifies the commanded motion (its
  motion envelope, :mod:`sim2real.deploy.safety.envelope`);
- a low-gain PD loop (a legged robot's, trained so): the target is a torque request, unbounded,
  judged by its predicted motion (:mod:`sim2real.deploy.safety.pd_barrier`), the joint filter
  runs the constant-velocity model, RAMP_IN in position mode ends on the commanded pose, no
  tracking tolerance, no motion envelope (the base moves the links anyway).

A robot may mix them (:mod:`sim2real.deploy.kinds.legged_arm`: PD legs, a commanded arm). Units:
rad, s; arrays (n,) in the robot's joint order.
"""

from __future__ import annotations

import numpy as np


class DriveTargets:
    """What a command means to each joint's drive (module docstring).

    Args:
        pd: (n,) bool, the joints whose position targets drive low-gain PD loops (torque
            requests); the rest follow their command.
        bounce: The estimate past a hard limit stops the robot only when it stays past (a PD
            robot's joints bounce off their stops: ``LEGGED_HARD_LIMIT_*`` of
            :mod:`sim2real.deploy.safety.limits`).
        holds_self_collision: The guard holds a target predicted to bring two links into
            contact (:mod:`sim2real.deploy.safety.predicted`).
        joint_input: The joint filters take the commanded acceleration as their input.

    Attributes:
        pd: (n,) bool, as given (read only).
        follows: (n,) bool, the joints whose drives follow their command (``~pd``).
    """

    def __init__(self, pd: np.ndarray, bounce: bool, holds_self_collision: bool, joint_input: bool):
        self.pd = np.array(pd, dtype=bool)
        self.pd.flags.writeable = False
        self.follows = ~self.pd
        self.follows.flags.writeable = False
        self._bounce = bool(bounce)
        self._holds = bool(holds_self_collision)
        self._joint_input = bool(joint_input)

    def target_bounds(self, lower: np.ndarray, upper: np.ndarray) -> tuple:
        """``(lower, upper)`` (n,) rad bounding a position target: the given ones where the drive
        follows its command, -inf and +inf on a PD joint (a torque request, judged instead)."""
        return np.where(self.pd, -np.inf, lower), np.where(self.pd, np.inf, upper)

    def bounded(self) -> np.ndarray:
        """(n,) bool: the joints whose smoothed command is bounded by the hard limits in
        position mode (:class:`~sim2real.deploy.smoothing.smoother.CommandSmoother`)."""
        return self.follows.copy()

    def motion_envelope(self, build):
        """``build()`` (the guard's :class:`~sim2real.deploy.safety.envelope.MotionEnvelope`)
        where every drive follows its command, else None: a PD target's motion is not the
        command's, and a moving base moves the links anyway."""
        return None if self.pd.any() else build()

    def soft_clamp_row(self) -> np.ndarray:
        """(1, n) 1.0 where the soft-limit check clamps a position target, 0.0 on a PD joint
        (judged by its consequence, :mod:`sim2real.deploy.safety.pd_barrier`)."""
        return self.follows.astype(np.float64)[None, :]

    def barrier_joints(self, mode: str) -> np.ndarray:
        """(n,) bool: the joints the PD barrier judges in control mode ``mode``: the PD joints in
        position mode, none otherwise."""
        return self.pd & (mode == "position")

    def hard_limit_rows(self, n: int, tolerance: float, duration: int, bounce: int) -> tuple:
        """``(tolerance, duration, bounce)`` rows (n,) each of the hard-limit check: the given
        tolerance (rad) and tick counts where the joints bounce off their stops, 0 otherwise."""
        on = 1.0 if self._bounce else 0.0
        return np.full(n, on * tolerance), np.full(n, on * duration), np.full(n, on * bounce)

    def self_collision_row(self, n: int) -> np.ndarray:
        """(1, n) 1.0 where the guard holds a target predicted in self-collision, else 0.0."""
        return np.full((1, n), 1.0 if self._holds else 0.0)

    def estimator_input(self, acceleration: np.ndarray | None) -> np.ndarray | None:
        """The joint filters' control input: the commanded ``acceleration`` (envs, n) rad/s^2
        where the drives follow it (the kind's ``joint_input``), else None (the
        constant-velocity model: low-gain PD targets lead the joints and may step from tick to
        tick, their acceleration is not the joints')."""
        return acceleration if self._joint_input else None

    def home_from_command(self, mode: str) -> bool:
        """RAMP_IN ends on the smoother's commanded position at home, not the estimate's: a PD
        robot in position mode (its soft PD holds its weight short of the home pose)."""
        return bool(self.pd.any()) and mode == "position"

    def follows_policy(self, smoothing: str, mode: str) -> bool:
        """The RUNNING envs command the policy's targets as it emitted them (after the guard),
        not through the smoother: PD targets in position mode whose spec's
        ``action.smoothing`` (``smoothing``) is not ``'jerk_limited'``."""
        return self.home_from_command(mode) and smoothing != "jerk_limited"

    def check_smoothing(self, smoothing: str, robot_name: str) -> None:
        """Refuse ``action.smoothing = 'none'`` on a robot with no PD joint (its commands always
        pass the smoother).

        Raises:
            ValueError: naming the robot and the expected smoothing."""
        if smoothing == "none" and not self.pd.any():
            raise ValueError(
                f"policy action.smoothing 'none': the robot '{robot_name}' does not run PD "
                "targets (its commands always pass the smoother); expected 'jerk_limited' or "
                "none given"
            )

    def tracking_tolerance(self, position: float, velocity: float, mode: str) -> float:
        """The runtime's re-anchoring tolerance, rad: ``velocity`` in velocity mode, ``position``
        otherwise; inf with any PD joint (a low-gain PD lags its targets by design)."""
        if self.pd.any():
            return np.inf
        return velocity if mode == "velocity" else position


def uniform_targets(kind, robot) -> DriveTargets:
    """:class:`DriveTargets` of ``kind``'s choices (``pd_targets``, ``hard_limit_bounce``,
    ``holds_self_collision``, ``joint_input``), the same for every joint of ``robot``."""
    pd = np.full(robot.n_joints, bool(kind.pd_targets))
    return DriveTargets(pd, kind.hard_limit_bounce, kind.holds_self_collision, kind.joint_input)
