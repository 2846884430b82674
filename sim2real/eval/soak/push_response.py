"""The base estimate through a push: its planar velocity error in the second after each of the
training domain's pushes (:class:`sim2real.eval.world.pushes.DomainPushes`), against the plant's
truth, beside the steady figures of :class:`sim2real.deploy.monitors.estimation.EstimationMonitor`.

A policy reads its base velocity from the estimator, which integrates the accelerometer: a push
it does not measure well is a push the policy answers late. Per env, over the RUNNING ticks of
the ``AFTER_PUSH`` s that follow each push (the push's own tick excluded: its force acts from the
next physics step), the error ``|v_est - v_true|`` of the base-frame planar velocity (m/s, x
and y, as ``velocity_rms_m_s`` measures it) is summed; a push's second ends at its last tick or
at the next push. The truth is the base's at the time of the frame the estimate was made from
(the plant's state at the end of the tick before, which its sensors sampled), not after the
tick's own physics: during a push the truth one control period later has moved on by the push's
acceleration times the period, a difference no estimator of that frame can know. Call it
after each tick, before that tick's pushes are applied (the truth it keeps for the next tick is
the one the next frame samples). Simulation only (the truth).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.state import BaseState

#: s after a push whose estimate is judged ("the second after a push").
AFTER_PUSH = 1.0
#: Columns of :attr:`PushResponse.sums`.
TICKS, SUM, SQUARES, WORST, PUSHES, WORST_PUSH, OPEN_SUM, OPEN_TICKS = range(8)


class PushResponse:
    """The planar base-velocity error after each push of ``pushes``, per env (module docstring).

    Args:
        pushes: The batch's :class:`~sim2real.eval.world.pushes.DomainPushes` (its
            ``last_tick``: each env's last push).
        control_period: s per tick.

    Attributes:
        window: ticks judged after a push (``AFTER_PUSH`` rounded, at least one).
        sums: (envs, 8) float64: ticks judged, the error's sum (m/s) and squares' sum
            (m^2/s^2), the worst tick's error (m/s), pushes judged, the worst push's mean error
            (m/s), and the open push's error sum and ticks (columns ``TICKS`` ... ``OPEN_TICKS``).
        measured: (envs,) int64, the tick of the last push seen (-1: none).
        open: (envs,) bool, whether that push's second is still being judged.
        frame_truth: (envs, 13) the true base state (``true_base_state``'s layout) at the end of
            the last tick, which the next tick's frame samples (NaN before the first call).
    """

    def __init__(self, pushes, control_period: float):
        self.pushes = pushes
        envs = len(pushes.seeds)
        self.window = max(1, round(AFTER_PUSH / control_period))
        self.sums = np.zeros((envs, 8))
        self.measured = np.full(envs, -1, dtype=np.int64)
        self.open = np.zeros(envs, dtype=bool)
        self.frame_truth = np.full((envs, 13), np.nan)
        self._now = np.empty((envs, 13))
        self._truth = BaseState.zeros(envs)

    def __call__(self, rt, backend) -> None:
        """After a tick of ``rt`` (a runtime over the simulated ``backend``), before its pushes."""
        now = backend.true_base_state(out=self._now)
        try:
            self._judge(rt)
        finally:
            self.frame_truth[:] = now

    def _judge(self, rt) -> None:
        """Add the judged envs' errors of this tick (against :attr:`frame_truth`)."""
        last = self.pushes.last_tick
        if not (last >= 0).any():
            return
        age = rt.ticks - last
        new = (last >= 0) & (last != self.measured)
        if new.any():  # a new push: the previous one's second ends here
            for e in np.flatnonzero(new & self.open):
                self._close(e)
            self.measured[new] = last[new]
            self.open[new] = True
        if not self.open.any():
            return
        known = np.isfinite(self.frame_truth).all(axis=1)
        judged = self.open & (age >= 1) & (age <= self.window) & (rt.mode == 2) & known
        if judged.any():
            truth = np.where(known[:, None], self.frame_truth, self._now)  # no NaN into set_truth
            base = self._truth.set_truth(truth)
            error = rt.state.base.linear_velocity[:, :2] - base.linear_velocity[:, :2]
            norm = np.sqrt((error**2).sum(axis=1))
            s = self.sums
            for e in np.flatnonzero(judged):
                s[e, TICKS] += 1
                s[e, SUM] += norm[e]
                s[e, SQUARES] += norm[e] ** 2
                s[e, WORST] = max(s[e, WORST], norm[e])
                s[e, OPEN_SUM] += norm[e]
                s[e, OPEN_TICKS] += 1
        for e in np.flatnonzero(self.open & (age >= self.window)):
            self._close(e)

    def _close(self, e: int) -> None:
        """End the judged push of env ``e`` (its mean into the worst push's)."""
        s = self.sums[e]
        if s[OPEN_TICKS] > 0:
            s[PUSHES] += 1
            s[WORST_PUSH] = max(s[WORST_PUSH], s[OPEN_SUM] / s[OPEN_TICKS])
        s[OPEN_SUM] = s[OPEN_TICKS] = 0.0
        self.open[e] = False

    def summary(self, env: int | None = None) -> dict | None:
        """``{"pushes", "ticks", "mean_m_s", "rms_m_s", "worst_m_s", "worst_push_mean_m_s",
        "window_s"}`` over every env, or env ``env``: the pushes judged (those whose second has
        ended), the RUNNING ticks judged, the error's mean, RMS and worst tick, the worst push's
        mean (m/s); None before any judged tick."""
        rows = self.sums if env is None else self.sums[env : env + 1]
        n = rows[:, TICKS].sum()
        if n == 0:
            return None
        return {
            "pushes": int(rows[:, PUSHES].sum()),
            "ticks": int(n),
            "mean_m_s": float(rows[:, SUM].sum() / n),
            "rms_m_s": float(np.sqrt(rows[:, SQUARES].sum() / n)),
            "worst_m_s": float(rows[:, WORST].max()),
            "worst_push_mean_m_s": float(rows[:, WORST_PUSH].max()),
            "window_s": AFTER_PUSH,
        }

    def state_dict(self, env: int) -> dict:
        """Env ``env``'s ``sums``, ``measured``, ``open`` and ``frame_truth`` as JSON (a list, an
        int, a bool, a list of 13 numbers or None before the first call)."""
        truth = self.frame_truth[env]
        return {
            "sums": self.sums[env].tolist(),
            "measured": int(self.measured[env]),
            "open": bool(self.open[env]),
            "frame_truth": truth.tolist() if np.isfinite(truth).all() else None,
        }

    def load_state_dict(self, state: dict, env: int) -> None:
        """Inverse of :meth:`state_dict` (a state without ``frame_truth``, from a checkpoint of
        an earlier version: the next tick is not judged)."""
        self.sums[env] = np.asarray(state["sums"], dtype=float)
        self.measured[env] = int(state["measured"])
        self.open[env] = bool(state["open"])
        truth = state.get("frame_truth")
        self.frame_truth[env] = np.nan if truth is None else np.asarray(truth, dtype=float)
