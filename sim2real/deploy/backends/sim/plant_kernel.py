"""The MuJoCo plant's compiled step: its own models around ``mj_step`` in two calls per tick.

Numba's dispatch of each array argument costs more than the arithmetic of an arm's drives,
thermal nodes and encoders. So the kernels take one int64 *table* (built and kept by
:class:`sim2real.deploy.backends.sim.compiled_step.CompiledStep`): a header of sizes and flags,
then the addresses of every array the step touches (the plant's own arrays and each env's
``MjData`` fields), which they view with ``numba.carray``. The arrays must live, keep their shape
and stay C-contiguous while the table is in use (the plant never rebinds them; ``set_model``
rewrites an env's row).

- :func:`before_physics`: the drive commands into each env's ``ctrl`` and the derating screen.
- :func:`after_physics`: the joint state gathered from ``MjData``, the divergence screen, the
  velocity loop's anti-windup, the thermal step and the encoder sample of the tick.
- :func:`actuator_substep`: one env's motors before one physics step (delay, torque-speed line).

Each runs the arithmetic of the kernels it replaces, in their order (the numpy references of
:mod:`sim2real.deploy.backends.sim.reference`, :meth:`TwoNodeThermalModel.step_reference`), so a
seeded plant gives the same states bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic
from numba.np.random._constants import (
    fi_double,
    ki_double,
    wi_double,
    ziggurat_nor_inv_r,
    ziggurat_nor_r,
)

from sim2real.deploy.backends.sim.drives_kernel import actuator_step, derating_due
from sim2real.deploy.backends.sim.sensors_kernel import encoder_sample
from sim2real.deploy.kernels.calls import pointer as _pointer
from sim2real.robots.thermal_kernel import thermal_step

# the header: sizes and flags (ROWS: actuators per joint, the rows of ctrl; NSTEP: physics steps
# per control period)
ENVS, N, ROWS, SLOTS, FLAGS, WARNINGS, DEPTH, NSTEP = range(8)
#: FLAGS bits: velocity mode (anti-windup), the drives report a velocity, the command goes
#: straight into ctrl (no actuator model between), the motors have torque-speed lines
VELOCITY_MODE, HAS_VELOCITY, WRITE_CTRL, ENVELOPE = 1, 2, 4, 8
# the plant's arrays (addresses)
(
    COMMAND, QPOS, QVEL, TORQUE, START, DERATED, HOT, LAG, BOUND, CONSTANTS, AMBIENT, WINDING,
    HOUSING, CURRENT, POWER, FLOW, BUF_POSITION, BUF_VELOCITY, BUF_STAMP, UNIFORM, NOISE, DROPOUT,
    VELOCITY_NOISE, BIAS, BIASED, SCALARS, HISTORY, DELAY, STALL, NO_LOAD, ACTIVE, LIMIT, STREAMS,
    T_REF, ALPHA, STALL_COEFFICIENT, NO_LOAD_SPEED, SUPPLY, SELF,
) = range(8, 47)  # fmt: skip
#: SCALARS (float64, 2): the encoder quantum (rad), the control period (s)
QUANTUM, PERIOD = 0, 1
#: first per-env row; each env has ``PER_ENV`` addresses
ENV_ROWS = 47
# per env: MjData's ctrl, the joints' qpos, qvel, qfrc_actuator, the divergence warnings' counters,
# act (velocity mode), and the model's jnt_actfrcrange rows of the joints
CTRL, JQPOS, JQVEL, FORCE, WARN, ACT, ACTFRC = range(7)
PER_ENV = 7
#: STREAMS (envs, 3) int64, each env's sensor stream: the address of its bit generator's state
#: and of its ``next_uint64`` and ``next_double`` (numpy's ``BitGenerator.ctypes``)
STATE, NEXT_UINT64, NEXT_DOUBLE = range(3)
#: ``after_physics``'s ``sample``: no encoder sample; a sample of the draws made before
#: (:meth:`JointSensorModel.draw`); a sample that draws from STREAMS itself
NO_SAMPLE, DRAWN, DRAW = 0, 1, 2
#: ``before_physics``'s answer, bits: some env's torque limits must be set; the table is a
#: copy's (``SELF`` is not its address): nothing was done, build the plant's own
DERATE, STALE = 1, 2
#: The kernels' signatures (:func:`compile_kernels`).
SIGNATURES = {
    "before_physics": "int64(int64[::1], int64)",
    "after_physics": "boolean(int64[::1], int64, int64)",
    "actuator_substep": "void(int64[::1], int64, int64, int64)",
}


@intrinsic
def _next_uint64(typingctx, function, state):
    """``function(state)``: a bit generator's ``uint64_t next_uint64(void *)`` at the address
    ``function``, on the state at the address ``state``."""

    def codegen(context, builder, signature, args):
        voidp = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.IntType(64), [voidp])
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(fn, [builder.inttoptr(args[1], voidp)])

    return types.uint64(function, state), codegen


@intrinsic
def _next_double(typingctx, function, state):
    """``function(state)``: a bit generator's ``double next_double(void *)`` at the address
    ``function``, on the state at the address ``state``."""

    def codegen(context, builder, signature, args):
        voidp = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.DoubleType(), [voidp])
        fn = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(fn, [builder.inttoptr(args[1], voidp)])

    return types.float64(function, state), codegen


@numba.njit(inline="always", cache=True, nogil=True)
def _standard_normal(stream):
    """One draw of numpy's ``Generator.standard_normal`` (float64) from ``stream`` (3,): the
    ziggurat of numpy's ``random_standard_normal`` (numpy/random/src/distributions/
    distributions.c) as numba's ``numba.np.random.distributions`` ports it, its tables."""
    state, u64, dbl = stream[STATE], stream[NEXT_UINT64], stream[NEXT_DOUBLE]
    while True:
        r = _next_uint64(u64, state)
        idx = r & 0xFF
        r >>= 8
        sign = r & 0x1
        rabs = (r >> 1) & 0x000FFFFFFFFFFFFF
        x = rabs * wi_double[idx]
        if sign & 0x1:
            x = -x
        if rabs < ki_double[idx]:
            return x
        if idx == 0:
            while True:
                xx = -ziggurat_nor_inv_r * np.log1p(-_next_double(dbl, state))
                yy = -np.log1p(-_next_double(dbl, state))
                if yy + yy > xx * xx:
                    if (rabs >> 8) & 0x1:
                        return -(ziggurat_nor_r + xx)
                    return ziggurat_nor_r + xx
        elif (fi_double[idx - 1] - fi_double[idx]) * _next_double(dbl, state) + fi_double[
            idx
        ] < np.exp(-0.5 * x * x):
            return x


