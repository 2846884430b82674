"""How the policy's own loop fares where the soak's robot fell (:class:`OwnLoopReplay`).

A fall the fall check stopped (no runtime stop began it) may be the policy's, one it takes in
its own loop too, or the runtime's: the estimate, the guard or the smoother took from it what it
needed to recover. The soak replays to show which. A floating-base session captures each
RUNNING env every ``CAPTURE_PERIOD`` s (the state a checkpoint holds,
:meth:`sim2real.eval.soak.session.Session.capture`). At a fall, the one-session copy of the batch
that :class:`~sim2real.eval.soak.counterfactual.StopReplay` keeps continues from each capture
``LEAD`` s before the fall's stop, in the same world (its model, floor, command schedule, the
training domain's pushes, the force of a fault armed at the capture), with the policy's own loop
in place of the runtime: each tick the policy reads the simulator's true state (no sensor noise,
no estimator; the observation as its contract builds it) and its targets go to the drives as it
emitted them (no guard, no smoother, no stop), as the sim2sim loops of unitree_rl_gym and
unitree_rl_lab run a policy. A replay falls when the true base falls by ``HORIZON`` s after the
stop (below ``TRUE_FALL_HEIGHT`` of its standing height or tilted past the fall tilt: the
estimation monitor's rule). The fall record gets ``own_loop``: ``{"from_s": [...], "fall_s":
[... or None]}``, one entry per replay. Not replayed: a fall a runtime stop began.

What it can tell: walking is chaotic, and a push's outcome turns on the gait's phase, so one
replay from one moment says little; the share of replays that fall says how near the policy
itself was to falling. What it cannot: the captured states are the ones the runtime brought the
robot to, and the own loop reads the truth, more than any deployment can. It does not judge.

Cost: one capture of each RUNNING env per ``CAPTURE_PERIOD``, and per fall ``len(LEAD)``
replays of up to ``max(LEAD) + HORIZON`` s of the own loop (no estimator, guard or smoother).
"""

from __future__ import annotations

import copy
from collections import deque

import numpy as np

from sim2real.deploy.core.attitude import tilt_of
from sim2real.eval.soak.counterfactual import HORIZON

#: s between two captures of a RUNNING env. Our choice: 1 s, a fifth of the push interval of
#: legged_gym and Isaac Lab's velocity tasks (5 s).
CAPTURE_PERIOD = 1.0
#: s before the fall's stop each replay starts from (the newest capture at least that early).
#: Our choice: 2 to 6 s, from the end of the fall attribution's window after a push
#: (``sim2real.eval.soak.falls.ATTRIBUTION_WINDOW``, 2 s: a push that began the fall is replayed
#: too) to a little past one push interval before it.
LEAD = (2.0, 3.0, 4.0, 5.0, 6.0)
#: The captures kept per env: enough to reach ``max(LEAD)`` s back.
KEPT = int(np.ceil(max(LEAD) / CAPTURE_PERIOD)) + 2


class OwnLoopReplay:
    """The own-loop replays of a floating-base batch's falls (module docstring). Call after
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
        self.replays = 0

    def __call__(self, rt) -> None:
        """Replay this tick's new falls of the fall check in the policy's own loop, then capture
        the RUNNING envs when a capture is due."""
        from sim2real.deploy.core.modes import RUNNING

        for e, log in enumerate(self.tracker.fall_log):
            for record in log[self.seen[e] :]:
                if record.get("cause") == "fall":
                    t_stop = float(record["t_s"])
                    starts = self._starts(e, t_stop)
                    record["own_loop"] = {
                        "from_s": [start[1]["tick"] * self.batch.dt for start in starts],
                        "fall_s": [self.replay(e, start, t_stop + HORIZON) for start in starts],
                    }
            self.seen[e] = len(log)
        if rt.ticks % self.every == 0:
            for e in np.flatnonzero(rt.mode == RUNNING):
                arrays, meta = self.batch.sessions[e].capture()
                self.captures[e].append((arrays, copy.deepcopy(meta)))

    def _starts(self, e: int, t_stop: float) -> list:
        """For each ``LEAD``, the newest capture of env ``e`` at least that long before
        ``t_stop`` (s), each capture once, oldest first; fewer where none is kept."""
        starts = []
        for lead in sorted(LEAD, reverse=True):
            latest = int(np.floor((t_stop - lead) / self.batch.dt + 1e-9))
            kept = [c for c in self.captures[e] if c[1]["tick"] <= latest]
            if kept and not any(kept[-1] is s for s in starts):
                starts.append(kept[-1])
        return starts

    def replay(self, e: int, start: tuple[dict, dict], until: float) -> float | None:
        """When (session time, s) the true base of env ``e`` falls in the policy's own loop run
        from the capture ``start`` until ``until`` s; None if it stays up."""
        twin = self.stop_replay.copy_of(e)
        arrays, meta = start
        twin.restore(arrays, copy.deepcopy(meta), "the soak's capture before a fall")
        self.replays += 1
        return own_loop(twin, until)


def own_loop(twin, until: float) -> float | None:
    """Run a one-session batch ``twin`` (:class:`~sim2real.eval.soak.batch.SessionBatch`) from
    where it stands to ``until`` (its session time, s) in the policy's own loop (module
    docstring); returns the time its true base fell, or None. Leaves the twin's runtime
    stages as they were (the runtime's clock and the plant moved on)."""
    rt, plant, monitor = twin.rt, twin.backend, twin.estimation
    state, spec, policy = rt.state, rt.spec, rt.policy
    obs = np.zeros((1, spec.obs_dim), dtype=np.float32)
    target = np.zeros((1, twin.robot.n_joints))
    schedule = twin.task.schedule
    while rt.time < until - 0.5 * twin.dt:
        if rt.injector is not None:  # a fault armed at the capture: its force
            rt.injector.before_read(rt.time)
        state.q[:] = plant.true_position()
        state.dq[:] = plant.true_velocity()
        truth = plant.true_base_state()
        state.base.set_truth(truth)
        state.clock[:] = rt.time
        spec.observation(state, rt.goal, out=obs)
        action = policy(obs)
        spec.action_to_target(action, state, out=target)
        plant.write(target)
        plant.advance()
        state.last_action[:] = action
        rt.ticks += 1
        rt.time += twin.dt
        if twin.pushes is not None:
            twin.pushes(rt, plant)
        if schedule is not None:
            schedule(rt)
        truth = plant.true_base_state()
        tilt = float(tilt_of(state.base.set_truth(truth).projected_gravity)[0])
        height = float(truth[0, 2])
        if not (np.isfinite(height) and height >= monitor.fall_height) or tilt > monitor.fall_tilt:
            return float(rt.time)
    return None
