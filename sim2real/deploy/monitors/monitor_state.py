"""A monitor's checkpoint state (:class:`MonitorState`): its per-env arrays and tick count as a
``state_dict``, read back field by field (:func:`load_fields`), for the violation and
intervention monitors (:mod:`sim2real.deploy.monitors.violations`,
:mod:`sim2real.deploy.monitors.interventions`) and the soak's checkpoints."""

from __future__ import annotations

import numpy as np


class MonitorState:
    """``state_dict`` / ``load_state_dict`` of a per-env tick counter (the soak's checkpoints).

    A monitor gives ``_arrays()`` (name -> live array with a leading env axis), ``_tick_count``
    ((1,) int64, what :attr:`ticks` reads) and ``_state_name`` (for error messages); its state
    is those arrays (copies) and ``ticks``.
    """

    _state_name = "monitor"
    _tick_count: np.ndarray

    @property
    def ticks(self) -> int:
        """Ticks observed (calls of ``update``, or of a compiled tick that counts for it)."""
        return int(self._tick_count[0])

    @ticks.setter
    def ticks(self, value: int) -> None:
        self._tick_count[0] = value

    def _arrays(self) -> dict[str, np.ndarray]:
        raise NotImplementedError

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        """The monitor's arrays (copies, see the class docstring), each with its leading env
        axis of length envs, or 1 for one env ``env`` (a soak session's checkpoint), and
        ``ticks`` (1,) int64."""
        index = slice(None) if env is None else slice(env, env + 1)
        out = {k: v[index].copy() for k, v in self._arrays().items()}
        out["ticks"] = np.array([self.ticks], dtype=np.int64)
        return out

    def load_state_dict(self, state: dict[str, np.ndarray], env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of all envs, or of env ``env``).

        Raises:
            ValueError: a missing field, or one whose shape differs (named, with the expected
                shape).
        """
        index = slice(None) if env is None else slice(env, env + 1)
        self.ticks = load_fields(self._arrays(), state, index, self._state_name)


def load_fields(targets: dict[str, np.ndarray], state: dict, index: slice, what: str) -> int:
    """Write ``state`` (a monitor's ``state_dict``) into ``targets[index]`` after checking every
    field (present, same shape) and ``state["ticks"]`` (shape (1,)); returns the ticks.

    Raises:
        ValueError: a missing field or a shape that differs (named, with the expected shape).
    """
    expected = {k: v[index].shape for k, v in targets.items()}
    expected["ticks"] = (1,)
    for key, shape in expected.items():
        if key not in state:
            raise ValueError(f"{what} state: field '{key}' is missing")
        if np.shape(state[key]) != shape:
            raise ValueError(
                f"{what} state: field '{key}': expected shape {shape}, got {np.shape(state[key])}"
            )
    for key, target in targets.items():
        target[index] = state[key]
    return int(state["ticks"][0])