@numba.njit(inline="always", cache=True, nogil=True)
def _draw(table, envs, n, slots, slot, flags):
    """The draws of :meth:`JointSensorModel.draw` from the STREAMS, in its order: standard
    normal into the position slot, uniform (``next_double``, numpy's ``Generator.random``) into
    UNIFORM, standard normal into the velocity slot where the drives report one; row ``e`` from
    env ``e``'s stream."""
    streams = numba.carray(_pointer(table[STREAMS]), (envs, 3), np.int64)
    position = _f64(table, BUF_POSITION, (slots, envs, n))[slot]
    for e in range(envs):
        for j in range(n):
            position[e, j] = _standard_normal(streams[e])
    uniform = _f64(table, UNIFORM, (envs, n))
    for e in range(envs):
        for j in range(n):
            uniform[e, j] = _next_double(streams[e, NEXT_DOUBLE], streams[e, STATE])
    if flags & HAS_VELOCITY:
        velocity = _f64(table, BUF_VELOCITY, (slots, envs, n))[slot]
        for e in range(envs):
            for j in range(n):
                velocity[e, j] = _standard_normal(streams[e])


@numba.njit(inline="always", cache=True, nogil=True)
def _f64(table, i, shape):
    return numba.carray(_pointer(table[i]), shape, np.float64)


@numba.njit(inline="always", cache=True, nogil=True)
def _bool(table, i, shape):
    return numba.carray(_pointer(table[i]), shape, np.bool_)


@numba.njit(inline="always", cache=True, nogil=True)
def _env(table, e, field):
    return table[ENV_ROWS + e * PER_ENV + field]


@numba.njit(cache=True, nogil=True)
def before_physics(table: np.ndarray, tick: int) -> int:
    """Before control tick ``tick``'s physics steps: each env's command ``COMMAND`` (envs, n)
    into every row of its ``ctrl`` (``ROWS`` rows of n) with ``WRITE_CTRL``; else the actuators'
    start of the period (:meth:`ActuatorModel.start_period`: the command into row
    ``tick % DEPTH`` of ``HISTORY``, and with ``ENVELOPE`` each motor's ``STALL`` torque at its
    winding temperature and ``NO_LOAD`` speed, scaled by the ``SUPPLY``); then the derating screen
    (:func:`sim2real.deploy.backends.sim.drives_kernel.derating_due`: ``HOT`` (envs,) bool
    written); returns ``DERATE`` where some env's torque limits must be set, ``STALE`` (having
    done nothing) for a copied table, else 0."""
    if table[SELF] != table.ctypes.data:
        return STALE
    envs, n, rows, flags = table[ENVS], table[N], table[ROWS], table[FLAGS]
    command = _f64(table, COMMAND, (envs, n))
    winding = _f64(table, WINDING, (envs, n))
    if flags & WRITE_CTRL:
        for e in range(envs):
            ctrl = numba.carray(_pointer(_env(table, e, CTRL)), (rows, n), np.float64)
            for r in range(rows):
                for j in range(n):
                    ctrl[r, j] = command[e, j]
    else:
        _start_period(table, tick, envs, n, flags, command, winding)
    start = _f64(table, START, (n,))
    derated, hot = _bool(table, DERATED, (envs,)), _bool(table, HOT, (envs,))
    return DERATE if derating_due(winding, start, derated, hot) else 0


