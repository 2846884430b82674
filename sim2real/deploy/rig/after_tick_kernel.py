"""The rig's after-tick work in one compiled call (:func:`after_tick`): the violation and
collision screens over the true state, the intervention counters' comparison, the goal
scheduler's timing and hit test, and ``deploy-run``'s motion figures, over one packed table
(:data:`AFTER`) built by :class:`sim2real.deploy.rig.after_tick.FusedAfterTick`.

The kernel gathers the true joint state from the plant's per-env views into the plant's arrays
(what ``true_position()`` and ``true_velocity()`` do) and the end-effector sites into the
monitors' arrays (``end_effector_position(out)``), then calls the monitors' own kernels of
:mod:`sim2real.deploy.monitors.kernel` in the order the monitors run, so the numbers are theirs
bit for bit. It stops where Python must act and says so in its returned bits: coal's collision
check or the exact per-type count of a flagged violation, an intervention counter that moved, a
goal due or reached. It times the monitors (from the caller's stamp to the end of the
intervention screen) and the motion figures with ``clock_gettime(CLOCK_MONOTONIC)``, the clock of
``time.perf_counter_ns``, into the rig's histograms (the bins of
:class:`sim2real.deploy.core.latency.LatencyHistogram`); when Python has monitor work left (a
legged robot's estimation monitor, always), the monitors' end stamp is left in ``stamp`` for
Python to finish the sample. An edit to a kernel of
:mod:`sim2real.deploy.monitors.kernel` recompiles the call (:mod:`sim2real.numba_cache`).
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

from sim2real.deploy.kernels.calls import pointer
from sim2real.deploy.kernels.tables import Table
from sim2real.deploy.monitors import kernel as mk
from sim2real.deploy.monitors.pair_bounds import APART, pair_lower_bounds

#: The call's arrays and constants: the plant's gathered state (``q``, ``dq``, ``tau``), the
#: clock's scratch (``stamp``: s, ns, the monitors' end), the violation monitor's (``v_*``), the
#: intervention monitor's (``i_*``; ``rows`` the guard's count rows), the monitors' and the
#: hooks' cost histograms (``bins`` + 1 columns of ``bin_ns``), the runtime's modes and goals,
#: the goal scheduler's (``g_*``: zeros without ``has_goals``), the motion figures' (zeros
#: without motion), ``b_*`` the pair bounds' arrays (``has_bounds``; :class:`sim2real.deploy.
#: monitors.pair_bounds.PairBounds`), and ``views`` (3, envs): each env's ``MjData`` qpos, qvel
#: and end-effector site addresses (MuJoCo's memory, alive with the plant's envs). ``margin`` m, ``dt`` s;
#: ``running``, ``safe_stop``: the modes' codes; ``lies_down``: an env in SAFE_STOP or FAULTED
#: lies down (a legged robot's), its ticks counted apart, the monitors' cost sample left to
#: Python (which runs the estimation monitor).
AFTER = Table(
    "sim2real.deploy.rig.after_tick_kernel:AFTER",
    has_workspace="b1", has_pairs="b1", has_goals="b1", lies_down="b1", running="i8",
    safe_stop="i8", bin_ns="i8", bins="i8", hook_stage="i8", margin="f8", dt="f8",
    q="f8[envs,n]", dq="f8[envs,n]", tau="f8[envs,n]", stamp="i8[3]", v_ee="f8[envs,3]",
    v_offset_q="f8[n]", v_offset_ee="f8[3]", v_bound="f8[*]", v_checked_q="f8[envs,n]",
    v_clearance="f8[envs,pairs]", v_weights="f8[pairs,n]", v_tmp="f8[envs,n]",
    v_need="b1[envs]", v_down="b1[envs]", v_ticks="i8[1]", i_guard="i8[rows,envs]",
    i_prev_guard="i8[rows,envs]", i_stopping="i8[envs,n]", i_clamps="i8[envs,n]",
    i_prev_smoother="i8[2,envs,n]", i_ticks="i8[1]", m_counts="i8[*,columns]", m_max="i8[*]",
    mode="i1[envs]", goal="f8[envs,3]", g_issued="i8[envs]", g_t_goal="f8[envs]",
    g_reached="b1[envs]", g_age="f8[envs]", g_due="b1[envs]", g_check="b1[envs]",
    g_ee="f8[envs,3]", g_best="f8[envs]", g_distance="f8[envs]", g_hit="b1[envs]",
    temperature="f8[envs,n]", peak="f8[envs,n]", prev_dq="f8[envs,n]", prev_acc="f8[envs,n]",
    jerk_sum="f8[envs,n]", jerk_ticks="i8[envs]", max_speed="f8[n]", h_counts="i8[*,columns]",
    h_max="i8[*]", views="i8[3,envs]", has_bounds="b1", b_joints="i8[*,4]",
    b_joint_frames="f8[*,4,3]", b_joint_axes="f8[*,3]", b_geoms="i8[*,2]",
    b_geom_frames="f8[*,4,3]", b_shapes="f8[*,4]", b_pairs="i8[*,2]", b_frames="f8[*,4,3]",
    b_placed="f8[*,4,3]",
)  # fmt: skip
#: The pair bounds' fields of ``AFTER``, in the order of ``PairBounds.arrays()``.
BOUNDS_FIELDS = (
    "b_joints", "b_joint_frames", "b_joint_axes", "b_geoms", "b_geom_frames", "b_shapes",
    "b_pairs", "b_frames", "b_placed",
)  # fmt: skip
#: The rows of ``views``.
QPOS, QVEL, SITE = 0, 1, 2
#: Bits of the returned code: the collision pairs of some env need coal (``v_need``), some env
#: may be past a limit, an intervention counter moved (the monitors' cost sample is then left to
#: Python: ``stamp[2]`` holds the end of the screens), a goal is due (``g_due``), a goal was
#: reached (``g_hit``).
COLLISION_CHECK, VIOLATION_FLAGGED, INTERVENTIONS_MOVED, GOAL_DUE, GOAL_HIT = 1, 2, 4, 8, 16
#: The bits after which Python finishes the monitors' work.
MONITOR_WORK = COLLISION_CHECK | VIOLATION_FLAGGED | INTERVENTIONS_MOVED


@intrinsic
def _clock_gettime(typingctx, timespec):
    """``clock_gettime(CLOCK_MONOTONIC, timespec)``, ``timespec`` the address of two int64
    (s, ns)."""

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(32), [ir.IntType(32), cgutils.voidptr_t])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "clock_gettime")
        address = builder.inttoptr(args[0], cgutils.voidptr_t)
        return builder.call(fn, [ir.Constant(ir.IntType(32), 1), address])

    return types.int32(timespec), codegen


@numba.njit(cache=True, nogil=True, inline="always")
def monotonic_ns(scratch) -> int:
    """``time.perf_counter_ns()`` (CLOCK_MONOTONIC) in a kernel; ``scratch`` (2,) int64."""
    _clock_gettime(scratch.ctypes.data)
    return scratch[0] * 1_000_000_000 + scratch[1]


@numba.njit(cache=True, nogil=True, inline="always")
def add_sample(counts, max_ns, stage: int, ns: int, width: int, top: int) -> None:
    """``LatencyHistogram.add(stage, ns)`` on its ``counts`` and ``max_ns``."""
    k = ns // width
    counts[stage, (top if k > top else k) if ns > 0 else 0] += 1
    if ns > max_ns[stage]:
        max_ns[stage] = ns


@numba.njit(cache=True, nogil=True, inline="always")
def _view(views, row: int, e: int, length: int):
    """Env ``e``'s ``MjData`` array of row ``row`` of ``views`` (``length`` float64)."""
    return numba.carray(pointer(views[row, e]), (length,), np.float64)


