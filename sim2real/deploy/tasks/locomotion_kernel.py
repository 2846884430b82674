"""The compiled arithmetic of :meth:`sim2real.deploy.tasks.locomotion.CommandTracker.__call__`.

A tick of a tracker judged on the plant's truth is :func:`truth_down` (the true base, the stops),
:func:`track` (distance, tracking, the heading's arguments), ``np.arctan2``, :func:`turn_args`,
``np.arctan2`` and :func:`integrate` (heading change, yaw-rate tracking, displacement, commanded
turn, height);
numpy's arctan2 is not the C library's, so the two arc tangents stay numpy's. Each expression is
numpy's in numpy's order: a mean over the window's ring sums its rows in order and divides, sums
of two or three terms go left to right, ``np.angle(np.exp(1j * d))`` is ``arctan2(sin d, cos d)``;
the true base is :func:`sim2real.deploy.monitors.estimation_kernel.true_base`'s.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim2real.deploy.kernels.calls import fits
from sim2real.deploy.monitors.estimation_kernel import fields, gemv_fused, gemv_matches, true_base


@numba.njit(cache=True, nogil=True)
def truth_down(
    orientation, gravity, angular, velocity_world, velocity, mode, up, down, fused, truth
):  # fmt: skip
    """Fill the true base from ``truth`` (envs, 13) as ``BaseState.set_truth`` (``fused``:
    :func:`~sim2real.deploy.monitors.estimation_kernel.gemv_fused`); ``down`` (envs,) bool: the
    envs RUNNING since their last stop that stopped now (mode >= SAFE_STOP); ``up`` updated (not
    down, or RUNNING). Returns whether any env is down."""
    anydown = False
    for e in range(truth.shape[0]):
        true_base(truth, e, orientation, gravity, angular, velocity_world, velocity, fused)
        d = up[e] and mode[e] >= 3
        down[e] = d
        anydown = anydown or d
        up[e] = (up[e] and not d) or mode[e] == 2
    return anydown


@numba.njit(cache=True, nogil=True)
def track(
    mode, velocity, command, orientation, dt, tolerance, settle, distance, forward, ring,
    command_ring, filled, last_command, changed_at, running_time, tracked_time, last_yaw,
    yaw_args, slot, time,
):  # fmt: skip
    """Distance, tracking and the last command of one tick (``velocity`` (envs, 3) m/s base
    frame, the truth's; ``command`` (envs, 3) the runtime's; ``slot`` the ring's row, ``time``
    s); ``yaw_args`` (2, envs): the arc tangent's arguments of the heading of ``orientation``
    (envs, 4). Returns whether any env is RUNNING."""
    envs, window = mode.shape[0], ring.shape[0]
    any_running = False
    for e in range(envs):
        running = mode[e] == 2
        any_running = any_running or running
        s0, s1 = velocity[e, 0] * dt, velocity[e, 1] * dt
        distance[e] += math.sqrt(s0 * s0 + s1 * s1) if running else 0.0
        forward[e] += s0 if running else 0.0
        ring[slot, e, 0], ring[slot, e, 1] = velocity[e, 0], velocity[e, 1]
        command_ring[slot, e, 0], command_ring[slot, e, 1] = command[e, 0], command[e, 1]
        filled[e] = min(filled[e] + 1, window) if running else 0
        full = filled[e] >= window
        m0, m1, c0, c1 = ring[0, e, 0], ring[0, e, 1], command_ring[0, e, 0], command_ring[0, e, 1]
        for k in range(1, window):
            m0 += ring[k, e, 0]
            m1 += ring[k, e, 1]
            c0 += command_ring[k, e, 0]
            c1 += command_ring[k, e, 1]
        d0, d1 = m0 / window - c0 / window, m1 / window - c1 / window
        error = math.sqrt(d0 * d0 + d1 * d1)
        a0, a1 = command[e, 0] - last_command[e, 0], command[e, 1] - last_command[e, 1]
        if math.sqrt(a0 * a0 + a1 * a1) > tolerance:
            changed_at[e] = time
        last_command[e, 0], last_command[e, 1] = command[e, 0], command[e, 1]
        settling = time - changed_at[e] < settle
        running_time[e] += (1.0 if running else 0.0) * dt
        ok = (full and error <= tolerance) or settling
        tracked_time[e] += (1.0 if running and ok else 0.0) * dt
        if not running:
            last_yaw[e] = np.nan
        w, x, y, z = orientation[e, 0], orientation[e, 1], orientation[e, 2], orientation[e, 3]
        yaw_args[0, e] = 2.0 * (w * z + x * y)
        yaw_args[1, e] = 1.0 - 2.0 * (y * y + z * z)
    return any_running


@numba.njit(cache=True, nogil=True)
def turn_args(yaw, last_yaw, sin_cos):
    """``sin_cos`` (2, envs): the sine and cosine of ``yaw - last_yaw`` (envs,) rad."""
    for e in range(yaw.shape[0]):
        d = yaw[e] - last_yaw[e]
        sin_cos[0, e] = math.sin(d)
        sin_cos[1, e] = math.cos(d)


@numba.njit(cache=True, nogil=True)
def integrate(
    mode, yaw, turn, asked, velocity_world, dt, heights, has_heights, heading_change, last_yaw,
    start_yaw, displacement, commanded_turn, height_sum, height_time, command, yaw_tolerance,
    settle, yaw_ring, yaw_command_ring, yaw_filled, last_yaw_command, yaw_changed_at,
    yaw_tracked_time, slot, time,
):  # fmt: skip
    """Heading change (``turn`` (envs,) rad, wrapped), the yaw-rate tracking (``turn / dt``
    against ``command[:, 2]``, the runtime's, over the rings' ``slot``; ``time`` s),
    displacement along and across the first heading, commanded turn (``asked`` (envs, 3)) and
    the fall check's ``heights`` (envs,) m."""
    window = yaw_ring.shape[0]
    for e in range(mode.shape[0]):
        running = mode[e] == 2
        t = turn[e]
        heading_change[e] += t if running and math.isfinite(t) else 0.0
        known = running and math.isfinite(t)
        yaw_ring[slot, e] = t / dt if known else 0.0
        c = command[e, 2]
        yaw_command_ring[slot, e] = c
        yaw_filled[e] = min(yaw_filled[e] + 1, window) if known else 0
        m, n = yaw_ring[0, e], yaw_command_ring[0, e]
        for k in range(1, window):
            m += yaw_ring[k, e]
            n += yaw_command_ring[k, e]
        error = abs(m / window - n / window)
        if abs(c - last_yaw_command[e]) > yaw_tolerance:
            yaw_changed_at[e] = time
        last_yaw_command[e] = c
        settling = time - yaw_changed_at[e] < settle
        ok = (yaw_filled[e] >= window and error <= yaw_tolerance) or settling
        yaw_tracked_time[e] += (1.0 if running and ok else 0.0) * dt
        last_yaw[e] = yaw[e] if running else np.nan
        if running and math.isnan(start_yaw[e]):
            start_yaw[e] = yaw[e]
        heading = 0.0 if math.isnan(start_yaw[e]) else start_yaw[e]
        c, s = math.cos(heading), math.sin(heading)
        vx, vy = velocity_world[e, 0], velocity_world[e, 1]
        along, across = c * vx + s * vy, -s * vx + c * vy
        displacement[e, 0] += (along if running else 0.0) * dt
        displacement[e, 1] += (across if running else 0.0) * dt
        commanded_turn[e] += asked[e, 2] * dt if running else 0.0
        if has_heights:
            known = running and math.isfinite(heights[e])
            height_sum[e] += (heights[e] if known else 0.0) * dt
            height_time[e] += (1.0 if known else 0.0) * dt


