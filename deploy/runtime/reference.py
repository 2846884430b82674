"""The numpy reference of the runtime's compiled tick: :class:`ReferenceRuntime`, a
:class:`~deploy.runtime.loop.Runtime` with the same constructor whose numeric logic runs in numpy:
the guard (:class:`~deploy.safety.reference.ReferenceGuard`), the smoother
(:class:`~deploy.smoothing.reference.ReferenceSmoother`), the observation
(:func:`~deploy.spec.reference.observation_reference`), the supervision and action screen
(:meth:`Supervision.supervise`, :meth:`Supervision.screen`, :meth:`Supervision.override` of
:mod:`deploy.runtime.supervision`) and the latency histograms
(:meth:`~deploy.observe.telemetry.LatencyHistogram.add_stages`). Both give the same numbers bit
for bit (``tests/test_compiled_tick.py``); the estimator is the compiled one in both.
"""

from __future__ import annotations

import numpy as np

from deploy.runtime.loop import Runtime
from deploy.safety.reference import ReferenceGuard
from deploy.smoothing.reference import ReferenceSmoother
from deploy.spec.reference import observation_reference
from deploy.state import RobotState


class ReferenceRuntime(Runtime):
    """A :class:`~deploy.runtime.loop.Runtime` whose tick runs the numpy references (module
    docstring); the same arguments, attributes and errors. It compiles nothing."""

    def _build_stages(self) -> tuple[ReferenceGuard, ReferenceSmoother]:
        """The guard and the smoother (numpy references)."""
        envs, mode = self.envs, self.mode_name
        return ReferenceGuard(self.robot, envs, mode), ReferenceSmoother(self.robot, envs, mode)

    def _compile(self) -> None:
        """Nothing to compile."""
        return None

    def _supervise(self, state: RobotState, drive_errors: np.ndarray | None) -> None:
        """The guard's ``update_thermal``, :meth:`Supervision.supervise` and :meth:`_reanchor`."""
        self.guard.update_thermal(state.winding_temperature)
        self.supervision.supervise(state, drive_errors)
        self._reanchor(state)

    def _observe(self, state: RobotState) -> np.ndarray:
        """:func:`~deploy.spec.reference.observation_reference`."""
        return observation_reference(self.spec, state, self.goal, out=self._obs)

    def _act(self, action: np.ndarray, state: RobotState) -> tuple[np.ndarray, np.ndarray]:
        """The fault injector's filter, :meth:`Supervision.screen`, ``spec.action_to_target``
        and :meth:`Supervision.override`."""
        if self.injector is not None:
            action = self.injector.filter_action(self.time, action)
        action = self.supervision.screen(action)
        target = self.spec.action_to_target(action, state, out=self._target)
        return action, self.supervision.override(target, state)

    def _record_latency(self, stamps: np.ndarray) -> None:
        """:meth:`LatencyHistogram.add_stages` and ``add`` in numpy."""
        st = stamps
        self.latency.add_stages(st)
        self.tick_cost.add(0, st[8] - st[0] - (st[8] - st[7]))  # runtime cost w/o physics
