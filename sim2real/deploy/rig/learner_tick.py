"""A training episode's control period on a rig's runtime stages (:class:`LearnerTick`), the learner's
action in the policy's slot.

The stages and their order are the runtime's tick (:meth:`sim2real.deploy.runtime.Runtime.tick`) cut
where a learner acts: the action to a target, the guard, the smoother and the guard's motion
envelope, the drives and the physics, the plant-side faults and the frame's, the Kalman filter, the
camera's image input (a spec with an image block), the thermal derating, the re-anchoring, the
kinematics and the observation; without the runtime's supervision (no RAMP_IN, no safe stops: an
episode ends instead, no screen but a fault's non-finite action holding the last one). What the
guard and the smoother changed counts as an intervention, by the rig's
:class:`~sim2real.deploy.monitors.interventions.InterventionMonitor` (the soak's definition). The
reach env (:mod:`sim2real.policies.envs`) steps its episodes here.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.runtime import reanchor


class LearnerTick:
    """One control period of ``rig``'s runtime stages under a learner's action (module
    docstring).

    Args:
        rig: The run (:class:`~sim2real.deploy.rig.rig.Rig`): its backend, runtime stages and state,
            its intervention monitor.
        spec: The policy's :class:`~sim2real.deploy.spec.policy_spec.PolicySpec` (the learner's).
        faults: Optional fault injector with ``filter_action``, ``before_read`` and
            ``filter_frame`` (:class:`sim2real.policies.episode_faults.EpisodeFaults`).
    """

    def __init__(self, rig, spec, faults=None):
        rt = rig.runtime
        self.backend, self.spec, self.faults, self.monitor = (
            rig.backend,
            spec,
            faults,
            rig.interventions,
        )
        self.estimator, self.kinematics, self.state = rt.estimator, rt.kinematics, rt.state
        self.guard, self.smoother = rt.guard, rt.smoother
        #: the runtime's camera stage (a spec with an image block), else None: its ``image``
        #: is the graph's image input after each step
        self.cameras = rt.cameras
        envs, n = rt.envs, rt.n
        # the estimator's control input, the runtime's (SafetyGuard.estimator_input)
        self._input = self.guard.estimator_input(self.smoother)
        # velocity mode: the guard's stopping bounds read Ruckig's integrated position too
        self._commanded = self.smoother.position if rt.mode_name == "velocity" else None
        self._moved, self._tracking = np.zeros(envs, dtype=np.int64), np.zeros(envs)
        self._target, self._cmd = np.zeros((envs, n)), np.zeros((envs, n))
        self._any_before = np.zeros(envs, dtype=np.int64)

    def step(self, action: np.ndarray, goal: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """One period under ``action`` ((envs, n) float64 in [-1, 1], clipped by the caller; a
        fault's non-finite rows are replaced by the last action, in place); the next observation
        into ``obs`` ((envs, obs_dim) float32) for ``goal`` ((envs, 3) m). Returns (envs,) bool:
        the envs where the guard or the smoother changed the command."""
        guard, faults, backend, state = self.guard, self.faults, self.backend, self.state
        if faults is not None:  # a nan-action fault; the runtime's screen holds the last action
            faults.filter_action(backend.time, action)
            bad = ~np.isfinite(action).all(axis=1)
            if bad.any():
                action[bad] = state.last_action[bad]
        target = self.spec.action_to_target(action, state, out=self._target)
        target = guard.filter(target, state, out=target, commanded_position=self._commanded)
        cmd = self.smoother.step(target, out=self._cmd)
        cmd = guard.check_motion(self.smoother, state, cmd)  # the runtime's motion envelope
        # what the guard and the smoother changed (the smoother's brake before a soft limit, its
        # clamp to the velocity limit, the guard's clamps and holds): interventions
        np.copyto(self._any_before, self.monitor.any)
        self.monitor.update()
        intervened = self.monitor.any > self._any_before
        backend.write(cmd)
        backend.advance()
        if faults is not None:  # the runtime's tick: plant-side faults, then the frame's
            faults.before_read(backend.time)
        frame = backend.read()
        if faults is not None:
            frame = faults.filter_frame(backend.time, frame)
        state = self.estimator.update(frame, state, self._input)
        if self.cameras is not None:  # the image input (no safe stop: the episode goes on)
            self.cameras.update(frame)
        state.last_action[:] = action
        guard.update_thermal(state.winding_temperature)
        reanchor(self.smoother, state, self._tracking, self._moved)
        self.kinematics.update(state)
        self.spec.observation(state, goal, out=obs)
        return intervened
