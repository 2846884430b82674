"""The MuJoCo plant's compiled step: its own models around ``mj_step`` in two calls per tick.

Numba's dispatch of each array argument costs more than the arithmetic of an arm's drives,
thermal nodes and encoders. So the kernels take one packed table (:data:`PLANT`, built by
:class:`sim2real.deploy.backends.sim.compiled_step.CompiledStep`): every array the step touches,
read by name, and each env's ``MjData`` fields by address (``views``; the plant never rebinds
its arrays; ``set_model`` rewrites an env's row).

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
from sim2real.deploy.kernels.calls import bind, pointer
from sim2real.deploy.kernels.tables import Table
from sim2real.robots.thermal_kernel import thermal_step

#: The step's arrays and constants: the flags (``live``: a plant's own table, not a copy's;
#: ``velocity_mode``: anti-windup; the drives report a velocity; the command goes straight into
#: ``ctrl``; the motors have torque-speed lines), ``rows`` actuators per joint (the rows of
#: ``ctrl``), ``warnings`` MuJoCo's warning counters, ``nstep`` physics steps per control period,
#: the encoder ``quantum`` (rad) and the control ``period`` (s); the plant's own arrays (the
#: drives', the thermal model's, the joint sensors' latency ``slots``, the actuators' ``depth``
#: of command history), ``streams`` (envs, 3) each env's sensor stream, and ``views`` (envs,
#: ``PER_ENV``) each env's ``MjData`` and model addresses (MuJoCo's memory; columns ``CTRL`` ...).
PLANT = Table(
    "sim2real.deploy.backends.sim.plant_kernel:PLANT",
    live="b1", velocity_mode="b1", has_velocity="b1", write_ctrl="b1", envelope="b1",
    rows="i8", warnings="i8", nstep="i8", quantum="f8", period="f8",
    command="f8[envs,n]", qpos="f8[envs,n]", qvel="f8[envs,n]", torque="f8[envs,n]",
    start="f8[n]", derated="b1[envs]", hot="b1[envs]", lag="f8[envs,n]", bound="f8[envs,n]",
    constants="f8[8,n]", ambient="f8[envs,n]", winding="f8[envs,n]", housing="f8[envs,n]",
    current="f8[envs,n]", power="f8[envs,n]", flow="f8[envs,n]",
    buf_position="f8[slots,envs,n]", buf_velocity="f8[slots,envs,n]",
    buf_stamp="f8[slots,envs]", uniform="f8[envs,n]", noise="f8[envs]", dropout="f8[envs]",
    velocity_noise="f8[envs]", bias="f8[envs,n]", biased="f8[envs,n]",
    history="f8[envs,depth,n]", delay="i8[n]", stall="f8[envs,n]", no_load="f8[envs,n]",
    active="b1[n]", limit="f8[envs,n]", streams="i8[envs,3]", t_ref="f8[n]", alpha="f8[n]",
    stall_coefficient="f8[n]", no_load_speed="f8[n]", supply="f8[envs]", views="i8[envs,7]",
)  # fmt: skip
# the columns of ``views``: MjData's ctrl, the joints' qpos, qvel, qfrc_actuator, the divergence
# warnings' counters, act (velocity mode), and the model's jnt_actfrcrange rows of the joints
CTRL, JQPOS, JQVEL, FORCE, WARN, ACT, ACTFRC = range(7)
PER_ENV = 7
#: STREAMS (envs, 3) int64, each env's sensor stream: the address of its bit generator's state
#: and of its ``next_uint64`` and ``next_double`` (numpy's ``BitGenerator.ctypes``)
STATE, NEXT_UINT64, NEXT_DOUBLE = range(3)
#: ``after_physics``'s ``sample``: no encoder sample; a sample of the draws made before
#: (:meth:`JointSensorModel.draw`); a sample that draws from STREAMS itself
NO_SAMPLE, DRAWN, DRAW = 0, 1, 2
#: ``before_physics``'s answer, bits: some env's torque limits must be set; the table is a
#: copy's (not ``live``): nothing was done, build the plant's own
DERATE, STALE = 1, 2


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
def _draw(t, slot):
    """The draws of :meth:`JointSensorModel.draw` from the streams, in its order: standard
    normal into the position slot, uniform (``next_double``, numpy's ``Generator.random``) into
    ``uniform``, standard normal into the velocity slot where the drives report one; row ``e``
    from env ``e``'s stream."""
    streams, position = t.streams, t.buf_position[slot]
    envs, n = position.shape
    for e in range(envs):
        for j in range(n):
            position[e, j] = _standard_normal(streams[e])
    uniform = t.uniform
    for e in range(envs):
        for j in range(n):
            uniform[e, j] = _next_double(streams[e, NEXT_DOUBLE], streams[e, STATE])
    if t.has_velocity:
        velocity = t.buf_velocity[slot]
        for e in range(envs):
            for j in range(n):
                velocity[e, j] = _standard_normal(streams[e])


@numba.njit(inline="always", cache=True, nogil=True)
def _env(t, e, column, shape):
    """Env ``e``'s ``MjData`` (or model) float64 array of column ``column`` of ``views``."""
    return numba.carray(pointer(t.views[e, column]), shape, np.float64)


@numba.njit(cache=True, nogil=True)
def before_physics(t, tick: int) -> int:
    """Before control tick ``tick``'s physics steps: each env's ``command`` (envs, n) into every
    row of its ``ctrl`` (``rows`` rows of n) with ``write_ctrl``; else the actuators' start of
    the period (:meth:`ActuatorModel.start_period`: the command into row ``tick % depth`` of
    ``history``, and with ``envelope`` each motor's ``stall`` torque at its winding temperature
    and ``no_load`` speed, scaled by the ``supply``); then the derating screen
    (:func:`sim2real.deploy.backends.sim.drives_kernel.derating_due`: ``hot`` (envs,) bool
    written); returns ``DERATE`` where some env's torque limits must be set, ``STALE`` (having
    done nothing) for a copy's table, else 0."""
    if not t.live:
        return STALE
    command, winding = t.command, t.winding
    envs, n = command.shape
    if t.write_ctrl:
        rows = t.rows
        for e in range(envs):
            ctrl = _env(t, e, CTRL, (rows, n))
            for r in range(rows):
                for j in range(n):
                    ctrl[r, j] = command[e, j]
    else:
        _start_period(t, tick, command, winding)
    return DERATE if derating_due(winding, t.start, t.derated, t.hot) else 0


@numba.njit(inline="always", cache=True, nogil=True)
def _start_period(t, tick, command, winding):
    history = t.history
    envs, depth, n = history.shape
    for e in range(envs):
        for j in range(n):
            history[e, tick % depth, j] = command[e, j]
    if not t.envelope:  # delays only: no line to follow
        return
    stall, no_load = t.stall, t.no_load
    t_ref, alpha = t.t_ref, t.alpha
    coefficient, speed = t.stall_coefficient, t.no_load_speed
    supply = t.supply
    for e in range(envs):
        for j in range(n):
            s = winding[e, j] - t_ref[j]
            s *= alpha[j]
            s += 1.0
            s = coefficient[j] / s
            stall[e, j] = s * supply[e]
            no_load[e, j] = speed[j] * supply[e]


@numba.njit(cache=True, nogil=True)
def actuator_substep(t, e: int, tick: int, sub: int) -> None:
    """Env ``e``'s motors before physics step ``sub`` of control tick ``tick``:
    :func:`sim2real.deploy.backends.sim.drives_kernel.actuator_step` on the table's arrays (the
    command ``history`` (envs, depth, n), ``delay`` (n,) int64 steps, ``stall`` and ``no_load``
    (envs, n), ``active`` (n,) bool, the ``limit`` (envs, n) N m) into the env's ``ctrl`` and
    ``jnt_actfrcrange`` rows."""
    n = t.delay.shape[0]
    actuator_step(
        t.history[e], tick, sub, t.nstep, t.delay, _env(t, e, CTRL, (t.rows, n)),
        _env(t, e, JQVEL, (n,)), t.limit[e], t.stall[e], t.no_load[e], t.active,
        _env(t, e, ACTFRC, (n, 2)),
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def after_physics(t, tick: int, sample: int) -> bool:
    """After a control period's physics steps, the plant's clock now at control tick ``tick``
    (``sample``: ``NO_SAMPLE``, or an encoder tick whose draws are made, ``DRAWN``, or to make,
    ``DRAW``).

    Gathers each env's joint ``qpos``, ``qvel`` (rad, rad/s) and actuator ``torque`` (N m),
    (envs, n) each, from its ``MjData``; returns False at once, before anything else changes,
    when a divergence warning counter of some env is set or some joint angle is not finite (the
    caller raises). Else, in this order: the velocity loop's anti-windup (``velocity_mode``:
    each env's setpoints ``act`` within ``bound`` of its joints where any of them lags further,
    as :meth:`SimDrives.anti_windup`), the thermal step over the control period
    (:func:`sim2real.robots.thermal_kernel.thermal_step`), and, at an encoder tick, the sample
    into slot ``tick % slots`` of the latency buffers, whose position (and velocity) rows hold
    the standard normal draws and ``uniform`` the uniform ones (as
    :meth:`JointSensorModel.sample`: bias, :func:`encoder_sample`, the stamp ``tick * period``,
    the velocity's noise; NaN where the angle dropped out; at other ticks the slot is NaN).
    Returns True.
    """
    qpos, qvel, torque = t.qpos, t.qvel, t.torque
    envs, n = qpos.shape
    slots = t.buf_stamp.shape[0]
    warnings = t.warnings
    ok = True
    for e in range(envs):
        q, dq, force = _env(t, e, JQPOS, (n,)), _env(t, e, JQVEL, (n,)), _env(t, e, FORCE, (n,))
        counters = numba.carray(pointer(t.views[e, WARN]), (2 * warnings,), np.int32)
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
    if t.velocity_mode:
        _anti_windup(t, qpos)
    thermal_step(
        torque, t.period, t.constants, t.ambient, t.winding, t.housing, t.current, t.power,
        t.flow,
    )  # fmt: skip
    if sample != NO_SAMPLE:
        if sample == DRAW:
            _draw(t, tick % slots)
        _encoder_tick(t, tick % slots, tick, qpos, qvel)
    else:  # no sample: the slot reads as no reading
        slot = tick % slots
        t.buf_position[slot] = np.nan
        t.buf_velocity[slot] = np.nan
        t.buf_stamp[slot] = np.nan
    return True


@numba.njit(inline="always", cache=True, nogil=True)
def _anti_windup(t, qpos):
    lag, bound = t.lag, t.bound
    envs, n = qpos.shape
    wound = False
    for e in range(envs):
        act = _env(t, e, ACT, (n,))
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
        act = _env(t, e, ACT, (n,))
        for j in range(n):  # np.clip: min(max(a, lo), hi), NaN kept
            lo, hi = qpos[e, j] - bound[e, j], qpos[e, j] + bound[e, j]
            a = act[j]
            a = a if (np.isnan(a) or a > lo) else lo
            a = a if (np.isnan(a) or a < hi) else hi
            act[j] = a


@numba.njit(inline="always", cache=True, nogil=True)
def _encoder_tick(t, slot, tick, qpos, qvel):
    sample, bias = t.buf_position[slot], t.bias
    envs, n = qpos.shape
    q = qpos
    biased = False
    for e in range(envs):
        for j in range(n):
            if bias[e, j] != 0.0:
                biased = True
    if biased:  # a calibration error: the encoder reads q + bias
        q = t.biased
        for e in range(envs):
            for j in range(n):
                q[e, j] = qpos[e, j] + bias[e, j]
    encoder_sample(sample, t.uniform, q, t.noise, t.quantum, t.dropout)
    stamp = t.buf_stamp
    time = tick * t.period
    for e in range(envs):
        stamp[slot, e] = time
    if t.has_velocity:
        velocity = t.buf_velocity[slot]
        sigma = t.velocity_noise
        for e in range(envs):
            for j in range(n):
                v = velocity[e, j] * sigma[e]
                v += qvel[e, j]
                velocity[e, j] = np.nan if np.isnan(sample[e, j]) else v


def compile_kernels() -> None:
    """Compile the kernels for a table (or load them from numba's cache), so that a plant's
    first tick does not pay for it."""
    empty = PLANT.empty()
    bind(before_physics, empty, rest=(0,))
    bind(after_physics, empty, rest=(0, 0))
    bind(actuator_substep, empty, rest=(0, 0, 0))
