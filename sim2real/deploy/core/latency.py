"""Per-stage latency histograms: fixed 1 us bins, O(1) per sample, nothing allocated per tick."""

from __future__ import annotations

import numpy as np

#: Histogram bins: 1 us wide from 0 to 20 ms, plus one overflow bin.
BIN_NS = 1_000
BINS = 20_000


class LatencyHistogram:
    """Fixed-bin latency histogram (1 us bins up to 20 ms) for ``stages`` stages; O(1) per sample,
    no allocation. Percentiles are exact to the bin width."""

    def __init__(self, stages: int = 1):
        self.counts = np.zeros((stages, BINS + 1), dtype=np.int64)
        self.max_ns = np.zeros(stages, dtype=np.int64)
        self._rows = np.arange(stages)
        self._flat = self.counts.reshape(-1)  # a view: one integer index per sample (add)

    def __getstate__(self) -> dict:
        """A copy (``copy.deepcopy``, pickle) makes its flat view of its own ``counts`` afresh."""
        return {k: v for k, v in self.__dict__.items() if k != "_flat"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._flat = self.counts.reshape(-1)

    def add(self, stage: int, ns: int) -> None:
        """One sample of ``ns`` ns to stage ``stage`` (its bin, the overflow bin past 20 ms)."""
        ns = int(ns)
        k = ns // BIN_NS if ns > 0 else 0
        self._flat[stage * (BINS + 1) + (k if k < BINS else BINS)] += 1
        if ns > self.max_ns[stage]:
            self.max_ns[stage] = ns

    def add_stages(self, stamps: np.ndarray) -> None:
        """``stamps`` (stages + 1,) int64 ns: stage i took ``stamps[i + 1] - stamps[i]``."""
        ns = np.diff(stamps)
        np.maximum(self.max_ns, ns, out=self.max_ns)
        np.clip(ns // BIN_NS, 0, BINS, out=ns)
        self.counts[self._rows, ns] += 1

    def clear(self) -> None:
        """Forget every sample (e.g. after a warm-up)."""
        self.counts[:] = 0
        self.max_ns[:] = 0

    def percentile(self, stage: int, p: float) -> float:
        """p-th percentile (0-100) of stage ``stage``, in us (NaN without samples)."""
        c = self.counts[stage]
        total = c.sum()
        if total == 0:
            return float("nan")
        idx = int(np.searchsorted(np.cumsum(c), np.ceil(p / 100.0 * total)))
        return (idx + 0.5) * BIN_NS / 1e3 if idx < BINS else self.max_ns[stage] / 1e3

    def summary(self, stage: int = 0) -> dict[str, float]:
        return {
            "p50_us": self.percentile(stage, 50),
            "p99_us": self.percentile(stage, 99),
            "p99.9_us": self.percentile(stage, 99.9),
            "max_us": float(self.max_ns[stage] / 1e3),
            "samples": int(self.counts[stage].sum()),
        }
