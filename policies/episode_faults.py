"""The soak's faults in training: each episode draws a fault schedule and meets it on its env.

A training episode (:class:`policies.envs.ReachTask`, :class:`policies.locomotion.LocomotionTask`)
draws its fault schedule from the soak's :class:`~eval.world.fault_schedule.FaultRanges` (the
same kinds, weights, magnitudes, durations and budgets), with only the time between faults
shortened to the episode's scale (:func:`training_fault_ranges`): the soak spaces faults
minutes apart, an episode lasts seconds to minutes. :class:`EpisodeFaults` applies each env's
schedule, shifted to its episode's start, through the soak's per-env injectors
(:class:`eval.soak.faults.SessionFaults`), and undoes a fault still in force when the episode
ends.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from eval.soak.faults import SessionFaults
from eval.world.fault_schedule import FaultRanges

#: s, no fault before this episode time (the soak's warmup is 10 s; an episode's RAMP_IN and
#: first steps are over within a second).
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
    """Each env's episode fault schedule, applied to that env only.

    The owner calls :meth:`stop` for an env before it draws the env's new episode (sensor
    settings, model), then :meth:`start` with the new schedule once the env's sensor settings are
    set (the injector restores those when a fault ends). :attr:`injector` is what the tick calls
    (``before_read``, ``filter_frame``, ``filter_action``, with the runtime's time).

    Args:
        backend: The task's :class:`~deploy.backends.sim.plant.SimBackend`.
        base_forces: Optional (envs, 3) N, the task's own pushes per env, which the schedule's
            pushes and cable pulls add to.
    """

    def __init__(self, backend, base_forces: np.ndarray | None = None):
        self.injector = SessionFaults(backend, base_forces)
        #: each env's current schedule, episode time (s from the episode's start)
        self.schedules: list[tuple] = [()] * backend.envs

    def stop(self, e: int) -> None:
        """End env ``e``'s schedule: disarm its injector and undo a fault in force (sensor
        settings, force, frozen frame)."""
        self.injector.disarm(e, restore=True)
        self.schedules[e] = ()

    def start(self, e: int, schedule, t0: float) -> None:
        """Start env ``e``'s episode schedule ``schedule`` (Faults in episode time) at runtime
        time ``t0`` (s): its faults are armed shifted by ``t0``; an empty schedule arms
        nothing."""
        self.injector.disarm(e)  # stopped already (stop): a no-op
        self.schedules[e] = tuple(schedule)
        if schedule:
            shifted = [dataclasses.replace(f, start=f.start + t0) for f in schedule]
            self.injector.arm(e, shifted)
