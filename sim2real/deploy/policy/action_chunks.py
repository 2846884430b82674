"""Action chunks executed one action per policy tick: :class:`ActionChunks`, the two schemes of
LeRobot's ACT (``lerobot/policies/act/modeling_act.py``, lerobot 0.4.4), without torch.

- The action queue (``ACTPolicy.select_action`` without ``temporal_ensemble_coeff``): when the
  queue is empty the network is called and the first ``n_action_steps`` of its ``chunk_size``
  actions are queued; every tick pops one. A call every ``n_action_steps`` ticks.
- Temporal ensembling (``ACTTemporalEnsembler``, Algorithm 2 of Zhao et al. 2023, "Learning
  Fine-Grained Bimanual Manipulation with Low-Cost Hardware"): a call every tick; the action for
  the next tick is the online weighted average of every chunk's prediction for it, with weights
  ``w_i = exp(-coeff * i)``, ``w_0`` the oldest prediction's.

The executor is a stage: it owns its state (:meth:`state_dict` / :meth:`load_state_dict`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


class ActionChunks:
    """One action per tick out of chunks of actions.

    Args:
        chunk_size: Actions per chunk (the network's output ``(chunk_size, action_dim)``).
        n_action_steps: Actions executed per call (queue scheme; 1 with ensembling).
        temporal_ensemble_coeff: None: the queue; a finite number: temporal ensembling.

    Raises:
        ValueError: ``n_action_steps`` outside ``[1, chunk_size]``, or not 1 with ensembling.
    """

    def __init__(self, chunk_size: int, n_action_steps: int, temporal_ensemble_coeff=None):
        if not 1 <= n_action_steps <= chunk_size:
            raise ValueError(
                f"n_action_steps must be in [1, chunk_size={chunk_size}], got {n_action_steps}"
            )
        if temporal_ensemble_coeff is not None and n_action_steps != 1:
            raise ValueError(f"temporal ensembling needs n_action_steps 1, got {n_action_steps}")
        self.chunk_size = int(chunk_size)
        self.n_action_steps = int(n_action_steps)
        self.coeff = None if temporal_ensemble_coeff is None else float(temporal_ensemble_coeff)
        if self.coeff is not None:
            # float32 as lerobot computes them (torch.exp on torch.arange, then cumsum)
            w = np.exp(-np.float32(self.coeff) * np.arange(self.chunk_size, dtype=np.float32))
            self._w = w.astype(np.float32)
            self._wsum = np.cumsum(self._w, dtype=np.float32)
        self.calls = 0
        self.reset()

    def reset(self) -> None:
        """Forget every queued or ensembled action (an episode's start)."""
        self._queue: list[np.ndarray] = []
        self._ens: np.ndarray | None = None  # (k, action_dim)
        self._count: np.ndarray | None = None  # (k,)

    def needs_call(self) -> bool:
        """Whether the next :meth:`step` calls the network."""
        return self.coeff is not None or not self._queue

    def take(self, chunk: np.ndarray, skip: int) -> None:
        """Queue a chunk computed beside the loop (async inference, queue scheme only): its
        first ``skip`` actions dropped (their time has passed, as LeRobot's async client drops
        an action whose timestep is not after the last one executed, ``robot_client.py`` line
        241), then up to ``n_action_steps`` of the rest.

        Raises:
            ValueError: a chunk of another shape, or a stage with temporal ensembling.
        """
        if self.coeff is not None:
            raise ValueError("a chunk taken beside the loop needs the action queue, not ensembling")
        chunk = self._checked(chunk)
        self.calls += 1
        self._queue = list(chunk[skip : skip + self.n_action_steps])

    def pop(self) -> np.ndarray | None:
        """The next queued action (None: the queue is empty); async inference's step."""
        return self._queue.pop(0) if self._queue else None

    def queued(self) -> int:
        """Actions left in the queue."""
        return len(self._queue)

    def _checked(self, chunk) -> np.ndarray:
        chunk = np.asarray(chunk, dtype=np.float32)
        if chunk.ndim == 3 and chunk.shape[0] == 1:
            chunk = chunk[0]
        if chunk.ndim != 2 or chunk.shape[0] != self.chunk_size:
            raise ValueError(f"a chunk must be ({self.chunk_size}, action_dim), got {chunk.shape}")
        return chunk

    def step(self, predict: Callable[[], np.ndarray]) -> np.ndarray:
        """The action of this tick; ``predict()`` is called when a chunk is needed and returns
        ``(chunk_size, action_dim)`` (a leading batch axis of 1 is accepted)."""
        if self.needs_call():
            chunk = np.asarray(predict(), dtype=np.float32)
            if chunk.ndim == 3 and chunk.shape[0] == 1:
                chunk = chunk[0]
            if chunk.ndim != 2 or chunk.shape[0] != self.chunk_size:
                raise ValueError(
                    f"a chunk must be ({self.chunk_size}, action_dim), got {chunk.shape}"
                )
            self.calls += 1
            if self.coeff is None:
                self._queue = list(chunk[: self.n_action_steps])
            else:
                self._ensemble(chunk)
        if self.coeff is None:
            return self._queue.pop(0)
        action, self._ens, self._count = self._ens[0], self._ens[1:], self._count[1:]
        return action

    def _ensemble(self, chunk: np.ndarray) -> None:
        """``ACTTemporalEnsembler.update`` on one chunk (batch 1)."""
        if self._ens is None:
            self._ens = chunk.copy()
            self._count = np.ones(self.chunk_size, dtype=np.int64)
            return
        c = self._count
        ens = self._ens * self._wsum[c - 1][:, None]
        ens = ens + chunk[:-1] * self._w[c][:, None]
        ens = ens / self._wsum[c][:, None]
        self._count = np.concatenate([np.minimum(c + 1, self.chunk_size), [1]])
        self._ens = np.concatenate([ens, chunk[-1:]], axis=0).astype(np.float32)

    def state_dict(self) -> dict:
        """The queued or ensembled actions and the call count."""
        return {
            "queue": [a.copy() for a in self._queue],
            "ens": None if self._ens is None else self._ens.copy(),
            "count": None if self._count is None else self._count.copy(),
            "calls": self.calls,
        }

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict`'s output."""
        self._queue = [np.asarray(a, dtype=np.float32) for a in state["queue"]]
        self._ens = None if state["ens"] is None else np.asarray(state["ens"], np.float32)
        self._count = None if state["count"] is None else np.asarray(state["count"], np.int64)
        self.calls = int(state["calls"])
