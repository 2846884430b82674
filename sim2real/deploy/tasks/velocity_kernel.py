"""The velocity task's tick (a tracker judged on the plant's truth, with or without the heading
hold) as one packed table and one compiled call per stage (:class:`TaskCall`).

The tracker's kernels (:mod:`sim2real.deploy.tasks.locomotion_kernel`) and the hold's
(:mod:`sim2real.deploy.tasks.heading_kernel`) run in their own order around the same four
``np.arctan2`` calls, numpy's, on the same arrays: :func:`task_stage` 0 is ``truth_down`` and,
unless an env went down (Python counts its fall first, then stage 1), ``track`` and the hold's
``yaw_args``; stage 2 the tracker's ``turn_args`` and the hold's ``hold_args``; stage 3
``integrate`` and the hold's ``command``. The hold reads the estimate's attitude and writes the
yaw-rate command after the tracker has read it, as when the hold runs after the tracker: the same
numbers. The packed table (:data:`TASK`) holds every array, so a call unboxes one array, not
forty.
"""

from __future__ import annotations

import numba
import numpy as np

from sim2real.deploy.kernels.tables import Table
from sim2real.deploy.tasks import heading_kernel as hk
from sim2real.deploy.tasks.locomotion_kernel import integrate, track, truth_down, turn_args

#: The task's arrays and constants: the runtime's (``mode`` .. ``velocity``), the tracker's and
#: the hold's (``h_*``, ``holding``, ``reference``, ``hold``), the scratch rows of numpy's
#: ``arctan2`` calls (``*_args``, ``sin_cos``: (2, envs) its y and x rows), and ``fused``
#: (``gemv_fused``), whether the fall check's heights exist and the hold runs; ``dt`` s, the
#: tracker's tolerance and settle time, its yaw-rate tolerance, the hold's gain and maximum rate.
TASK = Table(
    "sim2real.deploy.tasks.velocity_kernel:TASK",
    fused="b1", has_heights="b1", has_hold="b1", dt="f8", tolerance="f8", settle="f8",
    yaw_tolerance="f8", gain="f8", rate="f8",
    mode="i1[envs]", command="f8[envs,3]", asked="f8[envs,3]", heights="f8[envs]",
    estimate="f8[envs,4]", orientation="f8[envs,4]", gravity="f8[envs,3]",
    angular="f8[envs,3]", velocity_world="f8[envs,3]", velocity="f8[envs,3]", up="b1[envs]",
    down="b1[envs]", distance="f8[envs]", forward="f8[envs]", ring="f8[window,envs,2]",
    command_ring="f8[window,envs,2]", filled="i8[envs]", last_command="f8[envs,2]",
    changed_at="f8[envs]", running_time="f8[envs]", tracked_time="f8[envs]",
    last_yaw="f8[envs]", yaw_args="f8[2,envs]", yaw="f8[envs]", sin_cos="f8[2,envs]",
    turn="f8[envs]", heading_change="f8[envs]", start_yaw="f8[envs]",
    displacement="f8[envs,2]", commanded_turn="f8[envs]", height_sum="f8[envs]",
    height_time="f8[envs]", h_args="f8[2,envs]", h_yaw="f8[envs]", holding="b1[envs]",
    reference="f8[envs]", hold="b1[envs]", h_sin_cos="f8[2,envs]", h_error="f8[envs]",
    yaw_ring="f8[window,envs]", yaw_command_ring="f8[window,envs]", yaw_filled="i8[envs]",
    last_yaw_command="f8[envs]", yaw_changed_at="f8[envs]", yaw_tracked_time="f8[envs]",
)  # fmt: skip
#: Bits of :func:`task_stage`'s code: some env went down (stage 0 stopped before ``track``),
#: some env is RUNNING (``track``'s answer).
DOWN_BIT, RUNNING_BIT = 1, 2


