"""The base estimate against the simulator's truth, and the falls the truth saw (simulation only).

A policy trained in simulation observed the simulator's base state; through the runtime it gets
the base estimator's (:mod:`sim2real.deploy.estimation.base`). :class:`EstimationMonitor` measures the
difference on every RUNNING tick of a floating-base robot in simulation:

- attitude error: the angle (deg) between the estimated and the true projected gravity (roll and
  pitch; yaw is unobserved and not a policy input), mean and 95th percentile;
- base velocity: the mean estimated and true forward speed (base frame x, m/s), the bias of the
  estimate as a fraction of the true mean speed, and the RMS of the planar (x, y) error.

It also watches the true base for a fall the runtime may not have seen (a robot whose feet fell
through the floor with it keeps its kinematic height): the base below ``TRUE_FALL_HEIGHT`` of its
standing height above the ground under it (a plant on terrain; else z = 0), or tilted past the
robot's ``safety.fall_tilt`` (default ``FALL_TILT``), while RUNNING, counts a true fall once
until the robot is up again; a low base an operator asked for (``Runtime.lying_expected``: lying
down, standing up from the floor) is no fall, a tilt is.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.attitude import tilt_of
from sim2real.deploy.core.state import BaseState
from sim2real.deploy.core.stateful import check, put, take
from sim2real.deploy.estimation.fall import FALL_TILT

#: Fraction of ``[base] standing_height`` under which the true base has fallen (our choice: a
#: walking humanoid's base stays above 0.9 of it, a Go2's trot at 0.57; lying, below 0.3).
TRUE_FALL_HEIGHT = 0.4
#: Histogram of attitude errors: bin width and count (deg; 0.01 deg up to 90 deg).
BIN_DEG = 0.01
BINS = 9000


class EstimationMonitor:
    """Estimation error and true falls of ``envs`` floating-base robots in simulation, per env.

    Args:
        robot: A floating-base robot (``standing_height``, ``safety.fall_tilt``).
        envs: Batch size.

    Attributes:
        ticks: int, RUNNING env-ticks measured (all envs).
        true_falls: (envs,) int64, falls of the true base (module docstring).
        counts: (envs, BINS + 1) int64, the attitude errors' histogram (``BIN_DEG`` wide bins,
            the last one everything past 90 deg).
        sums: (envs, 7) float64, per env: attitude error (deg), estimated and true forward
            speed (m/s), planar squared error (m^2/s^2), ticks, vertical error (m/s) and its
            square, each summed over RUNNING ticks.
    """

    def __init__(self, robot, envs: int):
        self.envs = envs
        self.fall_height = TRUE_FALL_HEIGHT * float(robot.config.base.standing_height)
        tilt = robot.config.safety.fall_tilt
        self.fall_tilt = float(FALL_TILT if tilt is None else tilt)
        self.counts = np.zeros((envs, BINS + 1), dtype=np.int64)
        self.sums = np.zeros((envs, 7))
        self.true_falls = np.zeros(envs, dtype=np.int64)
        self._down = np.zeros(envs, dtype=bool)
        self._truth = BaseState.zeros(envs)  # filled from the plant's truth every update
        #: ``ground(truth) -> (envs,) m``: the ground's height under each true base (a plant on
        #: terrain's ``ground_height``); None: the plane z = 0
        self.ground = None
        self.compiled = True  # False: numpy's path only (the reference of the kernels)
        self._calls = None  # the kernels bound to the arrays of one runtime (see _bound)
        from sim2real.deploy.monitors.estimation_kernel import load

        load()  # the kernels ready before the first tick

    def __getstate__(self) -> dict:
        """A copy (``copy.deepcopy``, pickle) binds its kernels afresh: the bound call names the
        runtime's arrays, which a copy of the monitor alone does not share."""
        return self.__dict__ | {"_calls": None}

    @property
    def ticks(self) -> int:
        return int(self.sums[:, 4].sum())

    def _fields(self) -> dict[str, np.ndarray]:
        return {
            "counts": self.counts,
            "sums": self.sums,
            "true_falls": self.true_falls,
            "down": self._down,
        }

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """``counts``, ``sums``, ``true_falls`` and ``down`` (the true base down since its last
        RUNNING tick), copies (conventions of :mod:`sim2real.deploy.core.stateful`)."""
        return take(self._fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`.

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        check(self._fields(), state, env)
        put(self._fields(), state, env)

    def update(self, runtime, truth: np.ndarray) -> None:
        """After a tick: ``truth`` (envs, 13), the plant's ``true_base_state()``. The compiled
        kernels (:mod:`sim2real.deploy.monitors.estimation_kernel`) do it when they fit (a
        float64 C-contiguous ``truth``, the runtime's arrays the bound ones, ``compiled``),
        numpy otherwise; the same numbers either way. With :attr:`ground` the base's height is
        judged above the ground under it."""
        if self.ground is not None:
            truth = truth.copy()
            truth[:, 2] -= self.ground(truth)
        call = self._bound(runtime, truth)
        if call is not None:
            call(0, truth)  # the true base, the arc cosines' arguments
            np.arccos(self._arg, out=self._angle)
            if call(1, truth) >= 0:
                return
            base, true_base = runtime.state.base, self._truth
            running = runtime.mode == 2
            self._errors(base, true_base, np.flatnonzero(running))  # raises as numpy does
            return
        self.reference_update(runtime, truth)

    def _bound(self, runtime, truth):
        """The compiled update's call for ``runtime`` (``monitor_stage`` bound to its table),
        or None (numpy's path)."""
        if not self.compiled or type(truth) is not np.ndarray:
            return None
        if truth.dtype != np.float64 or not truth.flags.c_contiguous:
            return None
        if truth.shape != (self.envs, 13):
            return None
        base, calls = runtime.state.base, self._calls
        lying = getattr(runtime, "lying_expected", None)
        if calls is not None:
            mode, gravity, velocity, world, kept_lying, call = calls
            if (
                mode is runtime.mode
                and gravity is base.projected_gravity
                and velocity is base.linear_velocity
                and world is base.linear_velocity_world
                and kept_lying is lying
            ):
                return call
        self._calls = None
        from sim2real.deploy.monitors.estimation_kernel import gemv_matches

        arrays = (base.projected_gravity, base.linear_velocity, base.linear_velocity_world)
        if not gemv_matches():
            return None
        self._calls = (runtime.mode, *arrays, lying, self._bind(runtime, lying))
        return self._calls[-1]

    def _bind(self, runtime, lying):
        """``monitor_stage`` bound to a table of the runtime's arrays and the monitor's (None
        where one does not fit it)."""
        from sim2real.deploy.kernels.calls import bind
        from sim2real.deploy.monitors import estimation_kernel as ek

        base, t, envs = runtime.state.base, self._truth, self.envs
        self._arg, self._angle = np.zeros((2, envs)), np.zeros((2, envs))
        table = ek.MONITOR.pack_or_none(
            fused=ek.gemv_fused(), has_lying=lying is not None, bins=BINS,
            fall_height=self.fall_height, fall_tilt=self.fall_tilt, bin_deg=BIN_DEG,
            orientation=t.orientation, gravity=t.projected_gravity, angular=t.angular_velocity,
            velocity_world=t.linear_velocity_world, velocity=t.linear_velocity,
            g_est=base.projected_gravity, v_est=base.linear_velocity,
            vw_est=base.linear_velocity_world, arg=self._arg, angle=self._angle,
            mode=runtime.mode, lying=np.zeros(envs, dtype=bool) if lying is None else lying,
            true_falls=self.true_falls, down=self._down, counts=self.counts, sums=self.sums,
        )  # fmt: skip
        return None if table is None else bind(ek.monitor_stage, table, rest=(0, np.zeros((1, 13))))

    def reference_update(self, runtime, truth: np.ndarray) -> None:
        """:meth:`update` by numpy (the kernels' reference)."""
        true_base = self._truth.set_truth(truth)
        g_true = true_base.projected_gravity
        running = runtime.mode == 2  # RUNNING
        low = truth[:, 2] < self.fall_height
        asked = getattr(runtime, "lying_expected", None)  # an operator laying the robot down
        if asked is not None:
            low &= ~asked
        down = low | (tilt_of(g_true) > self.fall_tilt)
        self.true_falls += down & ~self._down & running
        self._down[:] = down | (self._down & ~running)
        if not running.any():
            return
        self._errors(runtime.state.base, true_base, np.flatnonzero(running))

    def _errors(self, base, true_base, envs: np.ndarray) -> None:
        """Add the errors of the RUNNING envs ``envs`` (numpy)."""
        g_true, v_true = true_base.projected_gravity, true_base.linear_velocity
        g_est = base.projected_gravity[envs]
        g_est = g_est / np.linalg.norm(g_est, axis=1, keepdims=True)
        cos = np.clip((g_est * g_true[envs]).sum(axis=1), -1.0, 1.0)
        deg = np.degrees(np.arccos(cos))
        np.add.at(self.counts, (envs, np.minimum((deg / BIN_DEG).astype(np.int64), BINS)), 1)
        v_est = base.linear_velocity[envs]
        err = v_est[:, :2] - v_true[envs, :2]
        vertical = base.linear_velocity_world[envs, 2] - true_base.linear_velocity_world[envs, 2]
        self.sums[envs] += np.stack(
            [
                deg,
                v_est[:, 0],
                v_true[envs, 0],
                (err**2).sum(axis=1),
                np.ones(len(envs)),
                vertical,
                vertical**2,
            ],
            axis=1,
        )

    def summary(self, env: int | None = None) -> dict | None:
        """``{"ticks", "attitude_error_deg": {"mean", "p95"}, "forward_speed_m_s": {"estimated",
        "true"}, "velocity_bias_fraction", "velocity_rms_m_s", "vertical_velocity_m_s": {"bias",
        "rms"}, "true_falls"}`` over every env, or env ``env``; None before any RUNNING tick (the
        figures are then unknown, not zero). The bias is None when the true mean forward speed
        is under 0.05 m/s (a fraction of standing still means nothing)."""
        sel = slice(None) if env is None else slice(env, env + 1)
        total = self.sums[sel].sum(axis=0)
        n = total[4]
        if n == 0:
            return None
        cum = np.cumsum(self.counts[sel].sum(axis=0))
        p95 = (np.searchsorted(cum, 0.95 * cum[-1]) + 0.5) * BIN_DEG
        est, true = total[1] / n, total[2] / n
        return {
            "ticks": int(n),
            "attitude_error_deg": {"mean": total[0] / n, "p95": float(p95)},
            "forward_speed_m_s": {"estimated": est, "true": true},
            "velocity_bias_fraction": (est / true - 1.0) if abs(true) >= 0.05 else None,
            "velocity_rms_m_s": float(np.sqrt(total[3] / n)),
            "vertical_velocity_m_s": {
                "bias": total[5] / n,
                "rms": float(np.sqrt(total[6] / n)),
            },
            "true_falls": int(self.true_falls[sel].sum()),
        }
