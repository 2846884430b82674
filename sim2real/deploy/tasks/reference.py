"""The numpy reference of the goal scheduler's kernels (:func:`sim2real.deploy.monitors.kernel.goal_screen`,
``goal_hits``): :class:`ReferenceGoalScheduler`, a :class:`~sim2real.deploy.tasks.goals.GoalScheduler` with
the same constructor whose tick runs in numpy. Both give the same goals, hits, records and state
(``tests/test_monitors.py``).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.tasks.goals import GoalScheduler


class ReferenceGoalScheduler(GoalScheduler):
    """A :class:`~sim2real.deploy.tasks.goals.GoalScheduler` whose tick runs in numpy (module docstring);
    the same arguments, attributes and results."""

    def __call__(self, rt) -> None:
        """:meth:`GoalScheduler.__call__` in numpy: the reference of its kernels."""
        t = rt.time
        running = rt.mode == 2
        if not running.all():  # only RUNNING time counts
            paused = ~running & ~self.reached
            self.t_goal[paused] = t
            if not running.any():
                return
        age = t - self.t_goal
        due = running & (self.issued == 0)
        if self.fixed is None:
            due |= running & (age >= self.period)
        if due.any():
            for e in np.flatnonzero(due):  # in env order (one stream for a batch)
                self.new_goal(rt, e)
        check = running & ~due & ~self.reached & (age <= self.success_time)
        if check.any():
            ee = self.end_effector(rt)
            diff, distance = self._diff, self._distance
            np.subtract(ee, rt.goal, out=diff)
            np.multiply(diff, diff, out=diff)
            np.sum(diff, axis=1, out=distance)
            np.sqrt(distance, out=distance)
            np.minimum(self.best_distance, distance, out=self.best_distance, where=check)
            hit = check & (distance <= self.success_radius)
            self._record_hits(np.flatnonzero(hit), age)