@numba.njit(cache=True, nogil=True)
def task_stage(t, stage, truth, slot, time, running):
    """Stage ``stage`` of the task's tick over the packed table ``t`` (:data:`TASK`, module
    docstring); ``truth`` (envs,
    13) the plant's true base, ``slot`` the ring's row, ``time`` s, ``running``: stage 0's
    answer (stages 2 and 3 skip the tracker's part without it). Returns the code's bits."""
    mode, command, asked = t.mode, t.command, t.asked
    orientation, velocity, hold, dt = t.orientation, t.velocity, t.has_hold, t.dt
    if stage == 0:
        down = truth_down(
            orientation, t.gravity, t.angular, t.velocity_world, velocity, mode, t.up, t.down,
            t.fused, truth,
        )  # fmt: skip
        if down:
            return DOWN_BIT
        stage = 1
    if stage == 1:
        on = track(
            mode, velocity, command, orientation, dt, t.tolerance, t.settle, t.distance,
            t.forward, t.ring, t.command_ring, t.filled, t.last_command, t.changed_at,
            t.running_time, t.tracked_time, t.last_yaw, t.yaw_args, slot, time,
        )  # fmt: skip
        if hold:
            hk.yaw_args(t.estimate, t.h_args)
        return RUNNING_BIT if on else 0
    if stage == 2:
        if running:
            turn_args(t.yaw, t.last_yaw, t.sin_cos)
        if hold:
            hk.hold_args(mode, asked, t.h_yaw, t.holding, t.reference, t.hold, t.h_sin_cos)
        return 0
    if running:
        integrate(
            mode, t.yaw, t.turn, asked, t.velocity_world, dt, t.heights, t.has_heights,
            t.heading_change, t.last_yaw, t.start_yaw, t.displacement, t.commanded_turn,
            t.height_sum, t.height_time, command, t.yaw_tolerance, t.settle, t.yaw_ring,
            t.yaw_command_ring, t.yaw_filled, t.last_yaw_command, t.yaw_changed_at,
            t.yaw_tracked_time, slot, time,
        )  # fmt: skip
    if hold:
        hk.command(t.hold, t.h_error, t.gain, t.rate, asked, command)
    return 0


