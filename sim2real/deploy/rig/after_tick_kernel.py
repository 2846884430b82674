"""The rig's after-tick work in one compiled call (:func:`after_tick`): the violation and
collision screens over the true state, the intervention counters' comparison, the goal
scheduler's timing and hit test, and ``deploy-run``'s motion figures, over a table of addresses
(:mod:`sim2real.deploy.kernels.calls`) built by :class:`sim2real.deploy.rig.after_tick.FusedAfterTick`.

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
legged robot's estimation monitor, always), the monitors' end stamp is left in the table for
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
from sim2real.deploy.monitors import kernel as mk

# the header: sizes, flags and the histograms' bins
ENVS, N, PAIRS, GUARD_ROWS, FLAGS, BIN_NS, BINS, HOOK_STAGE = range(8)
# the plant's gathered state and the parameters (margin m, dt s)
Q, DQ, TAU, PARAMS, STAMP = range(8, 13)  # STAMP (3,) int64: the clock's scratch, the end
# the violation monitor's
V_EE, V_OFFSET_Q, V_OFFSET_EE, V_BOUND, V_CHECKED_Q, V_CLEARANCE = range(13, 19)
V_WEIGHTS, V_TMP, V_NEED, V_DOWN, V_TICKS = range(19, 24)
# the intervention monitor's
I_GUARD, I_PREV_GUARD, I_STOPPING, I_CLAMPS, I_PREV_SMOOTHER, I_TICKS = range(24, 30)
# the monitors' cost histogram
M_COUNTS, M_MAX = range(30, 32)
# the goal scheduler's (MODE: the runtime's modes; GOAL: the runtime's goals)
MODE, G_ISSUED, G_T_GOAL, G_REACHED, G_AGE, G_DUE, G_CHECK = range(32, 39)
G_EE, GOAL, G_BEST, G_DISTANCE, G_HIT = range(39, 44)
# the motion figures' and the hooks' cost histogram
TEMP, PEAK, PREV_DQ, PREV_ACC, JERK_SUM, JERK_TICKS, MAX_SPEED, H_COUNTS, H_MAX = range(44, 53)
#: Where the per-env addresses start: the joints' qpos views, then the qvel views, then the
#: end-effector sites (``envs`` each).
VIEWS = 53
#: Bits of the header's ``FLAGS``: a workspace box, collision pairs, a goal task, a legged robot
#: (``LEGGED``: an env in SAFE_STOP or FAULTED lies down, its ticks counted apart; the monitors'
#: cost sample is left to Python, which runs the estimation monitor), RUNNING's code shifted by
#: ``RUNNING_SHIFT``, SAFE_STOP's by ``SAFE_STOP_SHIFT``.
HAS_WORKSPACE, HAS_PAIRS, HAS_GOALS, LEGGED, RUNNING_SHIFT, SAFE_STOP_SHIFT = 1, 2, 4, 16, 8, 24
#: Bits of the returned code: the collision pairs of some env need coal (``V_NEED``), some env
#: may be past a limit, an intervention counter moved (the monitors' cost sample is then left to
#: Python: ``STAMP[2]`` holds the end of the screens), a goal is due (``G_DUE``), a goal was
#: reached (``G_HIT``).
COLLISION_CHECK, VIOLATION_FLAGGED, INTERVENTIONS_MOVED, GOAL_DUE, GOAL_HIT = 1, 2, 4, 8, 16
#: The bits after which Python finishes the monitors' work.
MONITOR_WORK = COLLISION_CHECK | VIOLATION_FLAGGED | INTERVENTIONS_MOVED


def size(envs: int) -> int:
    """Length of the table of ``envs`` envs."""
    return VIEWS + 3 * envs


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
def sites(table, envs: int, out) -> None:
    """The end-effector sites of the table's envs into ``out`` (envs, 3) m."""
    for e in range(envs):
        site = numba.carray(pointer(table[VIEWS + 2 * envs + e]), (3,), np.float64)
        for i in range(3):
            out[e, i] = site[i]


