"""Per-stage latency histograms and downsampled MCAP telemetry.

MCAP is the robotics log format Foxglove opens. The recorder keeps a preallocated ring buffer,
samples every ``every``-th tick into it, and flushes it to the MCAP file when full and on close, so
a long run keeps its whole (downsampled) history with nothing allocated per tick in between. One
topic per stage of the tick, JSON messages (schemas are JSON Schema):

``/read`` encoder positions (rad) and their stamps (s); ``/estimate`` q (rad), dq (rad/s);
``/infer`` the policy action; ``/guard`` the guarded target; ``/smooth`` the command sent;
``/thermal`` reported winding temperatures (degC); ``/state`` the state machine of every env.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

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

    def add(self, stage: int, ns: int) -> None:
        ns = int(ns)
        self.counts[stage, min(ns // BIN_NS, BINS) if ns > 0 else 0] += 1
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


_TOPICS = ("/read", "/estimate", "/infer", "/guard", "/smooth", "/thermal", "/state")


class Telemetry:
    """Downsampled telemetry of a :class:`~deploy.runtime.Runtime`, written as MCAP.

    Args:
        path: Output ``.mcap`` file; written to ``path + '.part'`` and renamed on close, so a file
            under the final name is always complete.
        envs, n_joints: Shapes of the runtime.
        every: Keep one tick in ``every``.
        capacity: Rows of the ring buffer before a flush.
    """

    def __init__(
        self, path: str | Path, envs: int, n_joints: int, every: int = 10, capacity: int = 4096
    ):
        from mcap.writer import Writer

        self.path = Path(path)
        self.every, self.capacity = every, capacity
        self._tmp = self.path.with_name(self.path.name + ".part")
        self._file = open(self._tmp, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._file)
        self._writer.start(profile="", library="sim2real-deploy")
        self._channels = {}
        for topic in _TOPICS:
            schema = self._writer.register_schema(
                name=topic.strip("/"),
                encoding="jsonschema",
                data=json.dumps({"type": "object"}).encode(),
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema
            )
        shape = (capacity, envs, n_joints)
        self._t = np.zeros(capacity)
        self._pos = np.zeros(shape)
        self._stamp = np.zeros(shape)
        self._q = np.zeros(shape)
        self._dq = np.zeros(shape)
        self._action = np.zeros(shape, dtype=np.float32)
        self._target = np.zeros(shape)
        self._cmd = np.zeros(shape)
        self._temp = np.zeros(shape)
        self._mode = np.zeros((capacity, envs), dtype=np.int8)
        self._rows = 0
        self.messages = 0

    def record(self, rt) -> None:
        """Sample the runtime's latest tick (every ``every``-th call)."""
        if rt.ticks % self.every:
            return
        i = self._rows
        frame = rt.backend.frame
        self._t[i] = rt.time
        self._pos[i] = frame.position
        self._stamp[i] = frame.position_stamp
        self._q[i] = rt.state.q
        self._dq[i] = rt.state.dq
        self._action[i] = rt._action
        self._target[i] = rt._target
        self._cmd[i] = rt._cmd
        self._temp[i] = rt.state.winding_temperature
        self._mode[i] = rt.mode
        self._rows += 1
        if self._rows == self.capacity:
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows to the MCAP file."""

        def clean(a):
            return np.where(np.isfinite(a), a, None).tolist()

        for i in range(self._rows):
            t_ns = int(round(self._t[i] * 1e9))
            msgs = {
                "/read": {"position": clean(self._pos[i]), "stamp": clean(self._stamp[i])},
                "/estimate": {"q": self._q[i].tolist(), "dq": self._dq[i].tolist()},
                "/infer": {"action": clean(self._action[i])},
                "/guard": {"target": self._target[i].tolist()},
                "/smooth": {"command": self._cmd[i].tolist()},
                "/thermal": {"winding_temperature": self._temp[i].tolist()},
                "/state": {"mode": self._mode[i].tolist()},
            }
            for topic, msg in msgs.items():
                self._writer.add_message(
                    channel_id=self._channels[topic],
                    log_time=t_ns,
                    publish_time=t_ns,
                    data=json.dumps(msg).encode(),
                )
                self.messages += 1
        self._rows = 0

    def close(self) -> Path:
        """Flush, finish the MCAP file and move it to its final name; returns the path."""
        self.flush()
        self._writer.finish()
        self._file.close()
        os.replace(self._tmp, self.path)
        return self.path
