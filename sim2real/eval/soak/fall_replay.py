"""How likely a soak's fall was, and whether the policy falls there in its own loop
(:class:`FallReplay`).

A fall the fall check stopped (no runtime stop began it) may be the policy's, one it takes in
its own loop too; the runtime's, where its estimate, guard or smoother took what the policy
needed to recover; or a rare draw of the world's sensor noise. A floating-base session captures
each RUNNING env every ``CAPTURE_PERIOD`` s (what a checkpoint holds,
:meth:`sim2real.eval.soak.session.Session.capture`). At such a fall the one-session copy of the
batch that :class:`~sim2real.eval.soak.counterfactual.StopReplay` keeps replays, in the same
world (model, floor, command schedule, the domain's pushes, the force of a fault armed at the
capture), to ``HORIZON`` s after the stop:

- ``own_loop``: from each capture ``LEAD`` s before the stop, the policy's own loop in place of
  the runtime: it reads the simulator's true state (no sensor noise, no estimator; the
  observation as its contract builds it) and its targets go to the drives as emitted (no guard,
  no smoother, no stop), as unitree_rl_gym's and unitree_rl_lab's sim2sim loops run a policy.
  It fell when the true base fell (below ``TRUE_FALL_HEIGHT`` of its standing height or tilted
  past the fall tilt: the estimation monitor's rule).
- ``redraw``: from the capture ``REDRAW_LEAD`` s before the stop, the runtime itself, each of
  ``REDRAWS`` times with another draw of the sensor noise (seeded by the session's seed, the
  stop's tick and the draw). It fell when the runtime stopped (every legged stop lays it down).

Each holds ``from_s`` and ``fall_s`` (s, or null: stood), one entry per replay. Walking is
chaotic and a push's outcome turns on the gait's phase and the noise, so one run says little;
the shares say whether the fall was near certain from there, with or without the runtime. The
captured states are the ones our runtime brought the robot to, and the own loop reads the truth,
which no deployment can. A replay starts only from a capture of the env's present stretch of
RUNNING (never from before the previous fall); only a session's first ``MAX_FALLS`` falls
replay, and captures are not checkpointed (a fall soon after a resume replays from fewer).
"""

from __future__ import annotations

import copy
from collections import deque

import numpy as np

from sim2real.deploy.core.attitude import tilt_of
from sim2real.deploy.rig.own_loop import OwnLoop
from sim2real.eval.soak.counterfactual import HORIZON

#: s between two captures of a RUNNING env. Our choice: 1 s, a fifth of the push interval of
#: legged_gym and Isaac Lab's velocity tasks (5 s).
CAPTURE_PERIOD = 1.0
#: s before the fall's stop each replay starts from (the newest capture at least that early).
#: Our choice: 2 to 6 s, from the end of the fall attribution's window after a push
#: (``sim2real.eval.soak.falls.ATTRIBUTION_WINDOW``, 2 s: a push that began the fall is replayed
#: too) to a little past one push interval before it.
LEAD = (2.0, 3.0, 4.0, 5.0, 6.0)
#: s before the stop the runtime's replays with other sensor-noise draws start from, and how many.
#: Our choice: 4 s, before a push that began the fall; 5 draws.
REDRAW_LEAD, REDRAWS = 4.0, 5
#: Falls of a session that are replayed (the first ones): a policy that falls every minute
#: would otherwise double the soak's time.
MAX_FALLS = 10
#: The captures kept per env: enough to reach ``max(LEAD)`` s back.
KEPT = int(np.ceil(max(LEAD) / CAPTURE_PERIOD)) + 2