@numba.njit(cache=True, nogil=True)
def after_tick(
    table: np.ndarray,
    time: float,
    start_ns: int,
    period: float,
    periodic: bool,
    success_time: float,
    success_radius: float,
    count_jerk: bool,
    motion: bool,
) -> int:
    """One tick's monitors and goals and, with ``motion``, the motion figures, over the arrays of
    ``table`` (module docstring).

    Args:
        time: The runtime's time, s. start_ns: ``time.perf_counter_ns()`` when the monitors
            began. period, periodic, success_time, success_radius: the goal scheduler's (s, s,
            m). count_jerk: the runtime is past its second tick (the jerk is counted).

    Returns:
        The bits ``COLLISION_CHECK`` ... ``GOAL_HIT``; 0: nothing left for Python.
    """
    envs, n, pairs, rows, flags = (
        table[ENVS],
        table[N],
        table[PAIRS],
        table[GUARD_ROWS],
        table[FLAGS],
    )
    f8, i8, b1 = np.float64, np.int64, np.bool_
    stamp = numba.carray(pointer(table[STAMP]), (3,), i8)  # the clock's scratch, the end
    params = numba.carray(pointer(table[PARAMS]), (2,), f8)
    q = numba.carray(pointer(table[Q]), (envs, n), f8)
    dq = numba.carray(pointer(table[DQ]), (envs, n), f8)
    tau = numba.carray(pointer(table[TAU]), (envs, n), f8)
    v_ee = numba.carray(pointer(table[V_EE]), (envs, 3), f8)
    for e in range(envs):  # true_position(), true_velocity()
        qpos = numba.carray(pointer(table[VIEWS + e]), (n,), f8)
        qvel = numba.carray(pointer(table[VIEWS + envs + e]), (n,), f8)
        for j in range(n):
            q[e, j] = qpos[j]
            dq[e, j] = qvel[j]
    if flags & HAS_WORKSPACE:
        sites(table, envs, v_ee)  # end_effector_position(out)
    # the violation monitor (update with down: a legged robot's envs lying damped after a stop,
    # ``Runtime.damping``; else every env is up)
    mode = numba.carray(pointer(table[MODE]), (envs,), np.int8)
    down = numba.carray(pointer(table[V_DOWN]), (envs,), b1)
    legged = (flags & LEGGED) != 0
    safe_stop = (flags >> SAFE_STOP_SHIFT) & 0xFF
    for e in range(envs):
        down[e] = legged and mode[e] >= safe_stop
    numba.carray(pointer(table[V_TICKS]), (1,), i8)[0] += 1
    code = 0
    if flags & HAS_PAIRS:
        need = mk.collision_screen(
            q,
            numba.carray(pointer(table[V_CHECKED_Q]), (envs, n), f8),
            numba.carray(pointer(table[V_CLEARANCE]), (envs, pairs), f8),
            numba.carray(pointer(table[V_WEIGHTS]), (pairs, n), f8),
            params[0],
            numba.carray(pointer(table[V_TMP]), (envs, n), f8),
            numba.carray(pointer(table[V_NEED]), (envs,), b1),
        )
        if need:
            code |= COLLISION_CHECK
    if mk.violation_screen(
        q,
        dq,
        tau,
        v_ee,
        numba.carray(pointer(table[V_OFFSET_Q]), (n,), f8),
        numba.carray(pointer(table[V_OFFSET_EE]), (3,), f8),
        numba.carray(pointer(table[V_BOUND]), (3 * n + 3,), f8),
        (flags & HAS_WORKSPACE) != 0,
    ):
        code |= VIOLATION_FLAGGED
    # the intervention monitor
    numba.carray(pointer(table[I_TICKS]), (1,), i8)[0] += 1
    if mk.interventions_moved(
        numba.carray(pointer(table[I_GUARD]), (rows, envs), i8),
        numba.carray(pointer(table[I_PREV_GUARD]), (rows, envs), i8),
        numba.carray(pointer(table[I_STOPPING]), (envs, n), i8),
        numba.carray(pointer(table[I_CLAMPS]), (envs, n), i8),
        numba.carray(pointer(table[I_PREV_SMOOTHER]), (2, envs, n), i8),
    ):
        code |= INTERVENTIONS_MOVED
    width, top = table[BIN_NS], table[BINS]
    end = monotonic_ns(stamp)
    if code == 0 and not legged:
        counts = numba.carray(pointer(table[M_COUNTS]), (1, top + 1), i8)
        add_sample(
            counts, numba.carray(pointer(table[M_MAX]), (1,), i8), 0, end - start_ns, width, top
        )
    stamp[2] = end
    running = (flags >> RUNNING_SHIFT) & 0xFF
    # the goal scheduler
    if flags & HAS_GOALS:
        check = numba.carray(pointer(table[G_CHECK]), (envs,), b1)
        bits = mk.goal_screen(
            time,
            mode,
            running,
            numba.carray(pointer(table[G_ISSUED]), (envs,), i8),
            numba.carray(pointer(table[G_T_GOAL]), (envs,), f8),
            numba.carray(pointer(table[G_REACHED]), (envs,), b1),
            period,
            periodic,
            success_time,
            numba.carray(pointer(table[G_AGE]), (envs,), f8),
            numba.carray(pointer(table[G_DUE]), (envs,), b1),
            check,
        )
        if bits & mk.ANY_DUE:
            code |= GOAL_DUE
        if bits & mk.ANY_CHECK:
            g_ee = numba.carray(pointer(table[G_EE]), (envs, 3), f8)
            sites(table, envs, g_ee)
            if mk.goal_hits(
                g_ee,
                numba.carray(pointer(table[GOAL]), (envs, 3), f8),
                check,
                numba.carray(pointer(table[G_BEST]), (envs,), f8),
                success_radius,
                numba.carray(pointer(table[G_DISTANCE]), (envs,), f8),
                numba.carray(pointer(table[G_HIT]), (envs,), b1),
            ):
                code |= GOAL_HIT
    # the motion figures (deploy-run's MotionHook), timed as the hook
    if motion:
        begin = monotonic_ns(stamp)
        mk.motion_statistics(
            numba.carray(pointer(table[TEMP]), (envs, n), f8),
            numba.carray(pointer(table[PEAK]), (envs, n), f8),
            dq,
            numba.carray(pointer(table[PREV_DQ]), (envs, n), f8),
            numba.carray(pointer(table[PREV_ACC]), (envs, n), f8),
            params[1],
            mode,
            running,
            count_jerk,
            numba.carray(pointer(table[JERK_SUM]), (envs, n), f8),
            numba.carray(pointer(table[JERK_TICKS]), (envs,), i8),
            numba.carray(pointer(table[MAX_SPEED]), (n,), f8),
        )
        stage = table[HOOK_STAGE]
        ns = monotonic_ns(stamp) - begin
        add_sample(
            numba.carray(pointer(table[H_COUNTS]), (stage + 1, top + 1), i8),
            numba.carray(pointer(table[H_MAX]), (stage + 1,), i8),
            stage,
            ns,
            width,
            top,
        )
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
