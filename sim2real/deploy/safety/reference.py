"""The numpy reference of the guard: :class:`ReferenceGuard`, the guard with every check's
:meth:`~sim2real.deploy.safety.check.GuardCheck.reference` in place of the compiled kernel.

Both give the same targets, counters and state bit for bit (tests/test_safety.py,
tests/test_compiled_tick.py). The reference reads its bounds from the guard's attributes on every
tick, so a test may widen them (``sweep``, ``ee_lever``, ``gravity_bound``, ``pair_weights``) to
make it check every env every tick.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.safety.check import CLAMP, FINAL, INSPECT, PREDICTED
from sim2real.deploy.safety.checks import GUARD_CHECKS
from sim2real.deploy.safety.guard import SafetyGuard


class ReferenceGuard(SafetyGuard):
    """:class:`~sim2real.deploy.safety.guard.SafetyGuard` run in numpy (same arguments: ``robot``,
    ``envs``, ``mode``)."""

    def _warm_up(self) -> None:
        """Nothing to compile."""

    def _stage(self, stage: int, fired, needs, out, q, dq, commanded) -> None:
        """Run ``stage`` through every check (count-row order): ``fired``, ``needs``
        (checks, envs) bool, or-ed with each check's answer."""
        for k, check in enumerate(GUARD_CHECKS):
            f, n = check.reference(stage, self, out, q, dq, commanded)
            if f is not None:
                fired[k] |= f
            if n is not None:
                needs[k] |= n

    def _filter(self, q: np.ndarray, dq: np.ndarray, commanded: np.ndarray | None, out):
        """:meth:`SafetyGuard.filter` in numpy: the stages of :mod:`sim2real.deploy.safety.check`."""
        for k, r in enumerate(self._geometric_rows):  # the rows check_motion shares
            self._counted[k] = self.count_matrix[r]
        fired = np.zeros((len(GUARD_CHECKS), self.envs), dtype=bool)
        needs = np.zeros_like(fired)
        self._held[:] = False
        self._stage(INSPECT, fired, needs, out, q, dq, commanded)
        self._stage(CLAMP, fired, needs, out, q, dq, commanded)
        if self.mode == "position":  # the predicted next state
            self._pred[:] = out
        elif self.mode == "velocity":
            np.multiply(out, self.dt, out=self._pred)
            self._pred += q
        else:
            np.multiply(dq, self.dt, out=self._pred)
            self._pred += q
        self._stage(PREDICTED, fired, needs, out, q, dq, commanded)
        self.count_matrix += fired
        stops = np.flatnonzero(self._arrays.stops)  # SafetyGuard.set_stopping may change them
        np.any(fired[stops], axis=0, out=self.hard_violation)
        self._resolve(needs, q, dq, out)
        if self.mode == "position":
            keep = ~self._held
            self._last_valid[keep] = out[keep]
        fired[:] = False
        self._stage(FINAL, fired, needs, out, q, dq, commanded)
        self.count_matrix += fired
        return out
