"""The fault injection of a batch of soak sessions: one injector per session, on its env only.

The runtime of a batch (:class:`sim2real.eval.soak.batch.SessionBatch`) takes one injector;
:class:`SessionFaults` is that injector, made of one
:class:`sim2real.deploy.backends.sim.faults.FaultInjector` per session on a one-env view of the batch's
:class:`~sim2real.deploy.backends.sim.plant.SimBackend` (its env's sensor settings, model and forces). A
session's faults (its seeded schedule, :mod:`sim2real.eval.world.fault_schedule`) then touch its own env
only, whatever its neighbours; the session arms an injector ``sim2real.eval.soak.session.ARM_LEAD`` s
before each fault and disarms it when the fault is judged (:class:`sim2real.eval.soak.session.Session`).
Training episodes arm each env with its episode's whole schedule
(:class:`sim2real.policies.episode_faults.EpisodeFaults`).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.backend import SensorFrame


class _BackendSlice:
    """Env ``e`` of a SimBackend as a one-env backend: what a FaultInjector uses (views of the
    per-env sensor settings, the env's current model, forces).

    ``base_force`` (a (3,) N view, or None) is a force of the owner's own that the faults' forces
    add to (a training episode's pushes): a fault then pushes on top of it instead of replacing
    it."""

    envs = 1

    def __init__(self, backend, e: int, base_force: np.ndarray | None = None):
        self._backend, self._e = backend, e
        self.dropout_probability = backend.dropout_probability[e : e + 1]
        self.latency_ticks = backend.latency_ticks[e : e + 1]
        self.max_latency_ticks = backend.max_latency_ticks
        self.base_force = base_force

    @property
    def models(self) -> list:
        """The env's model, as it is now (``SimBackend.set_model`` replaces it)."""
        return [self._backend.models[self._e]]

    def set_external_force(self, env: int, force: np.ndarray, body: str | None = None) -> None:
        if self.base_force is not None:
            force = force + self.base_force
        self._backend.set_external_force(self._e, force, body)


class SessionFaults:
    """The fault injector the runtime sees: one :class:`sim2real.deploy.backends.sim.faults.FaultInjector`
    per session, on that session's env only, armed from ``sim2real.eval.soak.session.ARM_LEAD`` s before
    each fault until it is judged.

    Per-session injectors keep the sessions of a batch apart (one injector for the batch freezes
    one frame for every stale fault and resets every env's sensor settings each tick), and only
    armed injectors cost time in the tick.

    Args:
        backend: The batch's :class:`~sim2real.deploy.backends.sim.plant.SimBackend`.
        base_forces: Optional (envs, 3) N, forces of the owner's own per env that the faults'
            pushes and cable pulls add to (``_BackendSlice.base_force``); None: the faults' forces
            alone (the soak's).
    """

    def __init__(self, backend, base_forces: np.ndarray | None = None):
        self.backend = backend
        self.slices = [
            _BackendSlice(backend, e, None if base_forces is None else base_forces[e])
            for e in range(backend.envs)
        ]
        f = backend.frame
        self.frames = [
            SensorFrame(
                time=f.time[e : e + 1],
                position=f.position[e : e + 1],
                position_stamp=f.position_stamp[e : e + 1],
                winding_temperature=f.winding_temperature[e : e + 1],
                temperature_stamp=f.temperature_stamp[e : e + 1],
            )
            for e in range(backend.envs)
        ]
        self.armed: list = [None] * backend.envs
        self._items: list = []

    def arm(self, e: int, faults: list):
        """Arm env ``e`` with a new injector of ``faults`` (a list of
        :class:`sim2real.deploy.backends.sim.faults.Fault`, times in the runtime's clock, s); it takes the
        env's sensor settings as they are now as its settings without faults. Returns it."""
        from sim2real.deploy.backends.sim.faults import FaultInjector

        self.armed[e] = FaultInjector(list(faults), self.slices[e])
        self._items = [(i, inj) for i, inj in enumerate(self.armed) if inj is not None]
        return self.armed[e]

    def disarm(self, e: int, restore: bool = False):
        """Disarm env ``e``; returns its injector (None if none was armed). With ``restore``, a
        fault still in force is undone too
        (:meth:`sim2real.deploy.backends.sim.faults.FaultInjector.restore`: the env's force goes back to
        its base force, zero without one)."""
        inj, self.armed[e] = self.armed[e], None
        self._items = [(i, x) for i, x in enumerate(self.armed) if x is not None]
        if restore and inj is not None:
            inj.restore()
        return inj

    def before_read(self, t: float) -> None:
        for _, inj in self._items:
            inj.before_read(t)

    def filter_frame(self, t: float, frame: SensorFrame) -> SensorFrame:
        for e, inj in self._items:
            inj.filter_frame(t, self.frames[e])
        return frame

    def filter_action(self, t: float, action: np.ndarray) -> np.ndarray:
        for e, inj in self._items:
            inj.filter_action(t, action[e : e + 1])
        return action
