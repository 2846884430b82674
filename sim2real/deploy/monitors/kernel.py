"""Kernels of the per-tick bookkeeping that watches a run: goals, violations, interventions and
motor heat (:class:`sim2real.deploy.tasks.goals.GoalScheduler`,
:class:`sim2real.deploy.monitors.violations.ViolationMonitor`,
:class:`sim2real.deploy.monitors.interventions.InterventionMonitor`,
:class:`sim2real.eval.soak.batch.SessionBatch`).

Each kernel replaces the handful of small numpy calls a monitor made every tick with one call
that answers "did anything happen?"; the monitor's exact bookkeeping (new goals, hit records,
per-type counts) still runs in Python on the ticks where something did. The arithmetic that
reaches a result (the goal distance) keeps numpy's operation order, so the results are the same
bit for bit (``tests/test_monitors.py``). A simulated fixed base's rig calls them all in one
compiled call (:mod:`sim2real.deploy.rig.after_tick_kernel`, ``tests/test_fused_after_tick.py``).
"""

from __future__ import annotations

import numba
import numpy as np

from sim2real.deploy.kernels import np_max, pairs_may_touch, row_sum

#: Bits of :func:`goal_screen`'s answer.
ANY_RUNNING, ANY_DUE, ANY_CHECK = 1, 2, 4


@numba.njit(cache=True, nogil=True, _nrt=False)
def goal_screen(
    t: float,
    mode: np.ndarray,
    running_mode: int,
    issued: np.ndarray,
    t_goal: np.ndarray,
    reached: np.ndarray,
    period: float,
    periodic: bool,
    success_time: float,
    age: np.ndarray,
    due: np.ndarray,
    check: np.ndarray,
) -> int:
    """One tick of a goal scheduler's timing, over the envs.

    Envs not in ``running_mode`` (``mode`` (envs,) int8) keep an unreached goal's clock at ``t``
    (``t_goal`` (envs,) s, updated): only running time counts. Writes ``age`` (s, ``t -
    t_goal``), ``due`` (running, and no goal issued yet or, ``periodic``, the goal's ``period``
    s are over) and ``check`` (running, not due, not ``reached``, ``age <= success_time``), all
    (envs,).

    Returns:
        Bits :data:`ANY_RUNNING`, :data:`ANY_DUE`, :data:`ANY_CHECK`; 0 when no env runs (then
        ``age``, ``due`` and ``check`` are not written).
    """
    envs = mode.shape[0]
    bits = 0
    for e in range(envs):
        if mode[e] == running_mode:
            bits |= ANY_RUNNING
        elif not reached[e]:
            t_goal[e] = t
    if bits == 0:
        return 0
    for e in range(envs):
        running = mode[e] == running_mode
        a = t - t_goal[e]
        age[e] = a
        d = running and (issued[e] == 0 or (periodic and a >= period))
        due[e] = d
        c = running and not d and not reached[e] and a <= success_time
        check[e] = c
        if d:
            bits |= ANY_DUE
        if c:
            bits |= ANY_CHECK
    return bits


@numba.njit(cache=True, nogil=True, _nrt=False)
def goal_hits(
    ee: np.ndarray,
    goal: np.ndarray,
    check: np.ndarray,
    best_distance: np.ndarray,
    success_radius: float,
    distance: np.ndarray,
    hit: np.ndarray,
) -> bool:
    """The envs ``check`` (envs,) whose end effector ``ee`` (envs, 3) m is within
    ``success_radius`` m of its ``goal`` (envs, 3) m: writes ``distance`` (m) and ``hit``
    (envs,), lowers ``best_distance`` (envs,) m of the checked envs; returns whether any hit."""
    envs = ee.shape[0]
    any_hit = False
    for e in range(envs):
        d0 = ee[e, 0] - goal[e, 0]
        d1 = ee[e, 1] - goal[e, 1]
        d2 = ee[e, 2] - goal[e, 2]
        s = d0 * d0
        s += d1 * d1
        s += d2 * d2
        dist = np.sqrt(s)
        distance[e] = dist
        h = False
        if check[e]:
            if dist < best_distance[e]:
                best_distance[e] = dist
            h = dist <= success_radius
        hit[e] = h
        any_hit = any_hit or h
    return any_hit