class TrackerCall:
    """A :class:`~sim2real.deploy.tasks.locomotion.CommandTracker`'s tick as the kernels of this
    module, bound to the arrays of one runtime (:meth:`build`; :meth:`ready` before each call)."""

    def __init__(self, tracker, runtime, asked, heights, limits: tuple, fits: bool = True):
        from sim2real.deploy.kernels.calls import bind

        self.tracker, self.runtime, self.asked, self.heights = tracker, runtime, asked, heights
        self.mode, self.command = runtime.mode, runtime.velocity_command
        #: whether the kernels take these arrays (else the tracker's numpy path, not rebuilt
        #: while they stay the same)
        self.fits = fits
        if not fits:
            return
        a = tracker.kernel_arrays()
        envs = tracker.envs
        base = a["true_base"]
        arrays = fields(base)
        self._down = np.zeros(envs, dtype=bool)
        self._yaw_args, self._yaw = np.zeros((2, envs)), np.zeros(envs)
        self._sin_cos, self._turn = np.zeros((2, envs)), np.zeros(envs)
        example = np.zeros((1, 13))
        self._truth_down = bind(
            truth_down, *arrays, self.mode, a["up"], self._down, gemv_fused(), rest=(example,)
        )
        dt = tracker.dt
        names = ("distance", "forward", "ring", "command_ring", "filled", "last_command")
        names += ("changed_at", "running_time", "tracked_time", "last_yaw")
        self._track = bind(
            track,
            *(self.mode, base.linear_velocity, self.command, base.orientation, dt),
            *(*limits[:2], *(a[k] for k in names), self._yaw_args),
            rest=(0, 0.0),
        )
        self._turn_args = bind(turn_args, self._yaw, a["last_yaw"], self._sin_cos)
        has = heights is not None
        yaw = ("yaw_ring", "yaw_command_ring", "yaw_filled", "last_yaw_command")
        yaw += ("yaw_changed_at", "yaw_tracked_time")
        self._integrate = bind(
            integrate,
            *(self.mode, self._yaw, self._turn, asked, base.linear_velocity_world, dt),
            *(heights if has else np.zeros(envs), has, a["heading_change"], a["last_yaw"]),
            *(a["start_yaw"], a["displacement"], a["commanded_turn"], a["height_sum"]),
            *(a["height_time"], self.command, *limits[2:], limits[1]),
            *(a[k] for k in yaw),
            rest=(0, 0.0),
        )
        self._window = tracker.window

    @classmethod
    def build(cls, tracker, runtime, asked, limits: tuple) -> TrackerCall:
        """The call for ``runtime`` (``asked``: the command of the turn, (envs, 3); ``limits``:
        the tracking tolerance, m/s, the settling time, s, and the yaw-rate tolerance, rad/s;
        ``fits``
        False: an array the kernels do not take, or a machine whose BLAS differs
        (:func:`gemv_matches`)."""
        envs = tracker.envs
        detector = getattr(runtime, "fall_detector", None)
        heights = None if detector is None else detector.height
        ok = (
            gemv_matches()
            and fits(runtime.mode, np.int8, (envs,))
            and fits(runtime.velocity_command, np.float64, (envs, 3))
            and fits(asked, np.float64, (envs, 3))
            and (heights is None or fits(heights, np.float64, (envs,)))
        )
        return cls(tracker, runtime, asked, heights, limits, fits=bool(ok))

    def ready(self, runtime, asked) -> bool:
        """Whether the call holds ``runtime``'s arrays and ``asked``."""
        detector = getattr(runtime, "fall_detector", None)
        return (
            runtime is self.runtime
            and asked is self.asked
            and runtime.mode is self.mode
            and runtime.velocity_command is self.command
            and (None if detector is None else detector.height) is self.heights
        )

    def __call__(self, runtime, truth) -> None:
        """One tick: ``truth`` (envs, 13) float64 C-contiguous, the plant's true base."""
        tracker = self.tracker
        if self._truth_down(truth):
            tracker.account_falls(runtime, self._down, truth)
        slot = runtime.ticks % self._window
        if not self._track(slot, float(runtime.time)):
            return
        np.arctan2(self._yaw_args[0], self._yaw_args[1], out=self._yaw)
        self._turn_args()
        np.arctan2(self._sin_cos[0], self._sin_cos[1], out=self._turn)
        self._integrate(slot, float(runtime.time))


