"""An exported LeRobot Diffusion Policy as a policy of the runtime (:class:`DiffusionChunkPolicy`):
:class:`~sim2real.deploy.policy.lerobot_policy.LeRobotChunkPolicy`'s rate, units, action queue and
cameras, plus what Diffusion Policy adds (:mod:`sim2real.deploy.export.lerobot_diffusion`):

- the observation history: at every policy tick (not only at a network call) the state, the
  goal and each camera's frame are appended to ``n_obs_steps`` observations per env
  (:class:`~sim2real.deploy.policy.obs_history.ObservationHistory`, lerobot's queues); a reset
  (the end of RAMP_IN, a resume) empties it, and the next policy tick fills it with copies of
  its observation, as ``select_action`` does after ``reset()``;
- the sampler's noise: at each network call the graph's noise inputs (``noise``, and DDPM's
  ``variance_noise``) are drawn standard normal, float32, from a generator seeded with
  ``(seed, env, call)`` (:func:`draw_noise`): a run is repeatable, and the noise of a call depends
  on nothing but the env and the count of calls before it (part of the state).

The history is the stage's state with the queue (:meth:`DiffusionChunkPolicy.state_dict`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim2real.deploy.policy.lerobot_policy import LeRobotChunkPolicy
from sim2real.deploy.policy.obs_history import ObservationHistory
from sim2real.deploy.spec.foreign import lerobot as lr


def history_shapes(contract: lr.LeRobotContract) -> dict[str, tuple[int, ...]]:
    """{graph input: shape of one observation}: the state, the environment state, each camera
    ``(3, H, W)``."""
    shapes = {lr.STATE_KEY: (contract.state_dim,)}
    if contract.env_state_dim:
        shapes[lr.ENV_STATE_KEY] = (contract.env_state_dim,)
    shapes.update({k: tuple(s) for k, s in contract.cameras})
    return shapes


def draw_noise(noise_inputs: dict, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """{input: standard normal float32 of its shape} for the graph's noise inputs
    (the contract's ``diffusion.noise_inputs``)."""
    return {
        name: rng.standard_normal(tuple(shape), dtype=np.float32)
        for name, shape in noise_inputs.items()
    }


class DiffusionChunkPolicy(LeRobotChunkPolicy):
    """A LeRobot Diffusion Policy export as the runtime's policy (module docstring).

    Args:
        path: The ONNX file ``policy-export FOLDER`` wrote from a Diffusion Policy folder.
        robot: Our robot description (as :class:`LeRobotChunkPolicy`'s).
        seed: The noise generator's seed (module docstring).
        inference: ``sync`` or ``async`` (:class:`LeRobotChunkPolicy`'s).

    Attributes:
        history: The :class:`ObservationHistory` of every env (graph inputs, LeRobot's units).

    Raises:
        lr.LeRobotFormatError: not a Diffusion Policy export (no ``diffusion.noise_inputs`` in
            its contract), or any refusal of :class:`LeRobotChunkPolicy`.
    """

    def __init__(self, path: str | Path, robot, seed: int = 0, inference: str = "sync"):
        self.seed = int(seed)
        contract = lr.read_onnx(path)
        d = contract.diffusion
        if contract.policy_type != "diffusion" or not d or not d.get("noise_inputs"):
            raise lr.LeRobotFormatError(
                f"{path}: metadata {lr.METADATA_KEY!r} is not a Diffusion Policy export "
                "(expected policy_type diffusion with diffusion.noise_inputs)"
            )
        self._noise_inputs = dict(d["noise_inputs"])
        super().__init__(path, robot, inference=inference)

    def _bind(self, envs: int) -> None:
        super()._bind(envs)
        self.history = ObservationHistory(
            self.contract.n_obs_steps, history_shapes(self.contract), envs
        )

    def reset(self, envs: np.ndarray | None = None) -> None:
        """As :meth:`LeRobotChunkPolicy.reset`, and the envs' histories emptied."""
        super().reset(envs)
        self.history.reset(envs)

    def _policy_tick(self, e: int, obs_row: np.ndarray) -> None:
        """Every policy tick (sync or async inference): the observation into env ``e``'s
        history first, then :class:`LeRobotChunkPolicy`'s tick (its call reads :meth:`_feed`)."""
        now = super()._feed(e, self._read(obs_row), copy=False)
        self.history.push({k: v[0] for k, v in now.items()}, e)  # without the batch axis
        super()._policy_tick(e, obs_row)

    def _feed(self, e: int, values: dict, copy: bool) -> dict[str, np.ndarray]:
        """The graph's inputs for env ``e``: its history (copied with ``copy``: a call beside
        the loop while the next policy tick appends) and the call's noise."""
        feed = {k: (v.copy() if copy else v)[None] for k, v in self.history.stacked(e).items()}
        rng = np.random.default_rng([self.seed, e, int(self.calls[e])])
        feed.update(draw_noise(self._noise_inputs, rng))
        return feed

    def _fields(self) -> dict:
        hist = {f"history.{k}": v for k, v in self.history.fields().items()}
        return super()._fields() | hist
