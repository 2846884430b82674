"""Would the robot have fallen without the runtime's stop? (:class:`StopReplay`).

For a walking robot every safe stop is a fall: its drives damp and it lies down. A stop on a
robot already toppling changes nothing (its ankle driven into its stop as it goes over); a stop
on a robot that would have stood *is* the fall. The fall log alone cannot tell them apart, so
the soak replays each hard-limit stop's moment without the stop and looks.

How: a floating-base session captures its env (:meth:`sim2real.eval.soak.session.Session.capture`, the
same state a checkpoint holds) on the first tick of every episode of an estimate past a hard
limit (the guard's ``beyond_ticks`` is 1): a legged hard-limit stop comes only after the
estimate has been past for a while (:mod:`sim2real.deploy.safety.limits`), so the last such capture
precedes every one of them. When the tracker logs a fall begun by a hard-limit stop, a
one-session copy of the batch (built once per env, its own plant, runtime and world from the
same seed) continues from that capture with the hard-limit check's stop off
(:meth:`sim2real.deploy.safety.guard.SafetyGuard.set_stopping`) to ``HORIZON`` s after the stop. The
copy repeats the session tick for tick (a checkpoint's resume is exact), so with the stop on it
stops at the same tick; without it, if its fall detector fires by then the robot was falling
anyway: ``would_fall`` True, and :func:`sim2real.eval.soak.falls.attribute_falls` gives the fall to
what began it (a push, a fault, the policy). Otherwise ``would_fall`` False: the runtime's stop
laid a standing robot down.

Not replayed (``would_fall`` stays absent): stops of another cause (a stale sensor, non-finite
actions, an overrun: the runtime cannot walk on without the sensor it lost), and a hard-limit
stop whose episode past the limit began before a resume (its capture was not in the checkpoint)
or while the robot was not RUNNING (ramping in after a stand-up).

Cost: a capture of one env per episode past a hard limit, and per replayed stop
the copy's ``HORIZON`` s plus up to ``LEGGED_HARD_LIMIT_DURATION`` s before the stop.
"""

from __future__ import annotations

import copy
import tempfile

import numpy as np

#: Stop causes whose falls are replayed without the stop.
REPLAYED_CAUSES = ("hard_limit",)
#: s the replay runs past the stop's time, for the fall detector to fire. Our choice: 3 s; a
#: humanoid that starts to topple is on the floor within about 1 s, and a robot still standing
#: 3 s after the moment of its stop has recovered (legged_gym resamples pushes every 5 s).
HORIZON = 3.0


class StopReplay:
    """The replays of a :class:`~sim2real.eval.soak.batch.SessionBatch`'s hard-limit stops (module
    docstring). Call after each tick's bookkeeping, last (:meth:`SessionBatch.on_tick`).

    Args:
        batch: The batch (floating-base robot). Its tracker's ``fall_log`` records get
            ``would_fall`` (bool).

    Attributes:
        replays: Stops replayed so far in this process.
    """

    def __init__(self, batch):
        self.batch = batch
        self.tracker = batch.task.parts()["tracker"]
        self.seen = [len(log) for log in self.tracker.fall_log]
        self.captures: dict[int, tuple[dict, dict]] = {}
        self.copies: dict[int, object] = {}
        self._folders: dict[int, tempfile.TemporaryDirectory] = {}
        self.replays = 0

    def __call__(self, rt) -> None:
        """Replay the stops of this tick's new falls, then capture the envs that went past a
        hard limit this tick."""
        from sim2real.deploy.core.modes import RUNNING

        logs = self.tracker.fall_log
        for e, log in enumerate(logs):
            for record in log[self.seen[e] :]:
                if record.get("cause") in REPLAYED_CAUSES and self._captured(e, rt):
                    fell = self.replay(e, float(record["t_s"]))
                    record["would_fall"] = fell is not None
                    record["replay_fall_s"] = fell
            self.seen[e] = len(log)
        first = (rt.guard.beyond_ticks == 1) & (rt.mode == RUNNING)
        for e in np.flatnonzero(first):
            arrays, meta = self.batch.sessions[e].capture()
            # the meta holds the session's own lists (hours, curve): keep a copy of this moment
            self.captures[int(e)] = (arrays, copy.deepcopy(meta))

    def _captured(self, e: int, rt) -> bool:
        """Whether env ``e``'s capture was taken on the first tick of the episode past a hard
        limit that this tick's stop ends (not of an earlier one)."""
        got = self.captures.get(e)
        return got is not None and got[1]["tick"] == rt.ticks - int(rt.guard.beyond_ticks[e]) + 1

    def replay(self, e: int, t_stop: float) -> float | None:
        """When (session time, s) env ``e``'s robot falls (its fall detector's stop) by
        ``t_stop + HORIZON`` s if its session continues from its last capture without the
        hard-limit stop; None if it does not."""
        twin = self.copy_of(e)
        arrays, meta = self.captures[e]
        twin.restore(arrays, copy.deepcopy(meta), "the soak's capture before a hard-limit stop")
        log = twin.task.parts()["tracker"].fall_log[0]
        before = len(log)
        ticks = int(round((t_stop + HORIZON - twin.rt.time) / twin.dt))
        for cause in REPLAYED_CAUSES:
            twin.rt.guard.set_stopping(cause, False)
        try:
            twin.rt.run(max(ticks, 0), on_tick=twin.on_tick)
        finally:
            for cause in REPLAYED_CAUSES:
                twin.rt.guard.set_stopping(cause, True)
        self.replays += 1
        return next((float(r["t_s"]) for r in log[before:] if r.get("cause") == "fall"), None)

    def copy_of(self, e: int):
        """The one-session batch of env ``e``'s session (built on first use)."""
        if e not in self.copies:
            # the copy writes nothing there; the folder goes with this object (its finalizer)
            folder = self._folders.setdefault(e, tempfile.TemporaryDirectory(prefix="stop-replay-"))
            self.copies[e] = type(self.batch)(  # the batch's own class (sim2real.eval.soak.batch)
                [self.batch.configs[e]],
                folder.name,
                progress=False,
                replay_stops=False,
            )
        return self.copies[e]
