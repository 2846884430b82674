"""The estimate and observe stages of a fixed-base robot in one compiled call
(:func:`estimate_observe`): the joint estimator's Kalman tick, the end effector's kinematics,
the supervision and the observation; and the action screen over a table (:func:`screen`).

Numba's dispatch of each array argument costs more than the arithmetic of an arm's filters and
observation, and the four kernels took 60 arguments. So the call takes one packed table
(:data:`FUSED`, :mod:`sim2real.deploy.kernels.tables`), built by
:class:`sim2real.deploy.runtime.compiled.CompiledSupervision` again when handed other arrays
(compared by identity): every array the stages touch, read by its name.

The kernel calls the stages' own kernels in the tick's order:
:func:`sim2real.deploy.estimation.kernel.kalman_tick`,
:func:`sim2real.deploy.core.kinematics_kernel.chain_fk`,
:func:`sim2real.deploy.runtime.supervision_kernel.supervise` and
:func:`sim2real.deploy.spec.kernel.observation`, so the numbers are theirs bit for bit. A joint
filter that degenerates stops it (``RECOVER`` and the estimator's phase in the returned code):
Python re-initializes the joint and calls it again from the kinematics on (``start`` 1).
"""

from __future__ import annotations

import numba

from sim2real.deploy.core.kinematics_kernel import chain_fk
from sim2real.deploy.estimation.kernel import kalman_tick
from sim2real.deploy.kernels.tables import Table
from sim2real.deploy.runtime.supervision_kernel import screen_action, supervise
from sim2real.deploy.spec.kernel import CLOCK_COLUMNS, observation

#: :func:`~sim2real.deploy.runtime.supervision_kernel.supervise`'s arguments (their names;
#: shapes and units there), one table.
SUPERVISE = Table(
    "sim2real.deploy.runtime.fused_kernel:SUPERVISE",
    control="i8", realtime="b1", temperature="f8[envs,n]", derating="f8[3,n]",
    effort_scale="f8[envs,n]", time_since_fresh="f8[envs,n]", drive_any="b1[envs]",
    drive_errors="i8[envs,n]", overrun_ring="i8[*]", params="f8[7]", q="f8[envs,n]",
    dq="f8[envs,n]", home="f8[n]", commanded="f8[envs,n]", mode="i1[envs]", cause="i1[envs]",
    safe_stops="i8[envs]", faults="i8[*,envs]", stop_ticks="i8[envs]",
    stop_timeouts="i8[envs]", flags="b1[4,envs]", homed="b1[n]",
)  # fmt: skip
#: :func:`estimate_observe`'s: the supervision's, the estimator's (``kalman_tick``'s: the
#: frame's ``z``, ``ts``, ``now``, ``temperature_in``, its input ``u``, its ``filt`` (of which
#: ``time_since_fresh`` is row 7), ``consts``, ``counts``, ``est_flags``), the kinematics'
#: (``chain_fk``'s; ``joints`` 0: none) and the observation's (``observation``'s; no floating
#: base: ``vector``, ``orientation``, ``clock``, ``contact`` zeros of at least ``envs`` rows).
FUSED = SUPERVISE.extend(
    "sim2real.deploy.runtime.fused_kernel:FUSED",
    extrapolates="b1", joints="i8", z="f8[envs,n]", ts="f8[envs,n]", now="f8[envs]",
    temperature_in="f8[envs,n]", u="f8[envs,n]", filt="f8[8,envs,n]", consts="f8[5,n]",
    counts="i8[3,envs,n]", est_flags="b1[2,envs,n]", ee_position="f8[envs,3]",
    ee_rotation="f8[envs,3,3]", last_action="f8[envs,n]", chain="i8[links,3]",
    placements="f8[links,3,4]", work="f8[links,3,4]", layout="i8[blocks,*]",
    clocks=f"f8[blocks,{CLOCK_COLUMNS}]", clock_starts="f8[raw_rows,blocks]", goal="f8[envs,3]",
    vector="f8[envs+,3]", orientation="f8[envs+,4]", clock="f8[envs+]", contact="f8[envs+,0]",
    norm="f8[3,dim]", raw="f8[raw_rows,dim]", out="f4[envs,dim]",
)  # fmt: skip
#: The returned code: the supervision's ``SUPERVISE_*`` bits, or ``RECOVER`` and the estimator's
#: status (its phase to go on from) shifted by ``STATUS_SHIFT``.
RECOVER, STATUS_SHIFT = 16, 5


@numba.njit(cache=True, nogil=True, inline="always")
def _supervise(t) -> int:
    return supervise(
        t.control, t.temperature, t.derating, t.effort_scale, t.time_since_fresh, t.drive_any,
        t.drive_errors, t.overrun_ring, t.realtime, t.params, t.q, t.dq, t.home, t.commanded,
        t.mode, t.cause, t.safe_stops, t.faults, t.stop_ticks, t.stop_timeouts, t.flags,
        t.homed,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def estimate_observe(t, start: int) -> int:
    """The Kalman tick (from ``start`` 0; 1: after it), kinematics, supervision and observation
    of the packed table ``t`` (:data:`FUSED`). Returns the supervision's code, or
    ``RECOVER | status << STATUS_SHIFT`` when a joint filter must be re-initialized first."""
    q, dq, temperature = t.q, t.dq, t.temperature
    if start == 0:
        status = kalman_tick(
            0, t.z, t.ts, t.now, t.temperature_in, t.u, t.filt, t.consts, t.counts, t.est_flags,
            q, dq, temperature, t.extrapolates,
        )  # fmt: skip
        if status:
            return RECOVER | (status << STATUS_SHIFT)
    ee_position, ee_rotation = t.ee_position, t.ee_rotation
    if t.joints > 0:
        chain_fk(q, t.chain, t.placements, t.work, ee_position, ee_rotation)
    code = _supervise(t)
    vector = t.vector
    observation(
        t.layout, t.clocks, t.clock_starts, q, dq, ee_position, ee_rotation, t.goal,
        t.last_action, temperature, vector, vector, vector, vector, t.orientation, t.clock,
        t.contact, t.norm, t.raw, t.out,
    )  # fmt: skip
    return code


#: :func:`~sim2real.deploy.runtime.supervision_kernel.screen_action`'s arguments (their names;
#: shapes and units there), one table.
SCREEN = Table(
    "sim2real.deploy.runtime.fused_kernel:SCREEN",
    control="i8", nan_limit="i8", current="b1", ramp_gain="f8", action="f4[envs,n]",
    screened="f4[envs,n]", last_valid="f4[envs,n]", nan_streak="i8[envs]",
    non_finite="i8[envs]", mode="i1[envs]", cause="i1[envs]", safe_stops="i8[envs]",
    faults="i8[*,envs]", flags="b1[4,envs]", act="f8[3,n]", q="f8[envs,n]", dq="f8[envs,n]",
    home="f8[n]", limits="f8[3,n]", target="f8[envs,n]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def screen(t) -> int:
    """:func:`sim2real.deploy.runtime.supervision_kernel.screen_action` on the packed table
    ``t`` (:data:`SCREEN`); returns its code."""
    return screen_action(
        t.control, t.action, t.screened, t.last_valid, t.nan_streak, t.non_finite, t.nan_limit,
        t.mode, t.cause, t.safe_stops, t.faults, t.flags, t.act, t.current, t.q, t.dq, t.home,
        t.limits, t.ramp_gain, t.target,
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def supervise_only(t) -> int:
    """:func:`sim2real.deploy.runtime.supervision_kernel.supervise` alone on the packed table
    ``t`` (:data:`SUPERVISE`); returns its code."""
    return _supervise(t)
