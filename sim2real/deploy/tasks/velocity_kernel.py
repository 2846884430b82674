"""The velocity task's tick (a tracker judged on the plant's truth, with or without the heading
hold) as one table of addresses and one compiled call per stage (:class:`TaskCall`).

The tracker's kernels (:mod:`sim2real.deploy.tasks.locomotion_kernel`) and the hold's
(:mod:`sim2real.deploy.tasks.heading_kernel`) run in their own order around the same four
``np.arctan2`` calls, numpy's, on the same arrays: :func:`task_stage` 0 is ``truth_down`` and,
unless an env went down (Python counts its fall first, then stage 1), ``track`` and the hold's
``yaw_args``; stage 2 the tracker's ``turn_args`` and the hold's ``hold_args``; stage 3
``integrate`` and the hold's ``command``. The hold reads the estimate's attitude and writes the
yaw-rate command after the tracker has read it, as when the hold runs after the tracker: the same
numbers. The table (:func:`~sim2real.deploy.kernels.calls.put_slot`) holds every array, so a call
unboxes one array, not forty.
"""

from __future__ import annotations

import numba
import numpy as np

from sim2real.deploy.kernels.calls import SLOT, fits, put_slot, view1, view2, view3
from sim2real.deploy.tasks import heading_kernel as hk
from sim2real.deploy.tasks.locomotion_kernel import integrate, track, truth_down, turn_args

#: The header: ``fused`` (``gemv_fused``), whether the fall check's heights exist, whether the
#: hold runs; then the arrays' slots (``SLOT`` ints each).
FUSED, HAS_HEIGHTS, HAS_HOLD, HEADER = 0, 1, 2, 4
_NAMES = (
    "mode command asked heights estimate orientation gravity angular velocity_world velocity "
    "up down distance forward ring command_ring filled last_command changed_at running_time "
    "tracked_time last_yaw yaw_args yaw sin_cos turn heading_change start_yaw displacement "
    "commanded_turn height_sum height_time h_args h_yaw holding reference hold h_sin_cos "
    "h_error params"
).split()
(
    MODE, COMMAND, ASKED, HEIGHTS, ESTIMATE, ORIENTATION, GRAVITY, ANGULAR, VELOCITY_WORLD,
    VELOCITY, UP, DOWN, DISTANCE, FORWARD, RING, COMMAND_RING, FILLED, LAST_COMMAND, CHANGED_AT,
    RUNNING_TIME, TRACKED_TIME, LAST_YAW, YAW_ARGS, YAW, SIN_COS, TURN, HEADING_CHANGE, START_YAW,
    DISPLACEMENT, COMMANDED_TURN, HEIGHT_SUM, HEIGHT_TIME, H_ARGS, H_YAW, HOLDING, REFERENCE,
    HOLD, H_SIN_COS, H_ERROR, PARAMS,
) = (HEADER + SLOT * k for k in range(len(_NAMES)))  # fmt: skip
#: Bits of :func:`task_stage`'s code: some env went down (stage 0 stopped before ``track``),
#: some env is RUNNING (``track``'s answer).
DOWN_BIT, RUNNING_BIT = 1, 2


@numba.njit(cache=True, nogil=True)
def task_stage(table, stage, truth, slot, time, running):
    """Stage ``stage`` of the task's tick over ``table`` (module docstring); ``truth`` (envs,
    13) the plant's true base, ``slot`` the ring's row, ``time`` s, ``running``: stage 0's
    answer (stages 2 and 3 skip the tracker's part without it). Returns the code's bits."""
    f8, b1 = np.float64, np.bool_
    mode, command = view1(table, MODE, np.int8), view2(table, COMMAND, f8)
    asked = view2(table, ASKED, f8)
    orientation, velocity = view2(table, ORIENTATION, f8), view2(table, VELOCITY, f8)
    params, hold = view1(table, PARAMS, f8), table[HAS_HOLD] != 0
    dt = params[0]
    if stage == 0:
        down = truth_down(
            orientation, view2(table, GRAVITY, f8), view2(table, ANGULAR, f8),
            view2(table, VELOCITY_WORLD, f8), velocity, mode, view1(table, UP, b1),
            view1(table, DOWN, b1), table[FUSED] != 0, truth,
        )  # fmt: skip
        if down:
            return DOWN_BIT
        stage = 1
    if stage == 1:
        on = track(
            mode, velocity, command, orientation, dt, params[1], params[2],
            view1(table, DISTANCE, f8), view1(table, FORWARD, f8), view3(table, RING, f8),
            view3(table, COMMAND_RING, f8), view1(table, FILLED, np.int64),
            view2(table, LAST_COMMAND, f8), view1(table, CHANGED_AT, f8),
            view1(table, RUNNING_TIME, f8), view1(table, TRACKED_TIME, f8),
            view1(table, LAST_YAW, f8), view2(table, YAW_ARGS, f8), slot, time,
        )  # fmt: skip
        if hold:
            hk.yaw_args(view2(table, ESTIMATE, f8), view2(table, H_ARGS, f8))
        return RUNNING_BIT if on else 0
    hold_now = view1(table, HOLD, b1)
    if stage == 2:
        if running:
            turn_args(view1(table, YAW, f8), view1(table, LAST_YAW, f8), view2(table, SIN_COS, f8))
        if hold:
            reference, h_sin_cos = view1(table, REFERENCE, f8), view2(table, H_SIN_COS, f8)
            h_yaw, holding = view1(table, H_YAW, f8), view1(table, HOLDING, b1)
            hk.hold_args(mode, asked, h_yaw, holding, reference, hold_now, h_sin_cos)
        return 0
    if running:
        heights = view1(table, HEIGHTS, f8)
        integrate(
            mode, view1(table, YAW, f8), view1(table, TURN, f8), asked,
            view2(table, VELOCITY_WORLD, f8), dt, heights, table[HAS_HEIGHTS] != 0,
            view1(table, HEADING_CHANGE, f8), view1(table, LAST_YAW, f8),
            view1(table, START_YAW, f8), view2(table, DISPLACEMENT, f8),
            view1(table, COMMANDED_TURN, f8), view1(table, HEIGHT_SUM, f8),
            view1(table, HEIGHT_TIME, f8),
        )  # fmt: skip
    if hold:
        hk.command(hold_now, view1(table, H_ERROR, f8), params[3], params[4], asked, command)
    return 0


