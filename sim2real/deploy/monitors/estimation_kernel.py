"""The compiled arithmetic of :meth:`sim2real.deploy.monitors.estimation.EstimationMonitor.update`.

Two kernels around one ``np.arccos`` call (numpy's arccos is not the C library's, so it stays
numpy's): :func:`truth_angles` fills the true base from the plant's truth and writes the
arguments of the two arc cosines (the true tilt's, the attitude error's), :func:`accumulate`
counts the true falls and adds the errors. Each expression is numpy's in numpy's order: sums of
three terms left to right, as numpy reduces three elements; the true base-frame velocity
``R^T v`` as numpy's ``matmul`` computes it on the machine: through BLAS's ``gemv`` with fused
multiply-adds over the rows of ``R`` in order on some, as three products summed left to right on
others (an AMD EPYC's OpenBLAS), which :func:`gemv_variant` finds on the machine before the
kernels are used (neither: numpy's path).
:func:`true_base` is also the velocity tracker's
(:mod:`sim2real.deploy.tasks.locomotion_kernel`).
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba.core import types
from numba.extending import intrinsic

from sim2real.deploy.kernels.tables import Table

#: deg per rad as ``np.degrees`` multiplies.
DEG = 180.0 / math.pi


@intrinsic
def fma(typingctx, a, b, c):
    """``a * b + c`` rounded once (float64), in a compiled kernel."""

    def codegen(context, builder, signature, args):
        return builder.fma(*args)

    return types.float64(types.float64, types.float64, types.float64), codegen


@numba.njit(cache=True, nogil=True, inline="always")
def true_base(truth, e, orientation, gravity, angular, velocity_world, velocity, fused):
    """Env ``e``'s row of ``BaseState.set_truth(truth)`` (the same fields, the same numbers):
    ``R^T v`` with fused multiply-adds (``fused``) or as a plain sum (:func:`gemv_variant`)."""
    w, x, y, z = truth[e, 3], truth[e, 4], truth[e, 5], truth[e, 6]
    r00, r01, r02 = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    r10, r11, r12 = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    r20, r21, r22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    v0, v1, v2 = truth[e, 7], truth[e, 8], truth[e, 9]
    for j in range(4):
        orientation[e, j] = truth[e, 3 + j]
    gravity[e, 0], gravity[e, 1], gravity[e, 2] = -r20, -r21, -r22
    for j in range(3):
        angular[e, j] = truth[e, 10 + j]
        velocity_world[e, j] = truth[e, 7 + j]
    if fused:
        velocity[e, 0] = fma(r20, v2, fma(r10, v1, r00 * v0))
        velocity[e, 1] = fma(r21, v2, fma(r11, v1, r01 * v0))
        velocity[e, 2] = fma(r22, v2, fma(r12, v1, r02 * v0))
    else:
        velocity[e, 0] = (r00 * v0 + r10 * v1) + r20 * v2
        velocity[e, 1] = (r01 * v0 + r11 * v1) + r21 * v2
        velocity[e, 2] = (r02 * v0 + r12 * v1) + r22 * v2


@numba.njit(cache=True, nogil=True)
def _fill(truth, orientation, gravity, angular, velocity_world, velocity, fused):
    for e in range(truth.shape[0]):
        true_base(truth, e, orientation, gravity, angular, velocity_world, velocity, fused)


#: The ways :func:`true_base` can round ``R^T v``, in the order :func:`gemv_variant` tries them.
VARIANTS = ("fma", "plain")
_GEMV: list = []


def gemv_variant(samples: int | None = None) -> str | None:
    """The variant of :data:`VARIANTS` with which :func:`true_base` equals
    ``BaseState.set_truth`` bit for bit on this machine (``"fma"``: numpy's BLAS computes
    ``R^T v`` with fused multiply-adds in :func:`true_base`'s order; ``"plain"``: as products
    summed left to right), or None (neither: the kernels are not used), over seeded random base
    states in one batch and one env at a time: 256 checked once per process (None), or
    ``samples`` checked now."""
    if samples is not None:
        return _variant(samples)
    if not _GEMV:
        _GEMV.append(_variant(256))
    return _GEMV[0]


def gemv_matches(samples: int | None = None) -> bool:
    """Whether one variant of :func:`true_base` equals ``BaseState.set_truth`` bit for bit on
    this machine (:func:`gemv_variant`)."""
    return gemv_variant(samples) is not None


def gemv_fused() -> bool:
    """The ``fused`` argument of :func:`true_base` on this machine (:func:`gemv_variant`)."""
    return gemv_variant() == "fma"


def _variant(samples: int) -> str | None:
    for variant in VARIANTS:
        if _matches(samples, variant == "fma"):
            return variant
    return None


def _matches(samples: int, fused: bool) -> bool:
    from sim2real.deploy.core.state import BaseState

    rng = np.random.default_rng(0)
    truth = rng.normal(size=(samples, 13))
    truth[:, 3:7] /= np.linalg.norm(truth[:, 3:7], axis=1, keepdims=True)
    ref, mine = BaseState.zeros(samples).set_truth(truth), BaseState.zeros(samples)
    _fill(truth, *fields(mine), fused)
    if not all(np.array_equal(a, b) for a, b in zip(fields(ref), fields(mine), strict=True)):
        return False
    for k in range(min(samples, 16)):  # one env: numpy may take another path for one matrix
        one = truth[k : k + 1]
        ref, mine = BaseState.zeros(1).set_truth(one), BaseState.zeros(1)
        _fill(one, *fields(mine), fused)
        if not all(np.array_equal(a, b) for a, b in zip(fields(ref), fields(mine), strict=True)):
            return False
    return True


def fields(base) -> tuple:
    """A ``BaseState``'s arrays in :func:`true_base`'s order: orientation (envs, 4), projected
    gravity, angular velocity, world and base-frame linear velocity (envs, 3)."""
    return (
        base.orientation,
        base.projected_gravity,
        base.angular_velocity,
        base.linear_velocity_world,
        base.linear_velocity,
    )


@numba.njit(cache=True, nogil=True, inline="always")
def _clip(x):
    if x < -1.0:
        return -1.0
    if x > 1.0:
        return 1.0
    return x


@numba.njit(cache=True, nogil=True)
def truth_angles(
    orientation, gravity, angular, velocity_world, velocity, g_est, arg, fused, truth
):  # fmt: skip
    """Fill the true base (``orientation`` (envs, 4), ``gravity`` (envs, 3) projected,
    ``angular``, ``velocity_world``, ``velocity`` (envs, 3)) from ``truth`` (envs, 13), as
    ``BaseState.set_truth`` (``fused``: :func:`gemv_fused`); ``arg`` (2, envs): the clipped
    cosines of the true tilt and of the angle between ``g_est`` (envs, 3, the estimate's
    projected gravity) and the true one."""
    for e in range(truth.shape[0]):
        true_base(truth, e, orientation, gravity, angular, velocity_world, velocity, fused)
        g0, g1, g2 = gravity[e, 0], gravity[e, 1], gravity[e, 2]
        n = math.sqrt((g0 * g0 + g1 * g1) + g2 * g2)
        arg[0, e] = _clip(-(g2 / n))
        a0, a1, a2 = g_est[e, 0], g_est[e, 1], g_est[e, 2]
        m = math.sqrt((a0 * a0 + a1 * a1) + a2 * a2)
        arg[1, e] = _clip(((a0 / m) * g0 + (a1 / m) * g1) + (a2 / m) * g2)


@numba.njit(cache=True, nogil=True)
def accumulate(
    mode, lying, has_lying, angle, fall_height, fall_tilt, true_falls, down, counts, sums,
    v_est, v_true, vw_est, vw_true, bin_deg, bins, height,
):  # fmt: skip
    """The falls and errors of one tick: ``angle`` (2, envs) rad, the arc cosines of
    :func:`truth_angles`' ``arg``; ``height`` (envs, 13) the truth (its column 2). Returns 1:
    done; 0: no env RUNNING (errors untouched); -1: a RUNNING env's attitude error is not a
    number (errors untouched, the caller's numpy path raises as it would)."""
    envs = mode.shape[0]
    any_running = False
    for e in range(envs):
        running = mode[e] == 2
        low = height[e, 2] < fall_height
        if has_lying:
            low = low and not lying[e]
        d = low or (angle[0, e] > fall_tilt)
        if d and not down[e] and running:
            true_falls[e] += 1
        down[e] = d or (down[e] and not running)
        any_running = any_running or running
    if not any_running:
        return 0
    for e in range(envs):
        if mode[e] == 2 and math.isnan(angle[1, e] * DEG):
            return -1
    for e in range(envs):
        if mode[e] != 2:
            continue
        deg = angle[1, e] * DEG
        k = min(int(deg / bin_deg), bins)
        counts[e, k] += 1
        err0 = v_est[e, 0] - v_true[e, 0]
        err1 = v_est[e, 1] - v_true[e, 1]
        vertical = vw_est[e, 2] - vw_true[e, 2]
        sums[e, 0] += deg
        sums[e, 1] += v_est[e, 0]
        sums[e, 2] += v_true[e, 0]
        sums[e, 3] += err0**2 + err1**2
        sums[e, 4] += 1.0
        sums[e, 5] += vertical
        sums[e, 6] += vertical**2
    return 1


#: The monitor's table (:func:`monitor_stage`): ``fused`` (:func:`gemv_fused`), whether the
#: runtime has ``lying_expected``, the histogram's ``bins``; the true base's five fields
#: (:func:`fields`), the estimate's projected gravity, linear velocity and its world one, the
#: arc cosines' arguments and angles, the modes, ``lying_expected``, the true falls, the true
#: base down, the histogram's counts (``bins`` + 1 columns), the sums; the fall height (m),
#: fall tilt (rad), bin width (deg).
MONITOR = Table(
    "sim2real.deploy.monitors.estimation_kernel:MONITOR",
    fused="b1", has_lying="b1", bins="i8", fall_height="f8", fall_tilt="f8", bin_deg="f8",
    orientation="f8[envs,4]", gravity="f8[envs,3]", angular="f8[envs,3]",
    velocity_world="f8[envs,3]", velocity="f8[envs,3]", g_est="f8[envs,3]",
    v_est="f8[envs,3]", vw_est="f8[envs,3]", arg="f8[2,envs]", angle="f8[2,envs]",
    mode="i1[envs]", lying="b1[envs]", true_falls="i8[envs]", down="b1[envs]",
    counts="i8[envs,*]", sums="f8[envs,7]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def monitor_stage(t, stage, truth):
    """Stage 0: :func:`truth_angles`; stage 1: :func:`accumulate` (its answer), over the
    monitor's packed table ``t`` (:data:`MONITOR`) and ``truth`` (envs, 13)."""
    if stage == 0:
        truth_angles(
            t.orientation, t.gravity, t.angular, t.velocity_world, t.velocity, t.g_est, t.arg,
            t.fused, truth,
        )  # fmt: skip
        return 0
    return accumulate(
        t.mode, t.lying, t.has_lying, t.angle, t.fall_height, t.fall_tilt, t.true_falls, t.down,
        t.counts, t.sums, t.v_est, t.velocity, t.vw_est, t.velocity_world, t.bin_deg,
        t.bins, truth,
    )  # fmt: skip


def load() -> None:
    """Compile (or load from numba's cache) the kernels' specializations for the runtime's
    arrays' types (float64, an int8 mode, bool flags) and find :func:`gemv_variant`: done
    when a monitor is built, so that the first tick does not wait for it."""
    from sim2real.deploy.kernels.calls import bind

    gemv_variant()
    f, b = np.zeros((1, 3)), np.zeros(1, dtype=np.bool_)
    q, two = np.zeros((1, 4)), np.zeros((2, 1))
    bind(truth_angles, q, f, f, f, f, f, two, True, rest=(np.zeros((1, 13)),))
    mode, i = np.zeros(1, dtype=np.int8), np.zeros(1, dtype=np.int64)
    angle, counts, sums = np.zeros((2, 1)), np.zeros((1, 2), dtype=np.int64), np.zeros((1, 7))
    bind(
        accumulate,
        *(mode, b, True, angle, 1.0, 1.0, i, b, counts, sums, f, f, f, f, 1.0, 1),
        rest=(np.zeros((1, 13)),),
    )
    bind(monitor_stage, MONITOR.empty(), rest=(0, np.zeros((1, 13))))
