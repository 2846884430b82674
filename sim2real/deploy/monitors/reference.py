"""The numpy references of the monitors' kernels (:mod:`sim2real.deploy.monitors.kernel`), as subclasses
with the same constructors: :class:`ReferenceInterventionMonitor` compares the counters in numpy
(:func:`~sim2real.deploy.monitors.kernel.counters_moved`), :class:`ReferenceViolationMonitor` screens in
numpy (:func:`~sim2real.deploy.monitors.kernel.violation_screen`) and checks every env's collision pairs
with coal (no :func:`~sim2real.deploy.monitors.kernel.collision_screen`). Both count the same as the
compiled monitors (``tests/test_monitors.py``).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.monitors.interventions import InterventionMonitor
from sim2real.deploy.monitors.violations import ViolationMonitor
from sim2real.deploy.safety.collision import collision_query


class ReferenceInterventionMonitor(InterventionMonitor):
    """An :class:`~sim2real.deploy.monitors.interventions.InterventionMonitor` that compares the counters
    in numpy; the same arguments, attributes and counts."""

    def _moved(self) -> bool:
        """Whether a counter moved, in numpy: the reference of
        :func:`sim2real.deploy.monitors.kernel.counters_moved`."""
        np.not_equal(self._guard_rows, self._prev_guard, out=self._guard_changed)
        changed = np.count_nonzero(self._guard_changed)
        for i, (_, counter) in enumerate(self._smoother):
            np.not_equal(counter, self._prev_smoother[i], out=self._smoother_changed)
            changed += np.count_nonzero(self._smoother_changed)
        return bool(changed)


class ReferenceViolationMonitor(ViolationMonitor):
    """A :class:`~sim2real.deploy.monitors.violations.ViolationMonitor` that screens in numpy and checks
    every env's collision pairs; the same arguments, attributes and counts."""

    def _screen(self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray) -> bool:
        """:func:`sim2real.deploy.monitors.kernel.violation_screen` in numpy: its reference."""
        np.subtract(q, self._offset_q, out=self._q_part)
        np.copyto(self._dq_part, dq)
        np.copyto(self._tau_part, tau)
        if self._has_workspace:
            np.subtract(self._ee, self._offset_ee, out=self._ee_part)
        np.abs(self._buf, out=self._buf)
        np.greater(self._buf, self._bound, out=self._mask)
        return bool(np.count_nonzero(self._mask))

    def _collision_screen(self, q: np.ndarray) -> bool:
        """Every env's pairs are checked: no screen."""
        self._need.fill(True)
        return True

    def _in_collision(self, q: np.ndarray, e: int) -> bool:
        """Whether a collision pair of env ``e`` touches at ``q[e]`` (coal)."""
        args = (self._model, self._data, self._geom_model, self._geom_data, q[e])
        return collision_query(*args)
