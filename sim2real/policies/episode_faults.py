"""The soak's faults in training: each episode draws a fault schedule and meets it on its env.

A training episode (:class:`sim2real.policies.envs.ReachTask`,
:class:`sim2real.policies.locomotion.LocomotionTask`) draws its fault schedule from the soak's
:class:`~sim2real.eval.world.fault_schedule.FaultRanges` (the same kinds, weights, magnitudes, durations and
budgets), with only the time between faults shortened to the episode's scale (:func:`training_fault_ranges`):
the soak spaces faults minutes apart, an episode lasts seconds to minutes. :class:`EpisodeFaults` applies each
env's schedule, shifted to its episode's start, through the soak's per-env injectors
(:class:`sim2real.eval.soak.faults.SessionFaults`), and undoes a fault still in force when the episode
ends.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sim2real.eval.soak.faults import SessionFaults
from sim2real.eval.world.fault_schedule import FaultRanges

#: s, no fault before this episode time (our choice; the soak's ``FaultRanges.warmup`` of 10 s
#: would leave a 20-s episode little time for its faults).
FAULT_WARMUP = 1.0


def training_fault_ranges(faults: FaultRanges, interval: float) -> FaultRanges:
    """The soak's fault ranges ``faults`` with ``interval`` (s, > 0) as the mean time between
    faults and :data:`FAULT_WARMUP` as the warmup; everything else is the soak's.

    Raises:
        ValueError: ``interval`` not > 0 (:class:`FaultRanges`).
    """
    return dataclasses.replace(faults, mean_interval=float(interval), warmup=FAULT_WARMUP)


def fault_settings(enabled: bool, ranges: FaultRanges) -> dict:
    """The fault settings of a training run, for its info and curve JSON: ``enabled``, and the
    training ranges' ``mean_interval_s``, ``warmup_s`` and ``kinds``."""
    return {
        "enabled": bool(enabled),
        "mean_interval_s": float(ranges.mean_interval),
        "warmup_s": float(ranges.warmup),
        "kinds": list(ranges.kinds),
    }


class EpisodeFaults:
    """Each env's episode fault schedule, applied to that env only: the fault injector of the
    task's tick (``before_read``, ``filter_frame``, ``filter_action``, with the runtime's time).

    An env's injector (:class:`sim2real.eval.soak.faults.SessionFaults`) is armed only while its faults
    are in force, one window of overlapping faults at a time, as the soak arms its sessions':
    an unarmed env costs the tick nothing. The owner calls :meth:`stop` for an env before it
    draws the env's new episode (sensor settings, model), then :meth:`start` with the new
    schedule once the env's sensor settings are set (an injector restores those when its faults
    end).

    Args:
        backend: The task's :class:`~sim2real.deploy.backends.sim.plant.SimBackend`.
        base_forces: Optional (envs, 3) N, the task's own pushes per env, which the schedule's
            pushes and cable pulls add to.
    """

    def __init__(self, backend, base_forces: np.ndarray | None = None):
        self.session_faults = SessionFaults(backend, base_forces)
        envs = backend.envs
        #: each env's current schedule, episode time (s from the episode's start)
        self.schedules: list[tuple] = [()] * envs
        #: each env's faults applied so far this episode (``FaultInjector.log`` entries)
        self.log: list[list[dict]] = [[] for _ in range(envs)]
        self._windows: list[list] = [[] for _ in range(envs)]  # (start, end, faults), pending
        self._until = np.full(envs, np.inf)  # runtime time the armed window ends (inf: none)
        self._next = np.inf  # the earliest arm or disarm of any env

    def stop(self, e: int) -> None:
        """End env ``e``'s schedule: disarm its injector and undo a fault in force (sensor
        settings, force, frozen frame)."""
        self._disarm(e, restore=True)
        self.schedules[e], self._windows[e] = (), []
        self._plan()

    def start(self, e: int, schedule, t0: float) -> None:
        """Start env ``e``'s episode schedule ``schedule`` (Faults in episode time) at runtime
        time ``t0`` (s): its faults are applied shifted by ``t0``."""
        self._disarm(e, restore=False)  # stopped already (stop): a no-op
        self.schedules[e], self.log[e] = tuple(schedule), []
        shifted = sorted(
            (dataclasses.replace(f, start=f.start + t0) for f in schedule), key=lambda f: f.start
        )
        windows: list = []
        for f in shifted:  # overlapping faults share a window (and an injector)
            end = f.start + f.duration
            if windows and f.start < windows[-1][1]:
                windows[-1][1] = max(windows[-1][1], end)
                windows[-1][2].append(f)
            else:
                windows.append([f.start, end, [f]])
        self._windows[e] = windows
        self._plan()

    def _disarm(self, e: int, restore: bool) -> None:
        inj = self.session_faults.disarm(e, restore=restore)
        if inj is not None:
            self.log[e].extend(inj.log)
        self._until[e] = np.inf

    def _plan(self) -> None:
        starts = [w[0][0] for w in self._windows if w]
        self._next = min(float(self._until.min()), min(starts, default=np.inf))

    def _update(self, t: float) -> None:
        """Disarm the windows that ended by ``t`` (their faults undone, as the injector's own
        ``before_read`` would) and arm those that began."""
        for e in range(len(self._windows)):
            if t >= self._until[e]:
                self._disarm(e, restore=True)
            w = self._windows[e]
            if self._until[e] == np.inf and w and t >= w[0][0]:
                start, end, faults = w.pop(0)
                self.session_faults.arm(e, faults)
                self._until[e] = end
        self._plan()

    # ------------------------------------------------------------------ the injector's calls
    def before_read(self, t: float) -> None:
        if t >= self._next:
            self._update(t)
        self.session_faults.before_read(t)

    def filter_frame(self, t: float, frame):
        return self.session_faults.filter_frame(t, frame)

    def filter_action(self, t: float, action: np.ndarray) -> np.ndarray:
        return self.session_faults.filter_action(t, action)
