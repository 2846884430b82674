"""The joint jerk at action-chunk boundaries against the jerk inside chunks
(:func:`boundary_jerk`), the figure of a chunked policy's run (``deploy-run``'s ``chunks`` section,
:class:`sim2real.deploy.rig.chunk_hook.ChunkHook`).

A chunked policy (LeRobot's ACT) takes a new chunk every ``n_action_steps`` policy ticks; its
next chunk starts again from the robot's state, so its target jumps at a chunk boundary, where
inside a chunk it moves by one step of a smooth trajectory. The jerk (third finite difference of
a joint's position, or of a command, over the servo period) is taken in a window of one policy
period after each boundary and after each policy tick inside a chunk, its peak over the joints
and the window; the figures are the medians and maxima of those peaks.
"""

from __future__ import annotations

import numpy as np


def jerk(x: np.ndarray, dt: float) -> np.ndarray:
    """(ticks - 3, n) rad/s^3, the third finite difference of ``x`` ((ticks, n) rad) over
    ``dt`` s."""
    return np.diff(np.asarray(x, float), n=3, axis=0) / dt**3


def boundary_jerk(
    x: np.ndarray,
    dt: float,
    period: float,
    boundaries,
    policy_ticks,
) -> dict:
    """Peak |jerk| (rad/s^3, over joints) within one policy period after each chunk boundary,
    against the same after each policy tick inside a chunk.

    Args:
        x: (ticks, n) rad, one value per servo tick (a joint position or a command).
        dt: s, the servo period. period: s, the policy's period.
        boundaries: Servo ticks at which a new chunk was taken (the first chunk of a run, a jump
            from rest, left out by the caller).
        policy_ticks: Servo ticks of every policy tick (the boundaries among them).

    Returns:
        ``{"boundary_median", "boundary_max", "inside_median", "inside_max", "boundaries",
        "inside"}``: medians and maxima over the windows (NaN where there is none: with temporal
        ensembling every policy tick takes a chunk) and the windows counted. A window is the
        third differences of one policy period of ``x`` from its tick on (``jerk`` index
        ``s - 3`` reads ``x[s - 3 : s + 1]``, the first to see a step at tick ``s``); one
        reaching before the start or past the end of ``x`` is left out.
    """
    j = np.abs(jerk(x, dt)).max(axis=1) if len(x) > 3 else np.zeros(0)
    span = max(1, int(round(period / dt)))
    starts = sorted(set(int(s) for s in boundaries))
    inside = sorted(set(int(s) for s in policy_ticks) - set(starts))

    def peaks(ticks) -> np.ndarray:
        return np.asarray(
            [
                j[max(0, s - 3) : s - 3 + span].max()
                for s in ticks
                if s >= 3 and s - 3 + span <= len(j)
            ]
        )

    b, i = peaks(starts), peaks(inside)

    def stat(a: np.ndarray, f) -> float:
        return float(f(a)) if len(a) else float("nan")

    return {
        "boundary_median": stat(b, np.median),
        "boundary_max": stat(b, np.max),
        "inside_median": stat(i, np.median),
        "inside_max": stat(i, np.max),
        "boundaries": int(len(b)),
        "inside": int(len(i)),
    }