@numba.njit(cache=True, nogil=True, _nrt=False)
def violation_screen(
    q: np.ndarray,
    dq: np.ndarray,
    tau: np.ndarray,
    ee: np.ndarray,
    offset_q: np.ndarray,
    offset_ee: np.ndarray,
    bound: np.ndarray,
    with_ee: bool,
) -> bool:
    """Whether any env may be past a limit: ``|q - offset_q|``, ``|dq|``, ``|tau|`` (envs, n) and,
    ``with_ee``, ``|ee - offset_ee|`` (envs, 3) above ``bound`` ((3 n + 3,): the bounds of the
    four parts in that order)."""
    envs, n = q.shape
    for e in range(envs):
        for j in range(n):
            if abs(q[e, j] - offset_q[j]) > bound[j]:
                return True
            if abs(dq[e, j]) > bound[n + j]:
                return True
            if abs(tau[e, j]) > bound[2 * n + j]:
                return True
        if with_ee:
            for i in range(3):
                if abs(ee[e, i] - offset_ee[i]) > bound[3 * n + i]:
                    return True
    return False


@numba.njit(cache=True, nogil=True, _nrt=False)
def collision_screen(
    q: np.ndarray,
    checked_q: np.ndarray,
    pair_clearance: np.ndarray,
    pair_weights: np.ndarray,
    margin: float,
    tmp: np.ndarray,
    need: np.ndarray,
) -> bool:
    """The envs whose collision pairs may touch at ``q`` (envs, n) rad: ``need[e]`` (written,
    (envs,) bool) by the guard's screen (:func:`sim2real.deploy.kernels.pairs_may_touch`; ``tmp``
    (envs, n) its work array). Returns whether any env needs a check."""
    any_need = False
    for e in range(q.shape[0]):
        nd = pairs_may_touch(q, e, checked_q, pair_clearance, pair_weights, margin, tmp)
        need[e] = nd
        any_need = any_need or nd
    return any_need


@numba.njit(cache=True, nogil=True, _nrt=False)
def pairs_to_check(
    q: np.ndarray,
    checked_q: np.ndarray,
    pair_clearance: np.ndarray,
    pair_weights: np.ndarray,
    margin: float,
    tmp: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
    active: np.ndarray,
    e: int,
) -> int:
    """:func:`collision_screen`'s test pair by pair for env ``e``: ``active[first[p],
    second[p]]`` (written, (geoms, geoms) bool, Pinocchio's collision map) True for each pair
    ``p`` that may touch at ``q[e]`` (the test of :func:`sim2real.deploy.kernels.pairs_may_touch`,
    the same sums), False for a pair its bound keeps apart. Returns how many may touch."""
    n = q.shape[1]
    count = 0
    for p in range(pair_weights.shape[0]):
        for j in range(n):
            tmp[e, j] = abs(q[e, j] - checked_q[e, j]) * pair_weights[p, j]
        may = pair_clearance[e, p] <= row_sum(tmp, e) + margin
        active[first[p], second[p]] = may
        count += may
    return count


@numba.njit(cache=True, nogil=True)
def counters_moved(current: np.ndarray, previous: np.ndarray) -> bool:
    """Whether any counter of ``current`` differs from ``previous`` (same shape, int64)."""
    a, b = current.ravel(), previous.ravel()
    for i in range(a.shape[0]):
        if a[i] != b[i]:
            return True
    return False


@numba.njit(cache=True, nogil=True, _nrt=False)
def interventions_moved(
    guard: np.ndarray,
    previous_guard: np.ndarray,
    stopping: np.ndarray,
    clamps: np.ndarray,
    previous_smoother: np.ndarray,
) -> bool:
    """:func:`counters_moved` of an intervention monitor's three counters in one call: the
    guard's rows (checks, envs) against ``previous_guard``, the smoother's ``stopping`` and
    ``clamps`` (envs, n) against ``previous_smoother[0]`` and ``[1]`` ((2, envs, n)); int64."""
    return (
        counters_moved(guard, previous_guard)
        or counters_moved(stopping, previous_smoother[0])
        or counters_moved(clamps, previous_smoother[1])
    )


@numba.njit(cache=True, nogil=True, _nrt=False)
def temperature_bands(
    temperature: np.ndarray,
    derating_start: np.ndarray,
    maximum: np.ndarray,
    peak: np.ndarray,
    window_peak: np.ndarray,
    band_ticks: np.ndarray,
    over_ticks: np.ndarray,
) -> None:
    """One tick of motor-heat bookkeeping over ``temperature`` (envs, n) degC: raises ``peak``
    and ``window_peak`` (envs, n) degC to it, counts the ticks at or above the derating start
    (``band_ticks``) and above the maximum (``over_ticks``), (envs, n) int64 each; the limits
    (n,) degC."""
    envs, n = temperature.shape
    for e in range(envs):
        for j in range(n):
            x = temperature[e, j]
            if x > peak[e, j] or np.isnan(x):
                peak[e, j] = x
            if x > window_peak[e, j] or np.isnan(x):
                window_peak[e, j] = x
            if x >= derating_start[j]:
                band_ticks[e, j] += 1
            if x > maximum[j]:
                over_ticks[e, j] += 1


