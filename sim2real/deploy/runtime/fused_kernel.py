"""The estimate and observe stages of a fixed-base robot in one compiled call
(:func:`estimate_observe`): the joint estimator's Kalman tick, the end effector's kinematics,
the supervision and the observation; and the action screen over a table (:func:`screen`).

Numba's dispatch of each array argument costs more than the arithmetic of an arm's filters and
observation, and the four kernels took 60 arguments. So the call takes one int64 *table*, built
and kept by :class:`sim2real.deploy.runtime.compiled.CompiledSupervision`: a header of sizes and
flags, then the address of every array the stages touch, which the kernel views with
``numba.carray`` (:mod:`sim2real.deploy.kernels.calls`). The arrays must live, keep their shape
and dtype and stay C-contiguous while the table is in use (its owner keeps a reference to each,
checks them when it builds the table and builds it again when handed other arrays).

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
import numpy as np

from sim2real.deploy.core.kinematics_kernel import chain_fk
from sim2real.deploy.estimation.kernel import kalman_tick
from sim2real.deploy.kernels.calls import pointer as _pointer
from sim2real.deploy.runtime.supervision_kernel import screen_action, supervise
from sim2real.deploy.spec.kernel import CLOCK_COLUMNS, observation

# the header: sizes and flags
ENVS, N, JOINTS, BLOCKS, WIDTH, DIM, RAW_ROWS, WINDOW, CAUSES, FEET = range(10)
CONTROL, REALTIME, EXTRAPOLATES = range(10, 13)
# the addresses: the frame's, the estimator's, the state's
Z, TS, NOW, TEMP_IN, U, FILT, CONSTS, COUNTS, EST_FLAGS = range(13, 22)
Q, DQ, TEMP, EE_POSITION, EE_ROTATION, LAST_ACTION = range(22, 28)
# the kinematics' (chain_fk)
CHAIN, PLACEMENTS, WORK = range(28, 31)
# the supervision's (supervise)
DERATING, EFFORT_SCALE, DRIVE_ANY, DRIVE_ERRORS, OVERRUN_RING, PARAMS, HOME, COMMANDED = range(
    31, 39
)
MODE, CAUSE, SAFE_STOPS, FAULTS, STOP_TICKS, STOP_TIMEOUTS, FLAGS = range(39, 46)
# the observation's (no floating base: VECTOR, ORIENTATION, CLOCK, CONTACT are zeros)
LAYOUT, CLOCKS, GOAL, VECTOR, ORIENTATION, CLOCK, CONTACT, NORM, RAW, OUT = range(46, 56)
# the supervision's again (supervise's last argument); the observation's gait clock states
HOMED, STARTS = 56, 57
#: Length of the table.
SIZE = 58
#: The returned code: the supervision's ``SUPERVISE_*`` bits, or ``RECOVER`` and the estimator's
#: status (its phase to go on from) shifted by ``STATUS_SHIFT``.
RECOVER, STATUS_SHIFT = 16, 5
#: The kernel's signature (compiled, or loaded from numba's cache, by the table's owner).
SIGNATURE = "int64(int64[::1], int64)"


@numba.njit(cache=True, nogil=True)
def estimate_observe(table: np.ndarray, start: int) -> int:
    """The Kalman tick (from ``start`` 0; 1: after it), kinematics, supervision and observation
    of the arrays of ``table`` (module docstring). Returns the supervision's code, or
    ``RECOVER | status << STATUS_SHIFT`` when a joint filter must be re-initialized first."""
    envs, n = table[ENVS], table[N]
    joints, dim = table[JOINTS], table[DIM]
    f8, i8, b1 = np.float64, np.int64, np.bool_
    q = numba.carray(_pointer(table[Q]), (envs, n), f8)
    dq = numba.carray(_pointer(table[DQ]), (envs, n), f8)
    temp = numba.carray(_pointer(table[TEMP]), (envs, n), f8)
    filt = numba.carray(_pointer(table[FILT]), (8, envs, n), f8)
    if start == 0:
        status = kalman_tick(
            0,
            numba.carray(_pointer(table[Z]), (envs, n), f8),
            numba.carray(_pointer(table[TS]), (envs, n), f8),
            numba.carray(_pointer(table[NOW]), (envs,), f8),
            numba.carray(_pointer(table[TEMP_IN]), (envs, n), f8),
            numba.carray(_pointer(table[U]), (envs, n), f8),
            filt,
            numba.carray(_pointer(table[CONSTS]), (5, n), f8),
            numba.carray(_pointer(table[COUNTS]), (3, envs, n), i8),
            numba.carray(_pointer(table[EST_FLAGS]), (2, envs, n), b1),
            q,
            dq,
            temp,
            table[EXTRAPOLATES] != 0,
        )
        if status:
            return RECOVER | (status << STATUS_SHIFT)
    ee_position = numba.carray(_pointer(table[EE_POSITION]), (envs, 3), f8)
    ee_rotation = numba.carray(_pointer(table[EE_ROTATION]), (envs, 3, 3), f8)
    if joints > 0:
        chain_fk(
            q,
            numba.carray(_pointer(table[CHAIN]), (joints + 1, 3), i8),
            numba.carray(_pointer(table[PLACEMENTS]), (joints + 1, 3, 4), f8),
            numba.carray(_pointer(table[WORK]), (joints + 1, 3, 4), f8),
            ee_position,
            ee_rotation,
        )
    code = supervise(
        table[CONTROL],
        temp,
        numba.carray(_pointer(table[DERATING]), (3, n), f8),
        numba.carray(_pointer(table[EFFORT_SCALE]), (envs, n), f8),
        filt[7],
        numba.carray(_pointer(table[DRIVE_ANY]), (envs,), b1),
        numba.carray(_pointer(table[DRIVE_ERRORS]), (envs, n), i8),
        numba.carray(_pointer(table[OVERRUN_RING]), (table[WINDOW],), i8),
        table[REALTIME] != 0,
        numba.carray(_pointer(table[PARAMS]), (7,), f8),
        q,
        dq,
        numba.carray(_pointer(table[HOME]), (n,), f8),
        numba.carray(_pointer(table[COMMANDED]), (envs, n), f8),
        numba.carray(_pointer(table[MODE]), (envs,), np.int8),
        numba.carray(_pointer(table[CAUSE]), (envs,), np.int8),
        numba.carray(_pointer(table[SAFE_STOPS]), (envs,), i8),
        numba.carray(_pointer(table[FAULTS]), (table[CAUSES], envs), i8),
        numba.carray(_pointer(table[STOP_TICKS]), (envs,), i8),
        numba.carray(_pointer(table[STOP_TIMEOUTS]), (envs,), i8),
        numba.carray(_pointer(table[FLAGS]), (4, envs), b1),
        numba.carray(_pointer(table[HOMED]), (n,), b1),
    )
    vector = numba.carray(_pointer(table[VECTOR]), (envs, 3), f8)
    observation(
        numba.carray(_pointer(table[LAYOUT]), (table[BLOCKS], table[WIDTH]), i8),
        numba.carray(_pointer(table[CLOCKS]), (table[BLOCKS], CLOCK_COLUMNS), f8),
        numba.carray(_pointer(table[STARTS]), (table[RAW_ROWS], table[BLOCKS]), f8),
        q,
        dq,
        ee_position,
        ee_rotation,
        numba.carray(_pointer(table[GOAL]), (envs, 3), f8),
        numba.carray(_pointer(table[LAST_ACTION]), (envs, n), f8),
        temp,
        vector,
        vector,
        vector,
        vector,
        numba.carray(_pointer(table[ORIENTATION]), (envs, 4), f8),
        numba.carray(_pointer(table[CLOCK]), (envs,), f8),
        numba.carray(_pointer(table[CONTACT]), (envs, table[FEET]), f8),
        numba.carray(_pointer(table[NORM]), (3, dim), f8),
        numba.carray(_pointer(table[RAW]), (table[RAW_ROWS], dim), f8),
        numba.carray(_pointer(table[OUT]), (envs, dim), np.float32),
    )
    return code


# the action screen's table (:func:`screen`): its header, then its addresses
S_ENVS, S_N, S_CONTROL, S_NAN_LIMIT, S_CURRENT, S_CAUSES = range(6)
S_ACTION, S_SCREENED, S_LAST_VALID, S_NAN_STREAK, S_NON_FINITE = range(6, 11)
S_MODE, S_CAUSE, S_SAFE_STOPS, S_FAULTS, S_FLAGS = range(11, 16)
S_ACT, S_Q, S_DQ, S_HOME, S_LIMITS, S_RAMP_GAIN, S_TARGET = range(16, 23)
#: Length of the screen's table.
SCREEN_SIZE = 23
#: :func:`screen`'s signature.
SCREEN_SIGNATURE = "int64(int64[::1])"


@numba.njit(cache=True, nogil=True)
def screen(table: np.ndarray) -> int:
    """:func:`sim2real.deploy.runtime.supervision_kernel.screen_action` on the arrays of
    ``table`` (the ``S_*`` rows); returns its code."""
    envs, n = table[S_ENVS], table[S_N]
    f8, i8, b1 = np.float64, np.int64, np.bool_
    return screen_action(
        table[S_CONTROL],
        numba.carray(_pointer(table[S_ACTION]), (envs, n), np.float32),
        numba.carray(_pointer(table[S_SCREENED]), (envs, n), np.float32),
        numba.carray(_pointer(table[S_LAST_VALID]), (envs, n), np.float32),
        numba.carray(_pointer(table[S_NAN_STREAK]), (envs,), i8),
        numba.carray(_pointer(table[S_NON_FINITE]), (envs,), i8),
        table[S_NAN_LIMIT],
        numba.carray(_pointer(table[S_MODE]), (envs,), np.int8),
        numba.carray(_pointer(table[S_CAUSE]), (envs,), np.int8),
        numba.carray(_pointer(table[S_SAFE_STOPS]), (envs,), i8),
        numba.carray(_pointer(table[S_FAULTS]), (table[S_CAUSES], envs), i8),
        numba.carray(_pointer(table[S_FLAGS]), (4, envs), b1),
        numba.carray(_pointer(table[S_ACT]), (3, n), f8),
        table[S_CURRENT] != 0,
        numba.carray(_pointer(table[S_Q]), (envs, n), f8),
        numba.carray(_pointer(table[S_DQ]), (envs, n), f8),
        numba.carray(_pointer(table[S_HOME]), (n,), f8),
        numba.carray(_pointer(table[S_LIMITS]), (3, n), f8),
        numba.carray(_pointer(table[S_RAMP_GAIN]), (1,), f8)[0],
        numba.carray(_pointer(table[S_TARGET]), (envs, n), f8),
    )


#: :func:`supervise_only`'s signature: the table of :func:`estimate_observe` (its supervision's
#: rows, ``Q``, ``DQ``, ``TEMP`` and ``FILT`` for ``time_since_fresh``).
SUPERVISE_SIGNATURE = "int64(int64[::1])"


@numba.njit(cache=True, nogil=True)
def supervise_only(table: np.ndarray) -> int:
    """:func:`sim2real.deploy.runtime.supervision_kernel.supervise` alone on the arrays of an
    :func:`estimate_observe` table (the rows it reads; the others may be 0); returns its code."""
    envs, n = table[ENVS], table[N]
    f8, i8, b1 = np.float64, np.int64, np.bool_
    return supervise(
        table[CONTROL],
        numba.carray(_pointer(table[TEMP]), (envs, n), f8),
        numba.carray(_pointer(table[DERATING]), (3, n), f8),
        numba.carray(_pointer(table[EFFORT_SCALE]), (envs, n), f8),
        numba.carray(_pointer(table[FILT]), (8, envs, n), f8)[7],
        numba.carray(_pointer(table[DRIVE_ANY]), (envs,), b1),
        numba.carray(_pointer(table[DRIVE_ERRORS]), (envs, n), i8),
        numba.carray(_pointer(table[OVERRUN_RING]), (table[WINDOW],), i8),
        table[REALTIME] != 0,
        numba.carray(_pointer(table[PARAMS]), (7,), f8),
        numba.carray(_pointer(table[Q]), (envs, n), f8),
        numba.carray(_pointer(table[DQ]), (envs, n), f8),
        numba.carray(_pointer(table[HOME]), (n,), f8),
        numba.carray(_pointer(table[COMMANDED]), (envs, n), f8),
        numba.carray(_pointer(table[MODE]), (envs,), np.int8),
        numba.carray(_pointer(table[CAUSE]), (envs,), np.int8),
        numba.carray(_pointer(table[SAFE_STOPS]), (envs,), i8),
        numba.carray(_pointer(table[FAULTS]), (table[CAUSES], envs), i8),
        numba.carray(_pointer(table[STOP_TICKS]), (envs,), i8),
        numba.carray(_pointer(table[STOP_TIMEOUTS]), (envs,), i8),
        numba.carray(_pointer(table[FLAGS]), (4, envs), b1),
        numba.carray(_pointer(table[HOMED]), (n,), b1),
    )