@numba.njit(cache=True, nogil=True, inline="always")
def sites(views, out) -> None:
    """The end-effector sites of every env (``views``' ``SITE`` row) into ``out`` (envs, 3) m."""
    for e in range(out.shape[0]):
        site = _view(views, SITE, e, 3)
        for i in range(3):
            out[e, i] = site[i]


@numba.njit(cache=True, nogil=True)
def after_tick(
    t,
    time: float,
    start_ns: int,
    period: float,
    periodic: bool,
    success_time: float,
    success_radius: float,
    count_jerk: bool,
    motion: bool,
) -> int:
    """One tick's monitors and goals and, with ``motion``, the motion figures, over the packed
    table ``t`` (:data:`AFTER`, module docstring).

    Args:
        time: The runtime's time, s. start_ns: ``time.perf_counter_ns()`` when the monitors
            began. period, periodic, success_time, success_radius: the goal scheduler's (s, s,
            m). count_jerk: the runtime is past its second tick (the jerk is counted).

    Returns:
        The bits ``COLLISION_CHECK`` ... ``GOAL_HIT``; 0: nothing left for Python.
    """
    q, dq, tau, v_ee, views, stamp = t.q, t.dq, t.tau, t.v_ee, t.views, t.stamp
    envs, n = q.shape
    for e in range(envs):  # true_position(), true_velocity()
        qpos, qvel = _view(views, QPOS, e, n), _view(views, QVEL, e, n)
        for j in range(n):
            q[e, j] = qpos[j]
            dq[e, j] = qvel[j]
    if t.has_workspace:
        sites(views, v_ee)  # end_effector_position(out)
    # the violation monitor (update with down: a legged robot's envs lying damped after a stop,
    # ``Runtime.damping``; else every env is up)
    mode, down, lies_down, safe_stop = t.mode, t.v_down, t.lies_down, t.safe_stop
    for e in range(envs):
        down[e] = lies_down and mode[e] >= safe_stop
    t.v_ticks[0] += 1
    code = 0
    if t.has_pairs:
        need = mk.collision_screen(
            q, t.v_checked_q, t.v_clearance, t.v_weights, t.margin, t.v_tmp, t.v_need
        )
        if need and t.has_bounds:  # coal only for an env with a pair within APART
            need = False
            for e in range(envs):
                if t.v_need[e]:
                    near = pair_lower_bounds(
                        q, t.b_joints, t.b_joint_frames, t.b_joint_axes, t.b_geoms,
                        t.b_geom_frames, t.b_shapes, t.b_pairs, t.b_frames, t.b_placed,
                        t.v_weights, t.margin, t.v_checked_q, t.v_clearance, APART, e,
                    )  # fmt: skip
                    t.v_need[e] = near
                    need = need or near
        if need:
            code |= COLLISION_CHECK
    if mk.violation_screen(
        q, dq, tau, v_ee, t.v_offset_q, t.v_offset_ee, t.v_bound, t.has_workspace
    ):
        code |= VIOLATION_FLAGGED
    # the intervention monitor
    t.i_ticks[0] += 1
    if mk.interventions_moved(
        t.i_guard, t.i_prev_guard, t.i_stopping, t.i_clamps, t.i_prev_smoother
    ):
        code |= INTERVENTIONS_MOVED
    width, top = t.bin_ns, t.bins
    end = monotonic_ns(stamp)
    if code == 0 and not lies_down:
        add_sample(t.m_counts, t.m_max, 0, end - start_ns, width, top)
    stamp[2] = end
    running = t.running
    # the goal scheduler
    if t.has_goals:
        check = t.g_check
        bits = mk.goal_screen(
            time, mode, running, t.g_issued, t.g_t_goal, t.g_reached, period, periodic,
            success_time, t.g_age, t.g_due, check,
        )  # fmt: skip
        if bits & mk.ANY_DUE:
            code |= GOAL_DUE
        if bits & mk.ANY_CHECK:
            g_ee = t.g_ee
            sites(views, g_ee)
            if mk.goal_hits(g_ee, t.goal, check, t.g_best, success_radius, t.g_distance, t.g_hit):
                code |= GOAL_HIT
    # the motion figures (deploy-run's MotionHook), timed as the hook
    if motion:
        begin = monotonic_ns(stamp)
        mk.motion_statistics(
            t.temperature, t.peak, dq, t.prev_dq, t.prev_acc, t.dt, mode, running, count_jerk,
            t.jerk_sum, t.jerk_ticks, t.max_speed,
        )  # fmt: skip
        ns = monotonic_ns(stamp) - begin
        add_sample(t.h_counts, t.h_max, t.hook_stage, ns, width, top)
    return code


@numba.njit(cache=True, nogil=True, _nrt=False)
def motion_tick(
    temperature: np.ndarray,
    peak: np.ndarray,
    dq: np.ndarray,
    previous_dq: np.ndarray,
    previous_acc: np.ndarray,
    dt: float,
    mode: np.ndarray,
    running_mode: int,
    jerk_sum: np.ndarray,
    jerk_ticks: np.ndarray,
    max_speed: np.ndarray,
    count_jerk: bool,
) -> None:
    """:func:`sim2real.deploy.monitors.kernel.motion_statistics` (its arguments, units and
    shapes) with ``count_jerk`` last: the one argument of a call bound to the others."""
    mk.motion_statistics(
        temperature, peak, dq, previous_dq, previous_acc, dt, mode, running_mode, count_jerk,
        jerk_sum, jerk_ticks, max_speed,
    )  # fmt: skip
