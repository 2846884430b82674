"""The velocity-command task of a legged robot: a fixed command, a schedule of commands or neither,
and the :class:`~sim2real.deploy.tasks.locomotion.CommandTracker` judging it.

:func:`sim2real.deploy.tasks.task.task_for` builds it for ``deploy-run`` and the soak;
:mod:`sim2real.deploy.tasks.commands` draws the scheduled commands and
:mod:`sim2real.deploy.tasks.locomotion` measures how well the robot follows them.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.stateful import load_parts, parts_state_dict
from sim2real.deploy.tasks.commands import CommandRanges, CommandSchedule
from sim2real.deploy.tasks.locomotion import CommandTracker


class VelocityTask:
    """The velocity-command task (:class:`sim2real.deploy.tasks.task.Task`) of a legged robot: a fixed
    command, a :class:`CommandSchedule` or neither (the command the runtime holds), and a
    :class:`CommandTracker` judging it.

    Args:
        envs, control_period, backend, window: The tracker's (:class:`CommandTracker`).
        period: s between scheduled commands.
        rng: ``envs`` generators: a :class:`CommandSchedule` on them; None: no schedule.
        command: Optional fixed command (3,), written at :meth:`reset` (no schedule then).
        heading_gain: 1/s: with a fixed command whose yaw rate is zero, hold the heading
            (:class:`sim2real.deploy.tasks.heading.HeadingHold`, this gain); 0: the command as given.
        ranges: The schedule's :class:`CommandRanges` (default its defaults).

    Attributes:
        heading: The :class:`~sim2real.deploy.tasks.heading.HeadingHold` (checkpoint prefix
            ``heading``) or None.
        schedule: The :class:`CommandSchedule` (checkpoint prefix ``commands``) or None.
        tracker: The :class:`CommandTracker` (checkpoint prefix ``tracker``).
    """

    name = "locomotion"

    def __init__(
        self,
        envs,
        control_period,
        backend,
        period,
        rng,
        command=None,
        window=None,
        heading_gain: float = 0.0,
        ranges: CommandRanges | None = None,
    ):
        self.command = command
        self.schedule = None
        if command is None and rng is not None:
            self.schedule = CommandSchedule(envs, period, rng, ranges)
        self.heading = None
        if command is not None and heading_gain > 0 and command[2] == 0.0:
            from sim2real.deploy.tasks.heading import HeadingHold

            self.heading = HeadingHold(envs, heading_gain)
            #: (envs, 3) the command asked (vx m/s, vy m/s, yaw rate rad/s) that the heading
            #: hold turns into the runtime's command (only with a heading hold)
            self.asked = np.tile(command, (envs, 1))
        self.tracker = CommandTracker(envs, control_period, backend, window=window)
        self._call = None  # the tracker's and the hold's kernels as one table (_compiled_call)
        if self.tracker.truth is not None:
            from sim2real.deploy.tasks.velocity_kernel import load

            load()  # the kernels ready before the first tick

    def __getstate__(self) -> dict:
        """A copy (``copy.deepcopy``, pickle) binds its kernels afresh: the bound call's table
        names the original's arrays."""
        return self.__dict__ | {"_call": None}

    def reset(self, runtime, envs: np.ndarray) -> None:
        """Write the fixed command, if any, for the envs of ``envs``."""
        if self.command is not None:
            runtime.velocity_command[envs] = self.command

    def __call__(self, runtime, truth: np.ndarray | None = None) -> None:
        """One tick: the schedule's command, the tracker, the hold (in that order); judged on
        the plant's truth (``truth``: this tick's ``true_base_state()`` when the caller read
        it, else read here), the tracker's and the hold's kernels over one table
        (:class:`~sim2real.deploy.tasks.velocity_kernel.TaskCall`, the same numbers)."""
        if self.schedule is not None:
            self.schedule(runtime)
        call = self._compiled_call(runtime)
        if call is not None:
            truth = self.tracker.truth() if truth is None else truth
            if type(truth) is np.ndarray and truth.dtype == np.float64:
                if truth.shape == (self.tracker.envs, 13) and truth.flags.c_contiguous:
                    call(runtime, truth)
                    return
        if self.heading is not None:
            self.tracker(runtime, self.asked)
            self.heading(runtime, self.asked)
        else:
            self.tracker(runtime)

    def _compiled_call(self, runtime):
        """The tracker's and the hold's kernels bound to ``runtime``'s arrays (built again when
        they change), or None: the separate calls (a tracker or a hold on numpy's path, a
        tracker not judged on the truth or with success windows, an array that does not fit)."""
        tracker, heading = self.tracker, self.heading
        if not (tracker.compiled and tracker.truth is not None and tracker.success_window is None):
            return None
        if heading is not None and not heading.compiled:
            return None
        call = self._call
        if call is None or not call.ready(runtime):
            from sim2real.deploy.tasks.velocity_kernel import TaskCall

            call = self._call = TaskCall.build(self, runtime)
        return call if call.fits else None

    def success(self, env: int | None = None) -> float | None:
        """Tracking success: RUNNING time within tolerance / RUNNING time; None before any."""
        tr = self.tracker
        running = float(tr.running_time.sum() if env is None else tr.running_time[env])
        tracked = float(tr.tracked_time.sum() if env is None else tr.tracked_time[env])
        return tracked / running if running else None

    def report(self, runtime) -> dict:
        loco = self.tracker.summary(runtime)
        if self.heading is not None:
            loco["command"] = self.asked.tolist()
            loco["heading_hold_gain"] = self.heading.gain
        return {"goals": None, "locomotion": loco, "missed_goals": 0}

    def curve_start(self) -> dict[str, list]:
        curve = {"commands": [0], "falls": [0], "distance_m": [0.0]}
        return curve | {"running_s": [0.0], "tracked_s": [0.0]}

    def curve_point(self, curve: dict[str, list], e: int) -> None:
        tr = self.tracker
        issued = self.schedule.issued[e] if self.schedule is not None else 0
        curve["commands"].append(int(issued))
        curve["falls"].append(int(tr.falls[e]))
        curve["distance_m"].append(float(tr.distance[e]))
        curve["running_s"].append(float(tr.running_time[e]))
        curve["tracked_s"].append(float(tr.tracked_time[e]))

    def parts(self) -> dict:
        """The task's stateful parts by checkpoint prefix."""
        parts = {"commands": self.schedule} if self.schedule is not None else {}
        if self.heading is not None:
            parts["heading"] = self.heading
        return parts | {"tracker": self.tracker}

    def state_dict(self, env: int | None = None) -> dict:
        return parts_state_dict(self.parts(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        load_parts(self.parts(), state, env)
