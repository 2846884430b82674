"""The guard's certification of the motion the robot is committed to, after the smoother's step:
:class:`MotionCheck`, a base class of :class:`sim2real.deploy.safety.guard.SafetyGuard`
(:meth:`MotionCheck.check_motion` with the motion envelope, :mod:`sim2real.deploy.safety.envelope`).

A target is not the path to it: the envs whose committed motion the envelope cannot certify are
braked and counted as ``self_collision`` or ``workspace`` interventions (position mode, fixed
base), once per env and tick with the guard's own checks of the target.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.state import RobotState


class MotionCheck:
    """:meth:`check_motion` and its binding, on the guard's attributes: ``envelope`` (a
    :class:`~sim2real.deploy.safety.envelope.MotionEnvelope` or None), ``count_matrix``,
    ``_counted``, ``_geometric_rows``, ``effort_scale``, ``_motion_key`` and
    ``_certify_motion`` (the envelope's certify bound to the arrays of the last call)."""

    def check_motion(self, smoother, state: RobotState, command: np.ndarray) -> np.ndarray:
        """Certify the smoother's last step with the motion envelope
        (:mod:`sim2real.deploy.safety.envelope`):
        the envs whose committed motion could bring a collision pair, or the end effector and
        the workspace box's faces, within the clearance margin are braked instead
        (:meth:`sim2real.deploy.smoothing.CommandSmoother.brake`) and counted as ``self_collision`` or
        ``workspace`` interventions (once per env and tick with :meth:`filter`'s).

        Args:
            smoother: The :class:`~sim2real.deploy.smoothing.CommandSmoother` that just stepped.
            state: The estimated state (``q`` rad).
            command: (envs, n) the command of that step (rewritten where braked).

        Returns:
            ``command``.
        """
        envelope = self.envelope
        if envelope is None:
            return command
        k = self._motion_key  # the envelope's certify bound to the arrays of the last call
        if smoother is not k[0] or state is not k[1] or command is not k[2] or envelope is not k[3]:
            self._bind_motion(smoother, state, command)
        if self._certify_motion():  # some env unsafe: brake, commit (else certify committed)
            unsafe = envelope.unsafe
            braked = unsafe[0] | unsafe[1] | envelope.beyond
            for k, (r, fired) in enumerate(
                zip(self._geometric_rows, (unsafe[0], unsafe[1], envelope.beyond), strict=True)
            ):
                first = fired & (self.count_matrix[r] == self._counted[k])
                self.count_matrix[r] += first
            if envelope.torque is not None:  # the computed-torque stop; the rate limit follows
                envelope.torque.brake(state.q, state.dq, self.effort_scale, braked, command)
                smoother.sync(state.q, state.dq, envs=braked, effort=command)
            else:
                smoother.brake(braked, envelope.joints)
                command[braked] = smoother.command[braked]
            envelope.commit(command)
        return command

    def bind_motion(self, smoother, state: RobotState, command: np.ndarray) -> None:
        """Bind :meth:`check_motion`'s certify to the arrays the tick will pass it, compiled (or
        loaded from numba's cache) now: a runtime calls this when it is built, so that its first
        tick does not (a fresh clone's first run paid 0.6 s there, in its first period). A later
        :meth:`check_motion` with other arrays binds again. Nothing without a motion envelope."""
        if self.envelope is not None:
            self._bind_motion(smoother, state, command)

    def _bind_motion(self, smoother, state: RobotState, command: np.ndarray) -> None:
        """Bind the envelope's certify to these arrays (``MotionEnvelope.certifier``)."""
        args = (state.q, state.dq, smoother.before, smoother.trajectory, smoother.stopping)
        self._certify_motion = self.envelope.certifier(*args, self.effort_scale, command)
        self._motion_key = (smoother, state, command, self.envelope)