class TaskCall:
    """A :class:`~sim2real.deploy.tasks.velocity.VelocityTask`'s tick as :func:`task_stage`'s
    calls, bound to one runtime's arrays (:meth:`build`; :meth:`ready` before each call).

    Attributes:
        fits: Whether the table holds every array (else the task's separate calls, not rebuilt
            while the runtime's arrays stay the same).
    """

    def __init__(self, task, runtime, table=None):
        self.task, self.runtime = task, runtime
        self.mode, self.command = runtime.mode, runtime.velocity_command
        self.estimate = runtime.state.base.orientation
        detector = getattr(runtime, "fall_detector", None)
        self.heights = None if detector is None else detector.height
        self.fits = table is not None
        if not self.fits:
            return
        from sim2real.deploy.kernels.calls import bind

        at = table.arrays  # numpy's arctan2 calls between the stages read and write these
        self._down, self._yaw_args, self._yaw = at["down"], at["yaw_args"], at["yaw"]
        self._sin_cos, self._turn, self._h_args = at["sin_cos"], at["turn"], at["h_args"]
        self._h_yaw, self._h_sin_cos, self._h_error = at["h_yaw"], at["h_sin_cos"], at["h_error"]
        self._hold = task.heading is not None
        self._window = task.tracker.window
        self._call = bind(task_stage, table, rest=(0, np.zeros((1, 13)), 0, 0.0, True))

    @classmethod
    def build(cls, task, runtime) -> TaskCall:
        """The call for ``runtime``'s arrays; ``fits`` False where an array is not of the
        kernels' dtype, shape and layout, or the machine's BLAS differs (``gemv_matches``)."""
        from sim2real.deploy.monitors.estimation_kernel import gemv_fused, gemv_matches
        from sim2real.deploy.tasks.locomotion import (
            SETTLE_TIME,
            TRACKING_TOLERANCE,
            YAW_TRACKING_TOLERANCE,
        )

        tracker, h = task.tracker, task.heading
        envs, window = tracker.envs, tracker.window
        detector = getattr(runtime, "fall_detector", None)
        heights = None if detector is None else detector.height
        if not gemv_matches():
            return cls(task, runtime)
        a = tracker.kernel_arrays()
        base = a.pop("true_base")
        one, two = (envs,), (2, envs)
        scratch = {"down": np.zeros(envs, dtype=bool)}
        scratch |= {k: np.zeros(two) for k in ("yaw_args", "sin_cos", "h_args", "h_sin_cos")}
        scratch |= {k: np.zeros(one) for k in ("yaw", "turn", "h_yaw", "h_error")}
        gain, rate = (h.gain, h.max_rate) if h is not None else (0.0, 0.0)
        table = TASK.pack_or_none(
            {"envs": envs, "window": window},  # the slot the call takes is ticks % window
            fused=gemv_fused(), has_heights=heights is not None, has_hold=h is not None,
            dt=tracker.dt, tolerance=TRACKING_TOLERANCE, settle=SETTLE_TIME,
            yaw_tolerance=YAW_TRACKING_TOLERANCE, gain=gain, rate=rate,
            mode=runtime.mode, command=runtime.velocity_command,
            asked=task.asked if h is not None else runtime.velocity_command,
            heights=np.zeros(envs) if heights is None else heights,
            estimate=runtime.state.base.orientation, orientation=base.orientation,
            gravity=base.projected_gravity, angular=base.angular_velocity,
            velocity_world=base.linear_velocity_world, velocity=base.linear_velocity,
            holding=h.holding if h is not None else np.zeros(envs, dtype=bool),
            reference=h.reference if h is not None else np.zeros(envs),
            hold=h._hold if h is not None else np.zeros(envs, dtype=bool),
            **a, **scratch,
        )  # fmt: skip
        if table is None:
            return cls(task, runtime)
        return cls(task, runtime, table)

    def ready(self, runtime) -> bool:
        """Whether the call holds ``runtime``'s arrays."""
        detector = getattr(runtime, "fall_detector", None)
        return (
            runtime is self.runtime
            and runtime.mode is self.mode
            and runtime.velocity_command is self.command
            and runtime.state.base.orientation is self.estimate
            and (None if detector is None else detector.height) is self.heights
        )

    def __call__(self, runtime, truth) -> None:
        """One tick: ``truth`` (envs, 13) float64 C-contiguous, the plant's true base."""
        call, arctan2 = self._call, np.arctan2
        slot, time = runtime.ticks % self._window, float(runtime.time)
        code = call(0, truth, slot, time, False)
        if code & DOWN_BIT:
            self.task.tracker.account_falls(runtime, self._down, truth)
            code = call(1, truth, slot, time, False)
        running = code & RUNNING_BIT != 0
        if not (running or self._hold):
            return
        if running:
            arctan2(self._yaw_args[0], self._yaw_args[1], out=self._yaw)
        if self._hold:
            arctan2(self._h_args[0], self._h_args[1], out=self._h_yaw)
        call(2, truth, slot, time, running)
        if running:
            arctan2(self._sin_cos[0], self._sin_cos[1], out=self._turn)
        if self._hold:
            arctan2(self._h_sin_cos[0], self._h_sin_cos[1], out=self._h_error)
        call(3, truth, slot, time, running)


def load() -> None:
    """Compile (or load from numba's cache) :func:`task_stage` for its table: done when a task
    judged on the truth is built, so that the first tick does not wait for it."""
    from sim2real.deploy.kernels.calls import bind

    bind(task_stage, TASK.empty(), rest=(0, np.zeros((1, 13)), 0, 0.0, True))
