"""The last ``n_obs_steps`` observations of a policy that reads a history
(:class:`ObservationHistory`), per env, kept at the policy's own rate: LeRobot's Diffusion
Policy's observation queues without torch (``DiffusionPolicy.select_action`` and
``populate_queues`` in ``lerobot/policies/utils.py``, lerobot 0.4.4): at every policy tick each
key's newest observation is appended and the oldest dropped; the first observation after a
reset fills the whole history (copied ``n_obs_steps`` times), as ``populate_queues`` does on an
empty queue.

The history is a stage's state (:meth:`state_dict` / :meth:`load_state_dict`).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.stateful import put, take


class ObservationHistory:
    """``n_obs_steps`` observations per key and env, oldest first.

    Args:
        n_obs_steps: Observations kept (>= 1).
        shapes: {key: shape of one observation} (``(6,)`` for a state, ``(3, H, W)`` for an
            image).
        envs: Robots of the batch.

    Attributes:
        data: {key: float32 (envs, n_obs_steps, *shape)}. filled: (envs,) bool, the env's
            history holds an observation (False after a reset).

    Raises:
        ValueError: ``n_obs_steps`` below 1.
    """

    def __init__(self, n_obs_steps: int, shapes: dict[str, tuple[int, ...]], envs: int = 1):
        if n_obs_steps < 1:
            raise ValueError(f"n_obs_steps must be >= 1, got {n_obs_steps}")
        self.n_obs_steps = int(n_obs_steps)
        self.shapes = {k: tuple(int(x) for x in s) for k, s in shapes.items()}
        self.envs = int(envs)
        self.data = {
            k: np.zeros((self.envs, self.n_obs_steps, *s), np.float32)
            for k, s in self.shapes.items()
        }
        self.filled = np.zeros(self.envs, bool)

    def reset(self, envs: np.ndarray | None = None) -> None:
        """Forget the history of the envs of ``envs`` (bool mask; None: all): their next
        :meth:`push` fills it."""
        if envs is None:
            self.filled[:] = False
        else:
            self.filled[np.asarray(envs, bool)] = False

    def push(self, obs: dict[str, np.ndarray], env: int = 0) -> None:
        """Append one observation of every key (each of its shape) to env ``env``'s history.

        Raises:
            KeyError: a key missing. ValueError: an observation of another shape.
        """
        for key, shape in self.shapes.items():
            x = np.asarray(obs[key], np.float32)
            if x.shape != shape:
                raise ValueError(f"{key}: an observation of shape {x.shape}, expected {shape}")
            d = self.data[key][env]
            if not self.filled[env]:
                d[:] = x
            else:
                d[:-1] = d[1:].copy()
                d[-1] = x
        self.filled[env] = True

    def stacked(self, env: int = 0) -> dict[str, np.ndarray]:
        """{key: (n_obs_steps, *shape) float32} of env ``env``, oldest first (views)."""
        return {k: v[env] for k, v in self.data.items()}

    def fields(self) -> dict[str, np.ndarray]:
        """The state's arrays (``filled`` and ``obs.<key>``), leading env axis, live."""
        return {"filled": self.filled} | {f"obs.{k}": v for k, v in self.data.items()}

    def state_dict(self, env: int | None = None) -> dict:
        """The histories and ``filled`` (copies with a leading env axis; ``env``: that env's)."""
        return take(self.fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Restore :meth:`state_dict`'s output (of all envs, or into ``env``).

        Raises:
            StateDictError: a missing field or another shape (nothing written)."""
        put(self.fields(), state, env)
