"""The tick's small compiled calls equal the numpy they replace, bit for bit: the plant's
temperature report (:func:`~sim2real.deploy.backends.sim.sensors_kernel.temperature_report`
against ``np.round(x / res) * res``, halves included), the command copy
(:func:`~sim2real.deploy.kernels.copy_finite`) and ``SimBackend.write`` bound to a buffer
written twice (a NaN still raises and leaves the command in force), and the smoother's rows
written through their ctypes views (its command against the numpy reference's), and the action
the drives ran (:func:`~sim2real.deploy.runtime.supervision_kernel.action_ran`: the tick's copy,
mode comparison and zeroing of the envs not RUNNING)."""

from __future__ import annotations

import numpy as np
import pytest

from sim2real.deploy.backends.sim.plant import NonFiniteCommandError, SimBackend
from sim2real.deploy.backends.sim.sensors_kernel import temperature_report
from sim2real.deploy.core.modes import Mode
from sim2real.deploy.kernels import copy_finite
from sim2real.deploy.runtime.supervision_kernel import action_ran


def test_the_action_the_drives_ran_equals_the_ticks_numpy():
    """An env RUNNING keeps the policy's (screened) action as its last action; an env in any
    other mode ran the runtime's override, and its last action reads 0."""
    rng = np.random.default_rng(5)
    action = rng.uniform(-2.0, 2.0, (6, 4)).astype(np.float32)
    mode = np.array([*(m.value for m in Mode), Mode.RUNNING], dtype=np.int8)  # every mode
    assert (mode == Mode.RUNNING).any() and (mode != Mode.RUNNING).any()
    expected, idle_expected = np.full((6, 4), 9.0), np.zeros(6, dtype=bool)
    expected[:] = action
    if np.not_equal(mode, Mode.RUNNING, out=idle_expected).any():
        np.copyto(expected, 0.0, where=idle_expected[:, None])
    last, idle = np.full((6, 4), 9.0), np.ones(6, dtype=bool)
    action_ran(last, action, mode, idle, int(Mode.RUNNING))
    assert last.tobytes() == expected.tobytes()
    np.testing.assert_array_equal(idle, idle_expected)


@pytest.mark.parametrize("resolution", [1.0, 0.5, 0.1, 0.25])
def test_temperature_report_equals_numpy_round(resolution):
    rng = np.random.default_rng(3)
    x = rng.uniform(-40.0, 160.0, size=(7, 5))
    x[0] = (np.arange(5) + 0.5) * resolution  # exact halves: half to even
    x[1] = -(np.arange(5) + 0.5) * resolution
    out, stamp = np.zeros_like(x), np.zeros(7)
    temperature_report(x, out, stamp, resolution, 12.5)
    expected = np.round(x / resolution)
    expected *= resolution
    assert out.tobytes() == expected.tobytes()
    assert (stamp == 12.5).all()


def test_copy_finite_copies_or_refuses():
    src, dest = np.arange(6.0).reshape(2, 3), np.full((2, 3), 7.0)
    assert copy_finite(src, dest) and (dest == src).all()
    bad = src.copy()
    bad[1, 2] = np.nan
    assert not copy_finite(bad, dest) and (dest == src).all()


def test_write_of_one_buffer_is_the_plain_write(arm3):
    plain = SimBackend(arm3, mode="velocity", envs=2, seed=0)
    bound = SimBackend(arm3, mode="velocity", envs=2, seed=0)
    buffer = np.zeros((2, arm3.n_joints))
    rng = np.random.default_rng(0)
    for _ in range(200):
        buffer[:] = rng.normal(size=buffer.shape)
        plain.write(buffer.copy())  # a new array each tick: never bound
        bound.write(buffer)
        plain.advance()
        bound.advance()
    assert bound._write_source is buffer and plain._write_source is None
    assert plain.true_position().tobytes() == bound.true_position().tobytes()
    before = bound.state_dict()["command"].copy()
    buffer[1, 0] = np.inf
    with pytest.raises(NonFiniteCommandError):
        bound.write(buffer)
    assert bound.state_dict()["command"].tobytes() == before.tobytes()


def test_a_copied_latency_histogram_counts_into_its_own_bins():
    """A histogram's copy (``copy.deepcopy``, pickle: a soak checkpoint's) adds to its own
    counts, the original's untouched; each sample in its 1-us bin, the overflow bin past 20 ms."""
    import copy
    import pickle

    from sim2real.deploy.core.latency import BINS, LatencyHistogram

    h = LatencyHistogram(2)
    h.add(1, 5_400)
    h.add(0, 10**9)  # past the last bin
    h.add(0, -3)  # a clock step back: the first bin
    for twin in (copy.deepcopy(h), pickle.loads(pickle.dumps(h))):
        twin.add(1, 5_999)
        assert twin.counts[1, 5] == 2 and twin.counts.sum() == 4
        assert twin.max_ns.tolist() == [10**9, 5_999]
    assert h.counts[1, 5] == 1 and h.counts[0, BINS] == 1 and h.counts[0, 0] == 1
    assert h.counts.sum() == 3 and h.max_ns.tolist() == [10**9, 5_400]
    assert h.percentile(1, 50) == 5.5
