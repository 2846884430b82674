"""The soak batch's per-tick bookkeeping as a hook of its run (:class:`BatchTick`): the batch's
ticks go through its :class:`~sim2real.deploy.rig.rig.Rig` (``Rig.after_tick``: the monitors and
the task, then the hooks), as every run's do; this hook, the rig's first, does the batch's own
part after them: on terrain first where the true bases walked and fell (the batch's
:class:`~sim2real.eval.soak.terrain_figures.TerrainFigures`), then
:meth:`sim2real.eval.soak.batch.SessionBatch.bookkeeping` (temperatures and speeds, pushes,
faults, drift, curves, operator stand-ups, checkpoints' captures, the replays).
"""

from __future__ import annotations

from sim2real.deploy.rig.hooks import RunHook


class BatchTick(RunHook):
    """The bookkeeping of ``batch`` (a :class:`~sim2real.eval.soak.batch.SessionBatch`) after
    each tick of its rig's runtime."""

    name = "soak"

    def __init__(self, batch):
        self.batch = batch

    def after_tick(self, runtime) -> None:
        b = self.batch
        if b.terrain_figures is not None:  # before a stand-up moves the base, a capture holds it
            b.terrain_figures.tick(runtime, b.backend, b.task.tracker.falls)
        if b.curriculum is not None:  # a curriculum walk's timeouts: respawned on their level
            due = b.curriculum.tick(runtime, b.backend)
            if b.curriculum_respawns and due.any():  # a replay's copy respawns none
                b.stand_up(due, end="timeout")
        b.bookkeeping(runtime)
