"""What the emulated robot truly did while the policy walked it: the legged figures of
``deploy-run`` (:class:`sim2real.deploy.tasks.locomotion.CommandTracker`: distance, mean forward speed,
tracking) from the emulator's true base trajectory instead of the runtime's estimate.

The policy's time is taken as the ``running_s`` seconds (deploy-run's report) before the
close's damping onset (the last one the emulator saw): exact for a run that ended RUNNING.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.tasks.locomotion import TRACKING_TOLERANCE, TRACKING_WINDOW


def walk_truth(
    trace: np.ndarray, end: float, running_s: float, command: np.ndarray
) -> dict[str, float | None]:
    """Truth figures over ``(end - running_s, end]``.

    Args:
        trace: (rows, 6) the emulator's trace (monotonic s, x, y m, yaw rad, vx, vy m/s in the
            heading frame). end: monotonic s, the close's damping onset. running_s: s.
        command: (3,) the velocity command (vx, vy m/s, yaw rate rad/s).

    Returns:
        ``distance_m`` (planar path length), ``mean_forward_speed_m_s``, ``tracking_success``
        (fraction of the rows whose velocity averaged over ``TRACKING_WINDOW`` is within
        ``TRACKING_TOLERANCE`` of the command; None without rows), ``rows``.
    """
    rows = trace[(trace[:, 0] > end - running_s) & (trace[:, 0] <= end)]
    if len(rows) < 2:
        return {"distance_m": 0.0, "mean_forward_speed_m_s": None, "tracking_success": None,
                "rows": len(rows)}  # fmt: skip
    dt = np.diff(rows[:, 0])
    distance = float(np.hypot(np.diff(rows[:, 1]), np.diff(rows[:, 2])).sum())
    forward = float((rows[1:, 4] * dt).sum())
    span = float(rows[-1, 0] - rows[0, 0])
    window = max(1, int(round(TRACKING_WINDOW / max(float(np.median(dt)), 1e-6))))
    velocity = rows[:, 4:6]
    kernel = np.ones(window) / window
    mean = np.stack([np.convolve(velocity[:, k], kernel, mode="valid") for k in range(2)], 1)
    error = np.linalg.norm(mean - np.asarray(command, dtype=np.float64)[:2], axis=1)
    return {
        "distance_m": distance,
        "mean_forward_speed_m_s": forward / span if span > 0 else None,
        "tracking_success": float((error <= TRACKING_TOLERANCE).sum() / len(rows)),
        "rows": len(rows),
    }
