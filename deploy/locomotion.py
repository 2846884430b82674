"""How well a legged robot follows its velocity command: distance, speed, tracking, falls.

:class:`CommandTracker` is the legged counterpart of :class:`deploy.goals.GoalScheduler` for
``deploy-run`` and the soak: called after every tick, it measures the base's planar velocity
(the plant's truth in simulation, the base estimator's on hardware) against the command while
the runtime is RUNNING. Tracking success is the fraction of RUNNING time whose planar velocity
error ``|v_xy - command_xy|`` is within ``TRACKING_TOLERANCE`` (issue 17: 0.2 m/s), measured on
the velocity averaged over ``TRACKING_WINDOW`` (a trot's body sways within a stride: the
command is a mean speed). Falls are the runtime's safe stops of cause ``fall``.
"""

from __future__ import annotations

import numpy as np

#: Planar velocity error within which the robot tracks its command, m/s (issue 17).
TRACKING_TOLERANCE = 0.2
#: Averaging window of the tracked velocity, s (our choice: two strides of a 0.4 s trot).
TRACKING_WINDOW = 0.8


def parse_command(text: str) -> np.ndarray:
    """``"VX,VY,WZ"`` (m/s, m/s, rad/s, base frame) -> (3,) float array.

    Raises:
        ValueError: not three finite numbers (the message quotes ``text``).
    """
    try:
        command = np.array([float(x) for x in text.split(",")])
    except ValueError:
        command = np.array([])
    if command.shape != (3,) or not np.isfinite(command).all():
        raise ValueError(f"--command {text!r}: expected VX,VY,WZ (m/s, m/s, rad/s)")
    return command


class CommandTracker:
    """Command tracking of ``envs`` legged robots (module docstring).

    Args:
        envs: Batch size.
        control_period: s.
        backend: The runtime's backend; its ``true_base_state`` (simulation) is used when it
            has one, else the runtime's base estimate.

    Attributes:
        distance: (envs,) m, planar path length of the base while RUNNING.
        forward: (envs,) m, displacement along the base's heading while RUNNING.
        running_time: (envs,) s RUNNING. tracked_time: (envs,) s of it within tolerance.
    """

    def __init__(self, envs: int, control_period: float, backend):
        self.envs, self.dt = envs, float(control_period)
        self.truth = getattr(backend, "true_base_state", None)
        self.distance = np.zeros(envs)
        self.forward = np.zeros(envs)
        self.running_time = np.zeros(envs)
        self.tracked_time = np.zeros(envs)
        self.window = max(1, int(round(TRACKING_WINDOW / self.dt)))
        self._ring = np.zeros((self.window, envs, 2))
        self._filled = np.zeros(envs, dtype=np.int64)
        self.judged_on = "true base velocity" if self.truth is not None else "estimated base"

    def __call__(self, runtime) -> None:
        """Account one tick of ``runtime`` (a floating-base :class:`~deploy.runtime.Runtime`)."""
        from deploy.runtime import RUNNING

        running = runtime.mode == RUNNING
        velocity = self._planar_velocity(runtime)  # (envs, 2) m/s, base frame
        step = velocity * self.dt
        self.distance += np.where(running, np.linalg.norm(step, axis=1), 0.0)
        self.forward += np.where(running, step[:, 0], 0.0)
        self._ring[runtime.ticks % self.window] = velocity
        self._filled = np.where(running, np.minimum(self._filled + 1, self.window), 0)
        full = self._filled >= self.window
        mean = self._ring.mean(axis=0)
        error = np.linalg.norm(mean - runtime.velocity_command[:, :2], axis=1)
        self.running_time += running * self.dt
        self.tracked_time += (running & full & (error <= TRACKING_TOLERANCE)) * self.dt

    def _planar_velocity(self, runtime) -> np.ndarray:
        if self.truth is None:
            return runtime.state.base.linear_velocity[:, :2].copy()
        from deploy.base_estimation import quaternion_to_matrix

        truth = self.truth()
        out = np.empty((self.envs, 2))
        for e in range(self.envs):
            rot = quaternion_to_matrix(truth[e, 3:7])
            out[e] = (rot.T @ truth[e, 7:10])[:2]
        return out

    def summary(self, runtime) -> dict:
        """The report's ``locomotion`` entry (sums over the envs; speeds per RUNNING second)."""
        running = float(self.running_time.sum())
        return {
            "command": runtime.velocity_command.tolist(),
            "distance_m": float(self.distance.sum()),
            "mean_forward_speed_m_s": float(self.forward.sum() / running) if running else None,
            "tracking_success": float(self.tracked_time.sum() / running) if running else None,
            "tracking_tolerance_m_s": TRACKING_TOLERANCE,
            "running_s": running,
            "falls": int(runtime.counters.faults["fall"].sum()),
            "judged_on": self.judged_on,
        }
