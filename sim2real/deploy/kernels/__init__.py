"""The compiled tick: numba helpers shared by the kernels of the runtime's stages (``np_max``,
``np_min``, ``row_sum``, ``pairs_may_touch``), and their calls without numba's dispatch
(:mod:`sim2real.deploy.kernels.calls`).

Each stage runs its kernel per tick, over the stage's preallocated arrays, and keeps its numpy
implementation as the tested reference in ``reference.py`` beside it: a subclass
``Reference<Class>`` with the same constructor (``ReferenceGuard``, ``ReferenceSmoother``,
``ReferenceRuntime``, the monitors', the goal scheduler's, the joint estimator's, the plant's
sensor model's) or, for the observation, :func:`sim2real.deploy.spec.reference.observation_reference`.
The kernels live beside their stages: :mod:`sim2real.deploy.spec.kernel`,
:mod:`sim2real.deploy.runtime.supervision_kernel`, :mod:`sim2real.deploy.safety.kernel`,
:mod:`sim2real.deploy.safety.envelope_kernel`, :mod:`sim2real.deploy.smoothing.kernel`,
:mod:`sim2real.robots.thermal_kernel`, :mod:`sim2real.deploy.backends.sim.drives_kernel`,
:mod:`sim2real.deploy.backends.sim.sensors_kernel`, :mod:`sim2real.deploy.monitors.kernel`,
:mod:`sim2real.deploy.rig.after_tick_kernel` and :mod:`sim2real.deploy.core.latency_kernel`.

A kernel stops where Python must act (Ruckig, Pinocchio, a policy reset) and returns a code that
says what; the arithmetic and its order are those of the numpy reference, so both give the same
numbers bit for bit (``tests/test_compiled_tick.py``; row sums follow numpy's pairwise order).
Every kernel is compiled with ``cache=True`` and called once when its stage is built, so the first
tick runs compiled code. A kernel that allocates nothing is also compiled without numba's
reference counting (``_nrt=False``): with it, each array a kernel takes from a tuple (the guard's
``GuardArrays``) or keeps across a branch is counted up and down with atomic calls, which cost
more than the arithmetic of a small robot's check; such a kernel may not create an array (numba
refuses it at compile time). numba's cache of every kernel is keyed on its own file and the
package's modules it imports (:mod:`sim2real.numba_cache`): an edit to a helper here recompiles
the kernels that inline it.
"""

from __future__ import annotations

import math

import numba


@numba.njit(cache=True, nogil=True, inline="always")
def np_max(a: float, b: float) -> float:
    """``np.maximum`` of two floats (NaN propagates, the first operand wins a tie)."""
    return a if (a >= b or a != a) else b


@numba.njit(cache=True, nogil=True, inline="always")
def np_min(a: float, b: float) -> float:
    """``np.minimum`` of two floats (NaN propagates, the first operand wins a tie)."""
    return a if (a <= b or a != a) else b


@numba.njit(cache=True, nogil=True, _nrt=False)
def row_sum(a, e: int) -> float:
    """``a[e].sum()`` of a 2-d float64 array in numpy's order (sequential below 8 entries, then
    eight partial sums: numpy's pairwise summation for rows of at most 128)."""
    n = a.shape[1]
    if n < 8:
        s = 0.0
        for i in range(n):
            s += a[e, i]
        return s
    r0, r1, r2, r3 = a[e, 0], a[e, 1], a[e, 2], a[e, 3]
    r4, r5, r6, r7 = a[e, 4], a[e, 5], a[e, 6], a[e, 7]
    m = n - n % 8
    for i in range(8, m, 8):
        r0 += a[e, i]
        r1 += a[e, i + 1]
        r2 += a[e, i + 2]
        r3 += a[e, i + 3]
        r4 += a[e, i + 4]
        r5 += a[e, i + 5]
        r6 += a[e, i + 6]
        r7 += a[e, i + 7]
    s = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    for i in range(m, n):
        s += a[e, i]
    return s


@numba.njit(cache=True, nogil=True, inline="always")
def pairs_may_touch(q, e: int, checked_q, pair_clearance, pair_weights, margin: float, tmp) -> bool:
    """Whether a collision pair of env ``e`` may touch at ``q[e]`` (rad): unless every pair's
    distance computed at ``checked_q[e]`` (``pair_clearance[e]``, m) exceeds ``pair_weights[p] @
    |q[e] - checked_q[e]|`` plus ``margin`` (m), the weights (pairs, n) m/rad bounding how fast
    each pair approaches per radian of each joint
    (:func:`sim2real.robots.chain_bounds.collision_pair_weights`).
    ``tmp`` (envs, n): work row ``e``; the sum in numpy's order (:func:`row_sum`). The one
    collision screen of the guard and of the violation monitor."""
    n = q.shape[1]
    for p in range(pair_weights.shape[0]):
        for j in range(n):
            tmp[e, j] = abs(q[e, j] - checked_q[e, j]) * pair_weights[p, j]
        if pair_clearance[e, p] <= row_sum(tmp, e) + margin:
            return True
    return False


@numba.njit(cache=True, nogil=True, inline="always")
def finite(x: float) -> bool:
    return math.isfinite(x)


@numba.njit(cache=True, nogil=True, _nrt=False)
def any_true(mask) -> bool:
    """``mask.any()`` of a boolean array (any shape) without numpy's reduction machinery."""
    for x in mask.flat:
        if x:
            return True
    return False


@numba.njit(cache=True, nogil=True, _nrt=False)
def mark_at_least(a, value: int, out) -> bool:
    """``np.greater_equal(a, value, out=out)`` of a 1-d integer array into the bool array ``out``
    (same shape); returns ``out.any()``: one call for a mask and whether it is empty."""
    some = False
    for i in range(a.shape[0]):
        x = a[i] >= value
        out[i] = x
        some = some or x
    return some


@numba.njit(cache=True, nogil=True, _nrt=False)
def differs(a, b) -> bool:
    """Whether some entry of the 1-d float array ``a`` is not equal to ``b``'s (a NaN in
    either differs): ``(a != b).any()`` without a temporary."""
    for i in range(a.shape[0]):
        if a[i] != b[i]:
            return True
    return False


@numba.njit(cache=True, nogil=True, _nrt=False)
def all_finite(a) -> bool:
    """``np.isfinite(a).all()`` of a float array (any shape) without a temporary."""
    for x in a.flat:
        if not math.isfinite(x):
            return False
    return True


@numba.njit(cache=True, nogil=True, _nrt=False)
def copy_finite(source, dest) -> bool:
    """Copy ``source`` into ``dest`` (float arrays of one 2-D shape, any layout) if every value
    of ``source`` is finite, and return True; else return False, ``dest`` untouched."""
    rows, cols = source.shape
    for i in range(rows):
        for j in range(cols):
            if not math.isfinite(source[i, j]):
                return False
    for i in range(rows):
        for j in range(cols):
            dest[i, j] = source[i, j]
    return True
