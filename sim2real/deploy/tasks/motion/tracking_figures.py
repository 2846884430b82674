"""The judgement of a :class:`~sim2real.deploy.tasks.motion.tracking.TrackingTask` as a part of
its state dict: what a resumed soak needs to report the plays as an uninterrupted one."""

from __future__ import annotations

import numpy as np


class TrackingFigures:
    """The state of a :class:`~sim2real.deploy.tasks.motion.tracking.TrackingTask`'s judgement,
    as a part of its state dict (:mod:`sim2real.deploy.core.stateful`; the arrays:
    :meth:`~sim2real.deploy.tasks.motion.tracking.TrackingTask.judged_arrays`): what a resumed
    soak needs to report the plays as an uninterrupted one.

    Fields (the env axis kept): ``progress``, ``sq_error``, ``anchor_sum``, ``anchor_max``,
    ``ticks``, ``mpjpe_sum``, ``waited``, ``heading`` (the task's attributes), ``play``
    (envs, 12): the play under way's sums (squared joint error, ticks, interventions, safety
    interventions, anchor error, MPJPE, the rest's interventions and safety interventions, the
    play's hard-limit and any-violation ticks, the rest's), ``handed_over`` (envs,) and
    ``after_counts`` (envs, 3) (the task's), ``seen`` (envs, 2): the intervention counts at the
    last tick, ``vseen`` (envs, 2): the violation monitor's hard-limit and any-violation ticks
    at the last tick, ``peak`` (envs, n) degC: the play's hottest windings; ``play_log``: JSON
    text of the envs' ended plays (the task's ``play_log``); ``clock_now``: s, the
    runtime's time at the last tick (the batch's).
    """

    def __init__(self, task):  # the TrackingTask (not imported: it imports this module)
        self.task = task

    def _fields(self) -> dict[str, np.ndarray]:
        return self.task.judged_arrays()

    def state_dict(self, env: int | None = None) -> dict:
        """The fields (class docstring) of every env, or of env ``env``."""
        from sim2real.deploy.core.stateful import env_list, take, to_json

        out: dict = take(self._fields(), env)
        envs = env_list(self.task.envs, env)
        out["play_log"] = to_json([self.task.play_log[e] for e in envs])
        out["clock_now"] = self.task.clock_now
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`; a state that does not fit changes nothing.

        Raises:
            StateDictError: a field missing, shaped otherwise, or a play log that is not a list
                per env (named).
        """
        from sim2real.deploy.core.stateful import check, env_list, put, read_records, scalar

        fields = self._fields()
        check(fields, state, env)
        envs = env_list(self.task.envs, env)
        logs = read_records(state, ["play_log"], len(envs))["play_log"]
        now = scalar(state, "clock_now", float)
        put(fields, state, env)
        for e, log in zip(envs, logs, strict=True):
            self.task.play_log[e] = list(log)
        self.task.clock_now = now
