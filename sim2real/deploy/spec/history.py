"""A frame history in the observation (:class:`ObservationHistory`): the policy reads its blocks
over the last few control ticks, and the ring of past frames that provides them (:class:`FrameRing`).

A *frame* is the observation the blocks make in one tick (normalized and clipped, float32,
``PolicySpec.frame_dim`` entries); the graph's input stacks frames of the ticks before it. What
the stacks write, and how it is said here:

==============================  ==============  ============  ==========  =====================
stack                           layout          order         fill        length
==============================  ==============  ============  ==========  =====================
legged_gym / humanoid-gym       ``per_frame``   oldest first  zeros       ``env.frame_stack``
Isaac Lab, mjlab, unitree_rl    ``per_term``    oldest first  first       ``history_length``
  deploy.yaml                                                             per term
holosoma                        ``per_term``    oldest first  zeros       group ``history_length``
rl_sar                          ``per_frame``   as listed     zeros       ``observations_history``
                                (``time``) or                             (0 the newest)
                                ``per_term``
==============================  ==============  ============  ==========  =====================

``per_frame``: the whole frame of each tick in turn; ``per_term``: each block's entries over its
ticks in turn, then the next block's (a block may read fewer ticks: ``lengths``). ``fill``: what a
tick before the history's start (the policy's reset: RAMP_IN handing over, a resume) reads:
``zeros`` (humanoid-gym's deque of zeros), or ``first``, the first frame after the reset (Isaac
Lab's ``CircularBuffer`` fills itself with its first entry). The stacking runs compiled
(:func:`sim2real.deploy.spec.kernel.stack_history`); :meth:`FrameRing.stack_reference` is its
numpy oracle, the same numbers bit for bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.spec.kernel import stack_history

#: The orders of a history's ticks in the graph's input.
ORDERS = ("oldest_first", "newest_first")
#: How the ticks are laid out: whole frames in turn, or each block's ticks in turn.
LAYOUTS = ("per_frame", "per_term")
#: What a tick before the history's start reads: zeros, or the first frame after the reset.
FILLS = ("zeros", "first")


@dataclass(frozen=True)
class ObservationHistory:
    """The frame history a policy reads (module docstring).

    Attributes:
        length: Ticks of history, the present one included (>= 1).
        order: ``oldest_first`` or ``newest_first`` (:data:`ORDERS`).
        layout: ``per_frame`` or ``per_term`` (:data:`LAYOUTS`).
        fill: ``zeros`` or ``first`` (:data:`FILLS`).
        lengths: ``per_term`` only: the ticks each block reads, one per block in order, each in
            ``1..length``; empty: every block reads ``length``.
    """

    length: int
    order: str = "oldest_first"
    layout: str = "per_frame"
    fill: str = "zeros"
    lengths: tuple[int, ...] = ()

    def problems(self, blocks: int) -> list[str]:
        """What is wrong with this history for a spec of ``blocks`` blocks, one line each."""
        out = []
        if not (isinstance(self.length, int) and self.length >= 1):
            out.append(f"history.length: expected ticks >= 1, got {self.length!r}")
        for name, value, allowed in (
            ("order", self.order, ORDERS),
            ("layout", self.layout, LAYOUTS),
            ("fill", self.fill, FILLS),
        ):
            if value not in allowed:
                out.append(f"history.{name}: '{value}' is unknown; expected one of {allowed}")
        if self.lengths:
            if self.layout != "per_term":
                out.append("history.lengths: per-block ticks need layout 'per_term'")
            if len(self.lengths) != blocks:
                out.append(
                    f"history.lengths: {len(self.lengths)} entries, the spec has {blocks} blocks"
                )
            bad = [n for n in self.lengths if not 1 <= n <= max(1, int(self.length))]
            if bad:
                out.append(f"history.lengths: {bad} outside 1..{self.length} (history.length)")
        return out

    def ticks(self, blocks: int) -> tuple[int, ...]:
        """The ticks each of ``blocks`` blocks reads."""
        return self.lengths or (self.length,) * blocks


def stacked_dim(history: ObservationHistory | None, sizes: tuple[int, ...]) -> int:
    """Entries of the graph's input for blocks of ``sizes`` entries (one frame without history)."""
    if history is None:
        return sum(sizes)
    return sum(s * t for s, t in zip(sizes, history.ticks(len(sizes)), strict=True))


def gather_table(history: ObservationHistory, sizes: tuple[int, ...]) -> np.ndarray:
    """(2, input entries) int64: for each entry of the graph's input, the tick it reads (0 the
    present, 1 the one before, ...) and its column in that tick's frame."""
    starts = np.concatenate([[0], np.cumsum(sizes)])[:-1].astype(int)
    ticks = history.ticks(len(sizes))

    def lags(n: int) -> range:
        return range(n - 1, -1, -1) if history.order == "oldest_first" else range(n)

    entries: list[tuple[int, int]] = []
    if history.layout == "per_frame":
        frame = sum(sizes)
        for lag in lags(history.length):
            entries += [(lag, c) for c in range(frame)]
    else:
        for start, size, n in zip(starts, sizes, ticks, strict=True):
            for lag in lags(n):
                entries += [(lag, start + c) for c in range(size)]
    return np.ascontiguousarray(np.array(entries, dtype=np.int64).reshape(-1, 2).T)


