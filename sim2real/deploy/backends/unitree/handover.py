"""The hand-over from the bring-up's stand to the policy on a Unitree robot's drivers
(:class:`StandHandover`, kept by :class:`~sim2real.deploy.backends.unitree.backend.UnitreeBackend`).

Until the policy runs (the runtime's env 0 not RUNNING: IDLE, RAMP_IN), a position command goes
out at the stand's gains (robot.toml ``[unitree] ramp_kp``/``ramp_kd``, the bring-up's). From the
policy's first command, for ``bringup.BLEND_TIME``, the driver's PD law is the sum of two: the
stand's (the last target sent before the policy, at the stand's gains, weight ``1 - a``) and the
policy's (its target at the joints' gains, weight ``a``, ``a`` rising linearly from 0 to 1), sent
as one law: ``kp = (1 - a) kp_stand + a kp``, its target the gain-weighted mean of the two targets,
``kd`` alike (both damp toward 0 rad/s). Unitree's deploy programs stand the same way: their
FixStand gains until the policy's state sets its own (unitree_rl_mjlab deploy/robots/g1/config/
config.yaml). A policy whose gains cannot hold the home pose alone (a G1's waist pitch) otherwise
took the robot's weight during RAMP_IN with no policy to balance it, and a policy's first actions
sent at the stand's gains (up to 7x a G1's waist kp) swung its waist into its limits.

Without the runtime's modes (:meth:`StandHandover.watch`: a program of its own on the backend),
the hand-over starts at the first command. Units: rad, N m/rad, N m s/rad, s.
"""

from __future__ import annotations

import time

import numpy as np

from sim2real.deploy.backends.unitree.bringup import BLEND_TIME
from sim2real.deploy.core.modes import RUNNING


class StandHandover:
    """The gains and target of each position command around the policy's start (module
    docstring).

    Args:
        stand_kp, stand_kd: (n,) the stand's gains (``[unitree] ramp_kp``/``ramp_kd``).
        kp, kd: (n,) the joints' (the policy's) gains.
        home: (n,) rad, the stand's target when no command preceded the policy's first.
        speeds: (n,) bool, the velocity-driven joints (wheels): their target is a speed, sent
            as it is, never blended with a pose. None: none.
    """

    def __init__(self, stand_kp, stand_kd, kp, kd, home, speeds=None):
        n = len(home)
        self.speeds = np.zeros(n, dtype=bool) if speeds is None else np.asarray(speeds, bool)
        self.stand_kp, self.stand_kd = np.asarray(stand_kp), np.asarray(stand_kd)
        self.kp, self.kd = np.asarray(kp), np.asarray(kd)
        self.home = np.asarray(home, dtype=np.float64).copy()
        #: the runtime's (envs,) mode array, read only; None: not watched
        self.modes: np.ndarray | None = None
        #: time.monotonic() of the policy's first command while blending, else None
        self.started: float | None = None
        self.policy = False  # the policy's first command was sent (blending or blended)
        self.stand = self.home.copy()  # the stand's target during the blend

    def watch(self, mode: np.ndarray) -> None:
        """Follow the runtime's (envs,) mode array ``mode`` (:mod:`sim2real.deploy.core.modes`;
        read, never written): the stand holds until env 0 is RUNNING."""
        self.modes = mode

    def command(self, last: np.ndarray | None) -> None:
        """A command of the runtime is about to go out; ``last`` the target sent before it
        (rad, (n,); None: none). Starts the blend at the policy's first command."""
        running = self.modes is None or self.modes[0] == RUNNING
        if running and not self.policy:
            self.started = time.monotonic()
            self.stand = self.home.copy() if last is None else np.array(last, dtype=np.float64)
        self.policy = running

    def law(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(position target, kp, kd), each (n,), that send ``target`` (rad, (n,)) now (module
        docstring)."""
        if not self.policy:
            return target, self.stand_kp, self.stand_kd
        if self.started is None:
            return target, self.kp, self.kd
        a = (time.monotonic() - self.started) / BLEND_TIME
        if a >= 1.0:
            self.started = None
            return target, self.kp, self.kd
        stand, policy = (1 - a) * self.stand_kp, a * self.kp
        kp = stand + policy
        blended = (stand * self.stand + policy * target) / kp
        return (
            np.where(self.speeds, target, blended),
            kp,
            (1 - a) * self.stand_kd + a * self.kd,
        )