class TaskCall:
    """A :class:`~sim2real.deploy.tasks.velocity.VelocityTask`'s tick as :func:`task_stage`'s
    calls, bound to one runtime's arrays (:meth:`build`; :meth:`ready` before each call).

    Attributes:
        fits: Whether the table holds every array (else the task's separate calls, not rebuilt
            while the runtime's arrays stay the same).
    """

    def __init__(self, task, runtime, table=None, arrays=None, scratch=None):
        self.task, self.runtime = task, runtime
        self.mode, self.command = runtime.mode, runtime.velocity_command
        self.estimate = runtime.state.base.orientation
        detector = getattr(runtime, "fall_detector", None)
        self.heights = None if detector is None else detector.height
        self.fits = table is not None
        if not self.fits:
            return
        from sim2real.deploy.kernels.calls import bind

        self._table, self._arrays = table, arrays  # the arrays alive while the table names them
        self._down, self._yaw_args, self._yaw, self._sin_cos, self._turn = scratch[:5]
        self._h_args, self._h_yaw, self._h_sin_cos, self._h_error = scratch[5:]
        self._hold = task.heading is not None
        self._window = task.tracker.window
        self._call = bind(task_stage, table, rest=(0, np.zeros((1, 13)), 0, 0.0, True))

    @classmethod
    def build(cls, task, runtime) -> TaskCall:
        """The call for ``runtime``'s arrays; ``fits`` False where an array is not of the
        kernels' dtype, shape and layout, or the machine's BLAS differs (``gemv_matches``)."""
        from sim2real.deploy.monitors.estimation_kernel import gemv_fused, gemv_matches
        from sim2real.deploy.tasks.locomotion import SETTLE_TIME, TRACKING_TOLERANCE

        tracker, h = task.tracker, task.heading
        envs, window = tracker.envs, tracker.window
        detector = getattr(runtime, "fall_detector", None)
        heights = None if detector is None else detector.height
        if not gemv_matches():
            return cls(task, runtime)
        a = tracker.kernel_arrays()
        base = a["true_base"]
        one, two = (envs,), (2, envs)
        scratch = [np.zeros(envs, dtype=bool)]
        scratch += [np.zeros(s) for s in (two, one, two, one, two, one, two, one)]
        gain, rate = (h.gain, h.max_rate) if h is not None else (0.0, 0.0)
        arrays = dict(zip(_NAMES, (
            runtime.mode, runtime.velocity_command,
            task._asked if h is not None else runtime.velocity_command,
            np.zeros(envs) if heights is None else heights, runtime.state.base.orientation,
            base.orientation, base.projected_gravity, base.angular_velocity,
            base.linear_velocity_world, base.linear_velocity, a["up"], scratch[0],
            *(a[k] for k in _NAMES[12:22]), scratch[1], scratch[2], scratch[3], scratch[4],
            *(a[k] for k in _NAMES[26:32]), scratch[5], scratch[6],
            h.holding if h is not None else np.zeros(envs, dtype=bool),
            h.reference if h is not None else np.zeros(envs),
            h._hold if h is not None else np.zeros(envs, dtype=bool), scratch[7], scratch[8],
            np.array([tracker.dt, TRACKING_TOLERANCE, SETTLE_TIME, gain, rate]),
        ), strict=True))  # fmt: skip
        shapes = dict.fromkeys(_NAMES, one)
        shapes |= dict.fromkeys(("command", "asked", "gravity", "angular"), (envs, 3))
        shapes |= dict.fromkeys(("velocity_world", "velocity"), (envs, 3))
        shapes |= dict.fromkeys(("estimate", "orientation"), (envs, 4))
        shapes |= dict.fromkeys(("last_command", "displacement"), (envs, 2))
        shapes |= dict.fromkeys(("ring", "command_ring"), (window, envs, 2))
        shapes |= dict.fromkeys(("yaw_args", "sin_cos", "h_args", "h_sin_cos"), two)
        shapes["params"] = (5,)
        dtypes = {"mode": np.int8, "filled": np.int64}
        dtypes |= dict.fromkeys(("up", "down", "holding", "hold"), np.bool_)
        table, kept = np.zeros(HEADER + SLOT * len(_NAMES), dtype=np.int64), []
        for k, name in enumerate(_NAMES):
            array, shape = arrays[name], shapes[name]
            if not fits(array, dtypes.get(name, np.float64), shape):
                return cls(task, runtime)
            put_slot(table, kept, HEADER + SLOT * k, array, array.dtype, len(shape))
        table[:HEADER] = (int(gemv_fused()), int(heights is not None), int(h is not None), 0)
        return cls(task, runtime, table, kept, scratch)

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

    table = np.zeros(HEADER + SLOT * len(_NAMES), dtype=np.int64)
    bind(task_stage, table, rest=(0, np.zeros((1, 13)), 0, 0.0, True))
