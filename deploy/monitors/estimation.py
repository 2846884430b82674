"""The base estimate against the simulator's truth, and the falls the truth saw (simulation only).

A policy trained in simulation observed the simulator's base state; through the runtime it gets
the base estimator's (:mod:`deploy.estimation.base`). :class:`EstimationMonitor` measures the
difference on every RUNNING tick of a floating-base robot in simulation:

- attitude error: the angle (deg) between the estimated and the true projected gravity (roll and
  pitch; yaw is unobserved and not a policy input), mean and 95th percentile;
- base velocity: the mean estimated and true forward speed (base frame x, m/s), the bias of the
  estimate as a fraction of the true mean speed, and the RMS of the planar (x, y) error.

It also watches the true base for a fall the runtime may not have seen (a robot whose feet fell
through the floor with it keeps its kinematic height): the base below ``TRUE_FALL_HEIGHT`` of its
standing height, or tilted past the robot's ``safety.fall_tilt`` (default ``FALL_TILT``), while
RUNNING, counts a true fall once until the robot is up again.
"""

from __future__ import annotations

import numpy as np

from deploy.estimation.base import BaseState
from deploy.estimation.fall import FALL_TILT

#: Fraction of ``[base] standing_height`` under which the true base has fallen (our choice: a
#: walking humanoid's base stays above 0.9 of it, a Go2's trot at 0.57; lying, below 0.3).
TRUE_FALL_HEIGHT = 0.4
#: Histogram of attitude errors: bin width and count (deg; 0.01 deg up to 90 deg).
BIN_DEG = 0.01
BINS = 9000


class EstimationMonitor:
    """Estimation error and true falls of ``envs`` floating-base robots in simulation.

    Args:
        robot: A floating-base robot (``standing_height``, ``safety.fall_tilt``).
        envs: Batch size.

    Attributes:
        ticks: int, RUNNING env-ticks measured.
        true_falls: (envs,) int64, falls of the true base (module docstring).
    """

    def __init__(self, robot, envs: int):
        self.envs = envs
        self.fall_height = TRUE_FALL_HEIGHT * float(robot.config.base.standing_height)
        tilt = robot.config.safety.fall_tilt
        self.fall_tilt = float(FALL_TILT if tilt is None else tilt)
        self.counts = np.zeros(BINS + 1, dtype=np.int64)
        self.ticks = 0
        self._sum = np.zeros(5)  # attitude deg, est vx, true vx, planar sq err, n
        self.true_falls = np.zeros(envs, dtype=np.int64)
        self._down = np.zeros(envs, dtype=bool)
        self._truth = BaseState.zeros(envs)  # filled from the plant's truth every update

    def update(self, runtime, truth: np.ndarray) -> None:
        """After a tick: ``truth`` (envs, 13), the plant's ``true_base_state()``."""
        true_base = self._truth.set_truth(truth)
        g_true, v_true = true_base.projected_gravity, true_base.linear_velocity
        running = runtime.mode == 2  # RUNNING
        tilt = np.arccos(np.clip(-g_true[:, 2], -1.0, 1.0))
        down = (truth[:, 2] < self.fall_height) | (tilt > self.fall_tilt)
        self.true_falls += down & ~self._down & running
        self._down = down | (self._down & ~running)
        if not running.any():
            return
        base = runtime.state.base
        g_est = base.projected_gravity[running]
        g_est = g_est / np.linalg.norm(g_est, axis=1, keepdims=True)
        cos = np.clip((g_est * g_true[running]).sum(axis=1), -1.0, 1.0)
        deg = np.degrees(np.arccos(cos))
        np.add.at(self.counts, np.minimum((deg / BIN_DEG).astype(np.int64), BINS), 1)
        v_est = base.linear_velocity[running]
        err = v_est[:, :2] - v_true[running, :2]
        self._sum += [
            deg.sum(),
            v_est[:, 0].sum(),
            v_true[running, 0].sum(),
            (err**2).sum(),
            len(deg),
        ]
        self.ticks += int(running.sum())

    def summary(self) -> dict | None:
        """``{"ticks", "attitude_error_deg": {"mean", "p95"}, "forward_speed_m_s": {"estimated",
        "true"}, "velocity_bias_fraction", "velocity_rms_m_s", "true_falls"}``; None before any
        RUNNING tick (the figures are then unknown, not zero). The bias is None when the true
        mean forward speed is under 0.05 m/s (a fraction of standing still means nothing)."""
        if self.ticks == 0:
            return None
        n = self._sum[4]
        cum = np.cumsum(self.counts)
        p95 = (np.searchsorted(cum, 0.95 * cum[-1]) + 0.5) * BIN_DEG
        est, true = self._sum[1] / n, self._sum[2] / n
        return {
            "ticks": self.ticks,
            "attitude_error_deg": {"mean": self._sum[0] / n, "p95": float(p95)},
            "forward_speed_m_s": {"estimated": est, "true": true},
            "velocity_bias_fraction": (est / true - 1.0) if abs(true) >= 0.05 else None,
            "velocity_rms_m_s": float(np.sqrt(self._sum[3] / n)),
            "true_falls": int(self.true_falls.sum()),
        }