@numba.njit(inline="always", cache=True, nogil=True)
def _start_period(table, tick, envs, n, flags, command, winding):
    depth = table[DEPTH]
    history = _f64(table, HISTORY, (envs, depth, n))
    for e in range(envs):
        for j in range(n):
            history[e, tick % depth, j] = command[e, j]
    if not flags & ENVELOPE:  # delays only: no line to follow
        return
    stall, no_load = _f64(table, STALL, (envs, n)), _f64(table, NO_LOAD, (envs, n))
    t_ref, alpha = _f64(table, T_REF, (n,)), _f64(table, ALPHA, (n,))
    coefficient, speed = _f64(table, STALL_COEFFICIENT, (n,)), _f64(table, NO_LOAD_SPEED, (n,))
    supply = _f64(table, SUPPLY, (envs,))
    for e in range(envs):
        for j in range(n):
            s = winding[e, j] - t_ref[j]
            s *= alpha[j]
            s += 1.0
            s = coefficient[j] / s
            stall[e, j] = s * supply[e]
            no_load[e, j] = speed[j] * supply[e]


@numba.njit(cache=True, nogil=True)
def actuator_substep(table: np.ndarray, e: int, tick: int, sub: int) -> None:
    """Env ``e``'s motors before physics step ``sub`` of control tick ``tick``:
    :func:`sim2real.deploy.backends.sim.drives_kernel.actuator_step` on the table's arrays (the
    command ``HISTORY`` (envs, depth, n), ``DELAY`` (n,) int64 steps, ``STALL`` and ``NO_LOAD``
    (envs, n), ``ACTIVE`` (n,) bool, the limit ``LIMIT`` (envs, n) N m) into the env's ``ctrl``
    and ``jnt_actfrcrange`` rows."""
    envs, n, depth, rows = table[ENVS], table[N], table[DEPTH], table[ROWS]
    actuator_step(
        _f64(table, HISTORY, (envs, depth, n))[e], tick, sub, table[NSTEP],
        numba.carray(_pointer(table[DELAY]), (n,), np.int64),
        numba.carray(_pointer(_env(table, e, CTRL)), (rows, n), np.float64),
        numba.carray(_pointer(_env(table, e, JQVEL)), (n,), np.float64),
        _f64(table, LIMIT, (envs, n))[e], _f64(table, STALL, (envs, n))[e],
        _f64(table, NO_LOAD, (envs, n))[e], _bool(table, ACTIVE, (n,)),
        numba.carray(_pointer(_env(table, e, ACTFRC)), (n, 2), np.float64),
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def after_physics(table: np.ndarray, tick: int, sample: int) -> bool:
    """After a control period's physics steps, the plant's clock now at control tick ``tick``
    (``sample``: ``NO_SAMPLE``, or an encoder tick whose draws are made, ``DRAWN``, or to make,
    ``DRAW``).

    Gathers each env's joint ``QPOS``, ``QVEL`` (rad, rad/s) and actuator ``TORQUE`` (N m),
    (envs, n) each, from its ``MjData``; returns False at once, before anything else changes,
    when a divergence warning counter of some env is set or some joint angle is not finite (the
    caller raises). Else, in this order: the velocity loop's anti-windup (``VELOCITY_MODE``:
    each env's setpoints ``act`` within ``BOUND`` of its joints where any of them lags further,
    as :meth:`SimDrives.anti_windup`), the thermal step over the control period
    (:func:`sim2real.robots.thermal_kernel.thermal_step`), and, at an encoder tick, the sample
    into slot ``tick % SLOTS`` of the latency buffers, whose position (and velocity) rows hold
    the standard normal draws and ``UNIFORM`` the uniform ones (as
    :meth:`JointSensorModel.sample`: bias, :func:`encoder_sample`, the stamp ``tick * period``,
    the velocity's noise; NaN where the angle dropped out; at other ticks the slot is NaN).
    Returns True.
    """
    envs, n, slots, flags = table[ENVS], table[N], table[SLOTS], table[FLAGS]
    qpos, qvel = _f64(table, QPOS, (envs, n)), _f64(table, QVEL, (envs, n))
    torque = _f64(table, TORQUE, (envs, n))
    warnings = table[WARNINGS]
    ok = True
    for e in range(envs):
        q = numba.carray(_pointer(_env(table, e, JQPOS)), (n,), np.float64)
        dq = numba.carray(_pointer(_env(table, e, JQVEL)), (n,), np.float64)
        force = numba.carray(_pointer(_env(table, e, FORCE)), (n,), np.float64)
        counters = numba.carray(_pointer(_env(table, e, WARN)), (2 * warnings,), np.int32)
        for k in range(warnings):  # the counters of mjWarningStat {lastinfo, number}
            if counters[2 * k] != 0:
                ok = False
        for j in range(n):
            torque[e, j] = force[j]
            qpos[e, j] = q[j]
            qvel[e, j] = dq[j]
            if not np.isfinite(q[j]):
                ok = False
    if not ok:
        return False
    if flags & VELOCITY_MODE:
        _anti_windup(table, envs, n, qpos)
    scalars = _f64(table, SCALARS, (2,))
    thermal_step(
        torque, scalars[PERIOD], _f64(table, CONSTANTS, (8, n)), _f64(table, AMBIENT, (envs, n)),
        _f64(table, WINDING, (envs, n)), _f64(table, HOUSING, (envs, n)),
        _f64(table, CURRENT, (envs, n)), _f64(table, POWER, (envs, n)),
        _f64(table, FLOW, (envs, n)),
    )  # fmt: skip
    if sample != NO_SAMPLE:
        if sample == DRAW:
            _draw(table, envs, n, slots, tick % slots, flags)
        _encoder_tick(table, tick, envs, n, slots, flags, qpos, qvel, scalars)
    else:  # no sample: the slot reads as no reading
        slot = tick % slots
        _f64(table, BUF_POSITION, (slots, envs, n))[slot] = np.nan
        _f64(table, BUF_VELOCITY, (slots, envs, n))[slot] = np.nan
        _f64(table, BUF_STAMP, (slots, envs))[slot] = np.nan
    return True


@numba.njit(inline="always", cache=True, nogil=True)
def _anti_windup(table, envs, n, qpos):
    lag, bound = _f64(table, LAG, (envs, n)), _f64(table, BOUND, (envs, n))
    wound = False
    for e in range(envs):
        act = numba.carray(_pointer(_env(table, e, ACT)), (n,), np.float64)
        for j in range(n):
            lag[e, j] = act[j] - qpos[e, j]
            if abs(lag[e, j]) > bound[e, j]:
                wound = True
    if not wound:
        return
    for e in range(envs):
        clip = False
        for j in range(n):
            if abs(lag[e, j]) > bound[e, j]:
                clip = True
        if not clip:
            continue
        act = numba.carray(_pointer(_env(table, e, ACT)), (n,), np.float64)
        for j in range(n):  # np.clip: min(max(a, lo), hi), NaN kept
            lo, hi = qpos[e, j] - bound[e, j], qpos[e, j] + bound[e, j]
            a = act[j]
            a = a if (np.isnan(a) or a > lo) else lo
            a = a if (np.isnan(a) or a < hi) else hi
            act[j] = a


@numba.njit(inline="always", cache=True, nogil=True)
def _encoder_tick(table, tick, envs, n, slots, flags, qpos, qvel, scalars):
    slot = tick % slots
    sample = _f64(table, BUF_POSITION, (slots, envs, n))[slot]
    bias = _f64(table, BIAS, (envs, n))
    q = qpos
    biased = False
    for e in range(envs):
        for j in range(n):
            if bias[e, j] != 0.0:
                biased = True
    if biased:  # a calibration error: the encoder reads q + bias
        q = _f64(table, BIASED, (envs, n))
        for e in range(envs):
            for j in range(n):
                q[e, j] = qpos[e, j] + bias[e, j]
    encoder_sample(
        sample, _f64(table, UNIFORM, (envs, n)), q, _f64(table, NOISE, (envs,)),
        scalars[QUANTUM], _f64(table, DROPOUT, (envs,)),
    )  # fmt: skip
    stamp = _f64(table, BUF_STAMP, (slots, envs))
    time = tick * scalars[PERIOD]
    for e in range(envs):
        stamp[slot, e] = time
    if flags & HAS_VELOCITY:
        velocity = _f64(table, BUF_VELOCITY, (slots, envs, n))[slot]
        sigma = _f64(table, VELOCITY_NOISE, (envs,))
        for e in range(envs):
            for j in range(n):
                v = velocity[e, j] * sigma[e]
                v += qvel[e, j]
                velocity[e, j] = np.nan if np.isnan(sample[e, j]) else v


def compile_kernels() -> None:
    """Compile the kernels for their :data:`SIGNATURES` (or load them from numba's cache), so
    that a plant's first tick does not pay for it."""
    for name, signature in SIGNATURES.items():
        globals()[name].compile(signature)