@numba.njit(cache=True, nogil=True, _nrt=False)
def motion_statistics(
    temperature: np.ndarray,
    peak: np.ndarray,
    dq: np.ndarray,
    previous_dq: np.ndarray,
    previous_acc: np.ndarray,
    dt: float,
    mode: np.ndarray,
    running_mode: int,
    count_jerk: bool,
    jerk_sum: np.ndarray,
    jerk_ticks: np.ndarray,
    max_speed: np.ndarray,
) -> None:
    """One tick of ``deploy-run``'s motion summary: ``peak`` (envs, n) degC rises to the winding
    ``temperature`` (``np.fmax``: a NaN reading leaves it); from the joint velocities ``dq``
    (envs, n) rad/s the acceleration ``(dq - previous_dq) / dt`` (rad/s^2), with ``count_jerk``
    the jerk ``|acc - previous_acc| / dt`` (rad/s^3) added to ``jerk_sum`` (envs, n) and 1 to
    ``jerk_ticks`` (envs,) int64 for the envs running (``mode`` (envs,) int8 equal to
    ``running_mode``); ``previous_dq`` and ``previous_acc`` become this tick's; ``max_speed``
    (n,) rad/s rises to ``max_e |dq|``. The arithmetic is the numpy expressions' of
    ``sim2real.deploy.cli.deploy_run`` (``* running`` as 1.0 or 0.0)."""
    envs, n = dq.shape
    for e in range(envs):
        for j in range(n):
            t = temperature[e, j]
            if t > peak[e, j] or peak[e, j] != peak[e, j]:  # np.fmax(peak, t)
                peak[e, j] = t
    for e in range(envs):
        running = mode[e] == running_mode
        r = 1.0 if running else 0.0
        for j in range(n):
            acc = (dq[e, j] - previous_dq[e, j]) / dt
            if count_jerk:
                jerk_sum[e, j] = jerk_sum[e, j] + abs(acc - previous_acc[e, j]) / dt * r
            previous_dq[e, j] = dq[e, j]
            previous_acc[e, j] = acc
        if count_jerk and running:
            jerk_ticks[e] += 1
    for j in range(n):
        m = abs(dq[0, j])
        for e in range(1, envs):
            m = np_max(m, abs(dq[e, j]))
        max_speed[j] = np_max(max_speed[j], m)


def warm_up() -> None:
    """Call every kernel once on small arrays of the production types (compiled, or loaded from
    numba's cache, here rather than in the first tick of a run)."""
    f, b, i8 = np.zeros(2), np.zeros(2, dtype=bool), np.zeros(2, dtype=np.int64)
    mode = np.zeros(2, dtype=np.int8)
    goal_screen(0.0, mode, 2, i8, f.copy(), b, 1.0, True, 1.0, f.copy(), b.copy(), b.copy())
    goal_hits(np.zeros((2, 3)), np.zeros((2, 3)), b, f.copy(), 0.1, f.copy(), b.copy())
    q = np.zeros((2, 3))
    violation_screen(q, q, q, q, np.zeros(3), np.zeros(3), np.ones(12), True)
    counters_moved(np.zeros((2, 3), dtype=np.int64), np.zeros((2, 3), dtype=np.int64))
    c = np.zeros((2, 3), dtype=np.int64)
    interventions_moved(c, c.copy(), c.copy(), c.copy(), np.zeros((2, 2, 3), dtype=np.int64))
    collision_screen(q, q, np.zeros((2, 1)), np.ones((1, 3)), 0.0, q.copy(), b.copy())
    pair = np.zeros(1, dtype=np.int64)
    pairs_to_check(
        q, q, np.zeros((2, 1)), np.ones((1, 3)), 0.0, q.copy(), pair, pair,
        np.zeros((1, 1), dtype=bool), 0,
    )  # fmt: skip
    temperature_bands(q, np.zeros(3), np.zeros(3), q.copy(), q.copy(), q.astype(np.int64),
                      q.astype(np.int64))  # fmt: skip
    motion_statistics(
        q, q.copy(), q, q.copy(), q.copy(), 0.01, mode, 2, True, q.copy(), i8.copy(), np.zeros(3)
    )
