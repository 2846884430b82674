"""Kernels of :class:`sim2real.deploy.runtime.Runtime`'s supervision, action screen and overrides.

:func:`supervise` (before the observation): the thermal derating of the effort limits
(:func:`sim2real.robots.thermal.derating_factor`), the safe stops for stale sensors, over-temperature,
drive errors and overruns (in that order, the first cause wins), the end of RAMP_IN and of safe
stops (at rest, or ``STOP_TIMEOUT`` ticks after they began: counted), and the screen of the
re-anchoring (:func:`sim2real.deploy.runtime.reanchor`). It returns the ``SUPERVISE_*`` bits of what
Python must do: start the smoother's safe stop of the ``new`` envs, reset the policy of the envs
that took over, re-sync and reset those that resume, re-anchor.

:func:`screen_action` (after the policy): non-finite actions held and counted (``NAN_LIMIT`` in a
row make a safe stop), the action mapped to a target
(:meth:`sim2real.deploy.spec.policy_spec.PolicySpec.action_to_target`) and the targets of the envs not
RUNNING overridden (position and velocity mode; torque mode needs Pinocchio's gravity: the
``SCREEN_OVERRIDE`` bit asks Python).

``flags`` (4, envs) bool: rows new safe stop, took over, resumed (this tick), and a scratch row
of :func:`screen_action` (the envs with a non-finite action). ``faults`` (causes,
envs) int64: the runtime's per-cause counters (``sim2real.deploy.runtime.FAULT_CAUSES`` order).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim2real.deploy.core.modes import PD_RAMP_REST_SPEED
from sim2real.deploy.kernels import np_max, np_min

#: Modes of the state machine (sim2real.deploy.runtime.Mode).
IDLE, RAMP_IN, RUNNING, SAFE_STOP, FAULTED = 0, 1, 2, 3, 4
#: Indices of sim2real.deploy.runtime.FAULT_CAUSES (FALL: set by the runtime's fall check, OPERATOR by
#: an operator's stop, SMOOTHER by a plan Ruckig could not compute; not here).
HARD_LIMIT, NON_FINITE_ACTION, STALE_SENSOR, OVERRUN, OVER_TEMPERATURE, SERVO_ERROR = range(6)
FALL, OPERATOR, SMOOTHER = 6, 7, 8
#: Rows of ``flags``.
NEW_STOP, TOOK_OVER, RESUMED, BAD_ACTION = 0, 1, 2, 3
#: Return bits of :func:`supervise`.
SUPERVISE_STOP, SUPERVISE_TOOK_OVER, SUPERVISE_RESUME, SUPERVISE_ANCHOR = 1, 2, 4, 8
#: Return bits of :func:`screen_action`.
SCREEN_STOP, SCREEN_OVERRIDE = 1, 2
#: Control modes (the re-anchoring and the overrides differ).
POSITION, VELOCITY, TORQUE = 0, 1, 2
#: Rows of ``params`` of :func:`supervise`.
STALE_LIMIT, OVERRUN_LIMIT, REST_SPEED, HOME_TOLERANCE, TRACKING_TOLERANCE, STOP_TIMEOUT = range(6)
#: Row of ``params``: 1 where RAMP_IN ends on the commanded position reaching home (a legged
#: robot in position mode, whose soft PD holds its weight short of home), 0 on the estimate.
HOME_FROM_COMMAND = 6


@numba.njit(cache=True, nogil=True, inline="always")
def _stop(e, why, mode, cause, safe_stops, faults, flags) -> bool:
    """``Supervision.safe_stop`` (sim2real.deploy.runtime.supervision) for env ``e``; whether it was new."""
    m = mode[e]
    if m == SAFE_STOP or m == FAULTED:
        return False
    mode[e] = SAFE_STOP
    cause[e] = why
    safe_stops[e] += 1
    faults[why, e] += 1
    flags[NEW_STOP, e] = True
    return True


@numba.njit(cache=True, nogil=True, _nrt=False)
def supervise(
    control: int,
    temperature: np.ndarray,
    derating: np.ndarray,
    effort_scale: np.ndarray,
    time_since_fresh: np.ndarray,
    drive_any: np.ndarray,
    drive_errors: np.ndarray,
    overrun_ring: np.ndarray,
    realtime: bool,
    params: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    home: np.ndarray,
    commanded: np.ndarray,
    mode: np.ndarray,
    cause: np.ndarray,
    safe_stops: np.ndarray,
    faults: np.ndarray,
    stop_ticks: np.ndarray,
    stop_timeouts: np.ndarray,
    flags: np.ndarray,
    homed: np.ndarray,
) -> int:
    """Derating, supervision and transitions of one tick (module docstring).

    Args:
        control: ``POSITION``, ``VELOCITY`` or ``TORQUE``.
        temperature: (envs, n) degC, estimated winding temperatures.
        derating: (3, n) rows start, maximum (degC), floor (fraction): the derating law.
        effort_scale: (envs, n) written: the derating factor.
        time_since_fresh: (envs, n) s since each joint's last fresh reading.
        drive_any: (envs,) bool, a drive of the env reported an error this tick.
        drive_errors: (envs, n) int64, the latched drive error bits.
        overrun_ring: (window,) int64, the last control periods, 1 where the loop missed one;
            read when ``realtime``: a stop when their mean passes ``OVERRUN_LIMIT``.
        params: ``STALE_LIMIT`` s, ``OVERRUN_LIMIT`` fraction, ``REST_SPEED`` rad/s
            (``Supervision.rest_speed``: the robot's, at least ``REST_SPEED``),
            ``HOME_TOLERANCE`` rad, ``TRACKING_TOLERANCE`` rad (of the control mode),
            ``STOP_TIMEOUT`` ticks (``sim2real.deploy.runtime.SAFE_STOP_TIMEOUT``),
            ``HOME_FROM_COMMAND`` (1: RAMP_IN's home is judged on ``commanded``, 0: on ``q``).
        q, dq: (envs, n) rad, rad/s, the estimate; home (n,) rad.
        commanded: (envs, n) rad, the smoother's commanded position (Ruckig's position in
            velocity mode); unused in torque mode (and for RAMP_IN's end unless
            ``HOME_FROM_COMMAND``).
        mode, cause: (envs,) int8, the state machine (written).
        safe_stops: (envs,) int64; faults (causes, envs) int64: counters (written).
        stop_ticks: (envs,) int64, ticks since each safe stop began, 0 outside SAFE_STOP
            (written); stop_timeouts: (envs,) int64, safe stops not at rest at the timeout
            (written).
        flags: (4, envs) bool, written (rows ``NEW_STOP``, ``TOOK_OVER``, ``RESUMED``).
        homed: (n,) bool, the joints whose pose RAMP_IN's end judges against ``home`` (False:
            a velocity-driven wheel, whose angle is any).
    """
    envs, n = q.shape
    for e in range(envs):
        flags[NEW_STOP, e] = False
        flags[TOOK_OVER, e] = False
        flags[RESUMED, e] = False
        for j in range(n):
            v = derating[1, j] - temperature[e, j]
            v = v / (derating[1, j] - derating[0, j])
            v = np_min(np_max(v, 0.0), 1.0)
            v = v * (1.0 - derating[2, j])
            effort_scale[e, j] = v + derating[2, j]
    code = 0
    for e in range(envs):
        stale = False
        hot = False
        for j in range(n):
            if time_since_fresh[e, j] > params[STALE_LIMIT]:
                stale = True
            if temperature[e, j] > derating[1, j]:
                hot = True
        if stale and _stop(e, STALE_SENSOR, mode, cause, safe_stops, faults, flags):
            code |= SUPERVISE_STOP
        if hot and _stop(e, OVER_TEMPERATURE, mode, cause, safe_stops, faults, flags):
            code |= SUPERVISE_STOP
        if drive_any[e] and _stop(e, SERVO_ERROR, mode, cause, safe_stops, faults, flags):
            code |= SUPERVISE_STOP
    if realtime:
        late = 0
        for k in range(overrun_ring.shape[0]):
            late += overrun_ring[k]
        if late / overrun_ring.shape[0] > params[OVERRUN_LIMIT]:
            for e in range(envs):
                if _stop(e, OVERRUN, mode, cause, safe_stops, faults, flags):
                    code |= SUPERVISE_STOP
    from_command = params[HOME_FROM_COMMAND] != 0.0
    for e in range(envs):
        m = mode[e]
        if m != RAMP_IN and m != SAFE_STOP:
            continue
        at_rest = True
        at_home = True
        rest = PD_RAMP_REST_SPEED if from_command and m == RAMP_IN else params[REST_SPEED]
        for j in range(n):
            if not abs(dq[e, j]) < rest:
                at_rest = False
            pose = commanded[e, j] if from_command else q[e, j]
            if homed[j] and not abs(pose - home[j]) < params[HOME_TOLERANCE]:
                at_home = False
        if m == RAMP_IN:
            if at_rest and at_home:
                mode[e] = RUNNING
                flags[TOOK_OVER, e] = True
                code |= SUPERVISE_TOOK_OVER
        else:
            stop_ticks[e] += 1
            # at rest, or STOP_TIMEOUT ticks after the stop began (counted once, when reached)
            timed_out = stop_ticks[e] >= params[STOP_TIMEOUT]
            if not (at_rest or timed_out):
                continue
            if timed_out and not at_rest and stop_ticks[e] == params[STOP_TIMEOUT]:
                stop_timeouts[e] += 1
            thermal = cause[e] == OVER_TEMPERATURE
            cool = True
            latched = False
            for j in range(n):
                if not temperature[e, j] < derating[0, j]:
                    cool = False
                if drive_errors[e, j] != 0:
                    latched = True
            if thermal and cool and not latched:
                mode[e] = RAMP_IN
                cause[e] = -1
                stop_ticks[e] = 0
                flags[RESUMED, e] = True
                code |= SUPERVISE_RESUME
            elif not thermal or latched:
                mode[e] = FAULTED
                stop_ticks[e] = 0
    if control != TORQUE:
        for e in range(envs):
            for j in range(n):
                if not abs(commanded[e, j] - q[e, j]) <= params[TRACKING_TOLERANCE]:
                    code |= SUPERVISE_ANCHOR
    return code


@numba.njit(cache=True, nogil=True, _nrt=False)
def screen_action(
    control: int,
    action: np.ndarray,
    screened: np.ndarray,
    last_valid: np.ndarray,
    nan_streak: np.ndarray,
    non_finite: np.ndarray,
    nan_limit: int,
    mode: np.ndarray,
    cause: np.ndarray,
    safe_stops: np.ndarray,
    faults: np.ndarray,
    flags: np.ndarray,
    act: np.ndarray,
    current: bool,
    q: np.ndarray,
    dq: np.ndarray,
    home: np.ndarray,
    limits: np.ndarray,
    ramp_gain: float,
    target: np.ndarray,
) -> int:
    """Screen the policy's ``action``, map it to ``target`` and override the envs not RUNNING.

    Args:
        control: ``POSITION``, ``VELOCITY`` or ``TORQUE``.
        action: (envs, n) float32, the policy's output.
        screened, last_valid: (envs, n) float32, the action used / the last finite one (written).
        nan_streak, non_finite: (envs,) int64 counters (written); ``nan_limit`` the streak that
            makes a safe stop.
        mode, cause, safe_stops, faults, flags: as :func:`supervise` (written).
        act: (3, n) float64 rows clip, scale, offset of the action spec; ``current``: position
            actions relative to ``q``.
        q, dq: (envs, n) rad, rad/s; home (n,) rad.
        limits: (3, n) rows acceleration limit (rad/s^2), soft lower, soft upper (rad).
        ramp_gain: 1/s, the RAMP_IN approach gain of velocity mode.
        target: (envs, n) float64, written: the target in the units of the mode.
    """
    envs, n = action.shape
    code = 0
    finite = True
    for e in range(envs):
        flags[NEW_STOP, e] = False
        for j in range(n):
            if not math.isfinite(action[e, j]):
                finite = False
    if finite:  # the common case
        for e in range(envs):
            nan_streak[e] = 0
            for j in range(n):
                screened[e, j] = action[e, j]
                last_valid[e, j] = action[e, j]
    else:
        for e in range(envs):
            bad = False
            for j in range(n):
                if not math.isfinite(action[e, j]):
                    bad = True
            if bad:
                non_finite[e] += 1
                nan_streak[e] += 1
            for j in range(n):
                screened[e, j] = last_valid[e, j] if bad else action[e, j]
            flags[BAD_ACTION, e] = bad
        for e in range(envs):  # every env's streak as it stands (the reference's order)
            if nan_streak[e] >= nan_limit:
                if _stop(e, NON_FINITE_ACTION, mode, cause, safe_stops, faults, flags):
                    code |= SCREEN_STOP
        for e in range(envs):
            if not flags[BAD_ACTION, e]:
                nan_streak[e] = 0
                for j in range(n):
                    last_valid[e, j] = action[e, j]
    running = True
    for e in range(envs):
        for j in range(n):
            lo = np.float32(-act[0, j])
            a = screened[e, j]
            a = a if (a >= lo or a != a) else lo  # np.maximum in float32, as the reference
            v = np_min(np.float64(a), act[0, j])
            v = v * act[1, j]
            target[e, j] = v + (q[e, j] if current else act[2, j])
        if mode[e] != RUNNING:
            running = False
    if running:
        return code
    if control == TORQUE:
        return code | SCREEN_OVERRIDE
    for e in range(envs):
        m = mode[e]
        if m == RUNNING:
            continue
        for j in range(n):
            if m == RAMP_IN:
                if control == POSITION:
                    target[e, j] = home[j]
                else:
                    target[e, j] = ramp_gain * (home[j] - q[e, j])
            elif control == POSITION:
                stop = dq[e, j] * abs(dq[e, j])
                stop = stop / (2.0 * limits[0, j])
                stop = q[e, j] + stop
                target[e, j] = np_min(np_max(stop, limits[1, j]), limits[2, j])
            else:
                target[e, j] = 0.0
    return code


@numba.njit(cache=True, nogil=True, _nrt=False)
def action_ran(last, action, mode, idle, running: int) -> None:
    """The action the drives ran into ``last`` (envs, n) float64: ``action`` (envs, n) float32
    for each env whose ``mode`` (envs,) int8 is ``running``, 0 for the others, which ``idle``
    (envs,) bool marks (``Runtime.tick``'s copy, comparison and zeroing, the same numbers)."""
    for e in range(last.shape[0]):
        stop = mode[e] != running
        idle[e] = stop
        for j in range(last.shape[1]):
            last[e, j] = 0.0 if stop else action[e, j]
