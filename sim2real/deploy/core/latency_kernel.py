"""Kernel of the runtime's per-tick latency bookkeeping
(``sim2real.deploy.core.latency.LatencyHistogram``).

One call does what ``latency.add_stages(stamps)`` and ``tick_cost.add(0, cost)`` do: the stage
durations between consecutive stamps into the stage histograms, and the runtime's cost without
the physics stage (the last one) into the tick-cost histogram (1 us bins, overflow bin last).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, _nrt=False)
def add_stages(
    stamps: np.ndarray,
    bins: np.ndarray,
    counts: np.ndarray,
    max_ns: np.ndarray,
    cost_counts: np.ndarray,
    cost_max_ns: np.ndarray,
) -> None:
    """Record one tick.

    Args:
        stamps: (stages + 1,) int64 ns, stage ``i`` from ``stamps[i]`` to ``stamps[i + 1]``; the
            last stage is the physics.
        bins: (2,) int64: bin width (ns) and number of bins (``sim2real.deploy.observe.telemetry.BIN_NS``,
            ``BINS``).
        counts, max_ns: the stage histogram's arrays, (stages, bins + 1) and (stages,) int64.
        cost_counts, cost_max_ns: the tick-cost histogram's, (1, bins + 1) and (1,) int64.
    """
    width, top = bins[0], bins[1]
    stages = stamps.shape[0] - 1
    for i in range(stages):
        ns = stamps[i + 1] - stamps[i]
        if ns > max_ns[i]:
            max_ns[i] = ns
        k = ns // width
        counts[i, 0 if k < 0 else (top if k > top else k)] += 1
    cost = stamps[stages - 1] - stamps[0]
    k = cost // width
    counts_k = 0 if cost <= 0 else (top if k > top else k)
    cost_counts[0, counts_k] += 1
    if cost > cost_max_ns[0]:
        cost_max_ns[0] = cost