def runs_of(table: np.ndarray) -> np.ndarray:
    """(runs, 4) int64: a :func:`gather_table` as runs of input entries that read consecutive
    columns of one tick's frame: the tick, the first frame column, the first input entry, the
    length (what the kernel copies)."""
    out: list[list[int]] = []
    for k, (lag, column) in enumerate(table.T.tolist()):
        last = out[-1] if out else None
        if last and last[0] == lag and last[1] + last[3] == column:
            last[3] += 1
        else:
            out.append([lag, column, k, 1])
    return np.ascontiguousarray(np.array(out, dtype=np.int64).reshape(-1, 4))


def per_input_entry(spec, per_frame_entry: np.ndarray) -> np.ndarray:
    """A value per frame entry (``spec.frame_dim``) as a value per entry of the graph's input
    (``spec.obs_dim``): each input entry takes its frame column's (a clip, a scale)."""
    values = np.asarray(per_frame_entry)
    if spec.history is None:
        return values
    sizes = tuple(b.size for b in spec.observation_blocks)
    return values[gather_table(spec.history, sizes)[1]]


class FrameRing:
    """The past frames of each env: a ring of ``length`` frames, float32 (envs, length, frame),
    its newest slot ``head`` (envs,) and the frames pushed since each env's reset ``count``
    (envs,), at most ``length``; grown (and every env reset) when a batch of more envs comes.

    Args:
        history: The spec's history. table: Its :func:`gather_table` (the kernel copies its runs,
            :func:`runs_of`). frame: Entries of a frame.
    """

    def __init__(self, history: ObservationHistory, table: np.ndarray, frame: int):
        self.history, self.table, self.frame_dim = history, table, frame
        self.runs = runs_of(table)
        self.fill_first = history.fill == "first"
        self.frames = np.zeros((0, frame), dtype=np.float32)
        #: (frame, out, ring, the kernel bound to them) of the last call (:meth:`stack`)
        self._bound: tuple = ()
        self._size(0)

    def _size(self, envs: int) -> None:
        self.ring = np.zeros((envs, self.history.length, self.frame_dim), dtype=np.float32)
        self.head = np.zeros(envs, dtype=np.int64)
        self.count = np.zeros(envs, dtype=np.int64)
        self.frames = np.zeros((envs, self.frame_dim), dtype=np.float32)

    def frame_buffer(self, envs: int) -> np.ndarray:
        """float32 (envs, frame): where this tick's frame is written (the same array while the
        batch keeps its size)."""
        if self.ring.shape[0] != envs:
            self._size(envs)
        return self.frames

    def reset(self, envs: np.ndarray | None = None) -> None:
        """Start the history of the envs of ``envs`` (bool mask (envs,); default all) again: their
        next frame is the first, the ticks before it read the ``fill``."""
        if envs is None:
            self.count[:] = 0
        elif len(envs) == len(self.count):
            self.count[np.asarray(envs, dtype=bool)] = 0

    def stack(self, frame: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Push ``frame`` (float32 (envs, frame)) and write the graph's input into ``out``
        (float32 (envs, input entries)), compiled: the kernel's entry point bound to these
        arrays while ``frame``, ``out`` and the ring are the same objects (the runtime's every
        tick: :func:`sim2real.deploy.kernels.calls.bind`, no dispatch per call)."""
        bound = self._bound
        if not (bound and frame is bound[0] and out is bound[1] and self.ring is bound[2]):
            args = (frame, self.ring, self.head, self.count, self.runs, self.fill_first, out)
            if not (frame.flags.c_contiguous and out.flags.c_contiguous):
                stack_history(*args)
                return out
            self._bound = bound = (frame, out, self.ring, bind(stack_history, *args))
        bound[3]()
        return out

    def stack_reference(self, frame: np.ndarray, out: np.ndarray) -> np.ndarray:
        """:meth:`stack` in numpy (the kernel's oracle)."""
        length = self.history.length
        envs = frame.shape[0]
        self.head[:envs] = (self.head[:envs] + 1) % length
        rows = np.arange(envs)
        self.ring[rows, self.head[:envs]] = frame
        np.minimum(self.count[:envs] + 1, length, out=self.count[:envs])
        lag, column = self.table
        count = self.count[:envs, None]
        missing = lag[None, :] >= count
        read = np.where(missing, count - 1, lag[None, :]) if self.fill_first else lag[None, :]
        slot = (self.head[:envs, None] - read) % length
        out[:] = self.ring[rows[:, None], slot, column[None, :]]
        if not self.fill_first:
            out[missing] = 0.0
        return out