class FallReplay:
    """The replays of a floating-base batch's falls (module docstring). Call after
    each tick's bookkeeping, after ``stop_replay`` (:meth:`SessionBatch.on_tick`).

    Args:
        stop_replay: The batch's :class:`~sim2real.eval.soak.counterfactual.StopReplay` (its
            batch, and the one-session copies it keeps).

    Attributes:
        replays: Falls replayed so far in this process.
    """

    def __init__(self, stop_replay):
        self.stop_replay = stop_replay
        self.batch = batch = stop_replay.batch
        self.tracker = batch.task.parts()["tracker"]
        self.seen = [len(log) for log in self.tracker.fall_log]
        self.every = max(1, int(round(CAPTURE_PERIOD / batch.dt)))
        self.captures: list[deque] = [deque(maxlen=KEPT) for _ in batch.sessions]
        self.replayed = [0] * len(batch.sessions)
        self.replays = 0
        #: (envs,) int64, each env's last tick not RUNNING (-1: none yet): a stop, the lying
        #: down, the stand-up and its RAMP_IN. A replay starts only from a capture after it.
        self.stopped_at = np.full(len(batch.sessions), -1, dtype=np.int64)

    def __call__(self, rt) -> None:
        """Replay this tick's new falls of the fall check in the policy's own loop, note the
        envs not RUNNING (``stopped_at``), then capture the RUNNING envs when a capture is
        due."""
        from sim2real.deploy.core.modes import RUNNING

        for e, log in enumerate(self.tracker.fall_log):
            for record in log[self.seen[e] :]:
                if record.get("cause") == "fall" and self.replayed[e] < MAX_FALLS:
                    self.replayed[e] += 1
                    self._replay_fall(e, record)
            self.seen[e] = len(log)
        stopped = rt.mode != RUNNING
        if stopped.any():
            self.stopped_at[stopped] = rt.ticks
        if rt.ticks % self.every == 0:
            for e in np.flatnonzero(~stopped):
                arrays, meta = self.batch.sessions[e].capture()
                self.captures[e].append((arrays, copy.deepcopy(meta)))

    def _replay_fall(self, e: int, record: dict) -> None:
        """Write ``own_loop`` and ``redraw`` (module docstring) into the fall ``record``."""
        t_stop, dt = float(record["t_s"]), self.batch.dt
        until = t_stop + HORIZON
        starts = self._starts(e, t_stop, LEAD)
        record["own_loop"] = {
            "from_s": [start[1]["tick"] * dt for start in starts],
            "fall_s": [self.replay(e, start, until) for start in starts],
        }
        start = self._starts(e, t_stop, (REDRAW_LEAD,))
        if start:
            seed = (self.batch.configs[e].seed, int(round(t_stop / dt)))
            record["redraw"] = {
                "from_s": start[0][1]["tick"] * dt,
                "fall_s": [self.redraw(e, start[0], until, (*seed, k)) for k in range(REDRAWS)],
            }

    def _starts(self, e: int, t_stop: float, leads) -> list:
        """For each of ``leads`` (s), the newest capture of env ``e`` at least that long before
        ``t_stop`` (s) and after the env's last tick not RUNNING before it (``stopped_at``: never
        from before a previous fall or stand-up), each capture once, oldest first; fewer where
        none is kept."""
        starts = []
        for lead in sorted(leads, reverse=True):
            latest = int(np.floor((t_stop - lead) / self.batch.dt + 1e-9))
            kept = [c for c in self.captures[e] if self.stopped_at[e] < c[1]["tick"] <= latest]
            if kept and not any(kept[-1] is s for s in starts):
                starts.append(kept[-1])
        return starts

    def replay(self, e: int, start: tuple[dict, dict], until: float) -> float | None:
        """When (session time, s) the true base of env ``e`` falls in the policy's own loop run
        from the capture ``start`` until ``until`` s; None if it stays up."""
        self.replays += 1
        return own_loop(self._twin(e, start), until)

    def redraw(self, e: int, start: tuple[dict, dict], until: float, seed) -> float | None:
        """When (session time, s) the runtime stops env ``e``'s robot (it lies down) continuing
        from the capture ``start`` until ``until`` s with its sensor noise drawn from
        ``numpy.random.default_rng(seed)``; None if it stays up."""
        twin = self._twin(e, start)
        twin.backend.set_sensor_streams([np.random.default_rng(seed)])
        log = twin.task.parts()["tracker"].fall_log[0]
        before = len(log)
        twin.rt.run(max(int(round((until - twin.rt.time) / twin.dt)), 0), on_tick=twin.on_tick)
        self.replays += 1
        return float(log[before]["t_s"]) if len(log) > before else None

    def _twin(self, e: int, start: tuple[dict, dict]):
        """Env ``e``'s one-session copy of the batch, restored to the capture ``start``."""
        twin = self.stop_replay.copy_of(e)
        arrays, meta = start
        twin.restore(arrays, copy.deepcopy(meta), "the soak's capture before a fall")
        return twin


def own_loop(twin, until: float) -> float | None:
    """Run a one-session batch ``twin`` (:class:`~sim2real.eval.soak.batch.SessionBatch`) from
    where it stands to ``until`` (its session time, s) in the policy's own loop
    (:class:`~sim2real.deploy.rig.own_loop.OwnLoop`, on the runtime's state and clock as
    captured); returns the time its true base fell, or None. Leaves the twin's runtime as it
    was but for its state's fields the loop wrote (the plant, the world's schedules moved on)."""
    rt, plant, monitor = twin.rt, twin.backend, twin.estimation
    state = rt.state
    loop = OwnLoop(rt.policy, plant, state, rt.goal, twin.dt, rt.time, rt.ticks, rt.injector)
    schedule = twin.task.schedule
    while loop.time < until - 0.5 * twin.dt:
        loop.tick()
        if twin.pushes is not None:
            twin.pushes(loop, plant)
        if schedule is not None:
            schedule(loop)
        truth = plant.true_base_state()  # after the push: what the next tick observes
        tilt = float(tilt_of(state.base.set_truth(truth).projected_gravity)[0])
        height = float(truth[0, 2])
        if getattr(plant, "grounds", None):  # terrain: above the ground under it
            height -= float(plant.ground_height(truth)[0])
        if not (np.isfinite(height) and height >= monitor.fall_height) or tilt > monitor.fall_tilt:
            return float(loop.time)
    return None