def load() -> None:
    """Compile (or load from numba's cache) the kernels' specializations for the runtime's
    arrays' types (float64, an int8 mode, bool flags, int64 counts): done when a tracker judged
    on the truth is built, so that the first tick does not wait for it."""
    from sim2real.deploy.kernels.calls import bind

    f3, f1, b = np.zeros((1, 3)), np.zeros(1), np.zeros(1, dtype=np.bool_)
    mode, i = np.zeros(1, dtype=np.int8), np.zeros(1, dtype=np.int64)
    q, f2, two, ring = np.zeros((1, 4)), np.zeros((1, 2)), np.zeros((2, 1)), np.zeros((1, 1, 2))
    bind(truth_down, q, f3, f3, f3, f3, mode, b, b, True, rest=(np.zeros((1, 13)),))
    track_arrays = (f1, f1, ring, ring, i, f2, f1, f1, f1, f1, two)
    bind(track, mode, f3, f3, q, 1.0, 1.0, 1.0, *track_arrays, rest=(0, 0.0))
    bind(turn_args, f1, f1, two)
    yaw = (ring[0], ring[0], i, f1, f1, f1)
    bind(
        integrate, mode, f1, f1, f3, f3, 1.0, f1, True, f1, f1, f1, f2, f1, f1, f1, f3, 1.0, 1.0,
        *yaw, rest=(0, 0.0),
    )  # fmt: skip
