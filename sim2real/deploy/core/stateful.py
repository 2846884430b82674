"""State dicts: the explicit state of the runtime's stages, for checkpoints and exact resumes.

Every stage that keeps state from one tick to the next (estimator, guard, smoother, runtime, goal
scheduler, fault injector, policy, simulated plant, monitors) has::

    state_dict(env=None) -> dict[str, np.ndarray | int | float | bool | str]
    load_state_dict(state, env=None)

and loading a state into a fresh instance built with the same arguments continues exactly where
the source stood: the same outputs, bit for bit.

Conventions (those of :class:`sim2real.deploy.monitors.violations.ViolationMonitor`):

- Batched stages keep their env axis (leading, unless a field says otherwise): all envs for
  ``env=None``, or length 1 for one env ``env`` (``slice(env, env + 1)``), so that the state of
  one env of a batch also loads into a one-env instance with ``env=None``. Values the batch shares
  (a tick count, a clock, a shared random stream) are in the dict either way and are loaded
  either way. (:class:`sim2real.deploy.policy.onnx_policy.OnnxPolicy` drops the env axis for one env; the
  runtime passes ``env`` through to it unchanged.)
- Arrays are copies; scalars are Python ``int``, ``float``, ``bool`` or ``str``. A random
  generator's state (``bit_generator.state``) and ragged records (lists per env) are JSON text
  (:func:`streams_json`, :func:`records_json` and their inverses).
- Composite stages prefix their parts' keys with ``<part>/`` (:func:`prefixed`, :func:`section`;
  :func:`parts_state_dict` and :func:`load_parts` for a stage that is only its parts).
- A state that does not fit raises :class:`StateDictError` (a ``ValueError``) naming the field.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from sim2real.robots.errors import Sim2RealError

Scalar = int | float | bool | str


class StateDictError(Sim2RealError, ValueError):
    """A state dict that does not fit the stage: a missing field, a shape or kind that differs.

    Attributes:
        key: The field, with the prefixes of the stages it is nested in (:meth:`under`).
        problem: What is wrong with it (``" is missing"``, ``": expected shape ..."``).
    """

    def __init__(self, key: str, problem: str):
        self.key, self.problem = key, problem
        super().__init__(f"field '{key}'{problem}")

    def under(self, prefix: str) -> StateDictError:
        """The same error, its key nested under ``prefix`` (a composite stage's part)."""
        return StateDictError(f"{prefix}/{self.key}", self.problem)


def env_index(env: int | None) -> slice:
    """The index of the convention: every env (None) or env ``env`` keeping its axis."""
    return slice(None) if env is None else slice(env, env + 1)


def env_list(envs: int, env: int | None) -> list[int]:
    """The envs a state dict of a batch of ``envs`` covers: every one (``env`` None) or ``[env]``."""
    return list(range(envs)) if env is None else [env]


def take(fields: Mapping[str, np.ndarray], env: int | None) -> dict[str, np.ndarray]:
    """Copies of ``fields[k][env_index(env)]`` (arrays with a leading env axis)."""
    index = env_index(env)
    return {k: np.array(v[index], copy=True) for k, v in fields.items()}


def check(fields: Mapping[str, np.ndarray], state: Mapping, env: int | None) -> None:
    """Check that ``state`` has every key of ``fields``, shaped as ``fields[k][env_index(env)]``.

    Raises:
        StateDictError: a missing field, or a shape that differs from the target's.
    """
    index = env_index(env)
    for key, target in fields.items():
        if key not in state:
            raise StateDictError(key, " is missing")
        expected, got = np.shape(target[index]), np.shape(state[key])
        if got != expected:
            raise StateDictError(key, f": expected shape {expected}, got {got}")


def put(fields: Mapping[str, np.ndarray], state: Mapping, env: int | None) -> None:
    """Write ``state[k]`` into ``fields[k][env_index(env)]`` for every key of ``fields``.

    Every field is checked (:func:`check`) before anything is written: a state that does not fit
    changes nothing.

    Raises:
        StateDictError: a missing field, or a shape that differs from the target's.
    """
    check(fields, state, env)
    index = env_index(env)
    for key, target in fields.items():
        target[index] = state[key]


def load_named(parts: Iterable[tuple[str, object]], state: Mapping, env: int | None) -> None:
    """Load each ``(name, stage)`` of ``parts`` from the keys ``<name>/...`` of ``state`` (its
    ``load_state_dict``; of every env, or of env ``env``): one stage's parts under their names,
    as several cameras of one policy are kept.

    Raises:
        StateDictError: (or what a stage raises) a stage's field missing or of another shape;
            nothing is written: the stages loaded before it are put back first.
    """
    done = []
    try:
        for name, part in parts:
            head = f"{name}/"
            before = part.state_dict(env)
            part.load_state_dict(
                {k[len(head) :]: v for k, v in state.items() if k.startswith(head)}, env
            )
            done.append((part, before))
    except Exception:
        for part, before in done:
            part.load_state_dict(before, env)
        raise


def scalar(state: Mapping, key: str, kind: type[Scalar]) -> Scalar:
    """``state[key]`` as a Python ``kind`` (int, float, bool or str; a 0-d array is accepted).

    Raises:
        StateDictError: the field is missing or is not a single value.
    """
    if key not in state:
        raise StateDictError(key, " is missing")
    value = state[key]
    if np.ndim(value) != 0:
        raise StateDictError(
            key, f": expected a single {kind.__name__}, got shape {np.shape(value)}"
        )
    value = value.item() if isinstance(value, np.ndarray | np.generic) else value
    if kind is str and not isinstance(value, str):
        raise StateDictError(key, f": expected text, got {type(value).__name__}")
    return kind(value)


def to_json(value) -> str:
    """JSON text of ``value`` (lists, dicts, numbers; floats round-trip exactly)."""
    return json.dumps(value)


def from_json(state: Mapping, key: str):
    """The value of the JSON text ``state[key]``.

    Raises:
        StateDictError: the field is missing or not valid JSON.
    """
    text = scalar(state, key, str)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise StateDictError(key, f": not valid JSON ({exc})") from None


def records_json(records: Mapping[str, Sequence], envs: Iterable[int]) -> dict[str, str]:
    """Ragged per-env records (key -> a list over all envs) as JSON text of the envs ``envs``
    (:func:`env_list`): ``{key: to_json([records[key][e] for e in envs])}``."""
    envs = list(envs)
    return {key: to_json([lists[e] for e in envs]) for key, lists in records.items()}


def read_records(state: Mapping, keys: Iterable[str], count: int) -> dict[str, list]:
    """Inverse of :func:`records_json`: ``{key: the list of ``count`` envs' records}``.

    Raises:
        StateDictError: a field missing, not JSON, or not a list of ``count`` entries.
    """
    out = {}
    for key in keys:
        value = from_json(state, key)
        if not isinstance(value, list) or len(value) != count:
            raise StateDictError(key, f": expected a list of {count} env(s)")
        out[key] = value
    return out


def streams_json(streams: Sequence[np.random.Generator], envs: Iterable[int]) -> str:
    """JSON text of per-env random streams' states (:func:`rng_state`), a list over ``envs``."""
    return to_json([rng_state(streams[e]) for e in envs])


def read_streams(state: Mapping, key: str, count: int) -> list:
    """The parsed :func:`streams_json` ``state[key]``, checked to hold ``count`` states.

    Raises:
        StateDictError: the field is missing, not JSON, or not a list of ``count`` states.
    """
    states = from_json(state, key)
    if not (isinstance(states, list) and len(states) == count):
        raise StateDictError(key, f": expected {count} stream state(s), one per env")
    return states


def set_streams(
    streams: Sequence[np.random.Generator], envs: Iterable[int], states: Sequence, key: str
) -> None:
    """Restore the states of :func:`read_streams` into ``streams[e]`` for the envs ``envs``.

    Raises:
        StateDictError: a state of another kind of bit generator (:func:`set_rng_state`).
    """
    for e, value in zip(envs, states, strict=True):
        set_rng_state(streams[e], value, key)


def rng_state(gen: np.random.Generator):
    """A numpy ``Generator``'s ``bit_generator.state`` (a JSON-ready dict)."""
    return gen.bit_generator.state


def set_rng_state(gen: np.random.Generator, state, key: str) -> None:
    """Restore a :func:`rng_state` into ``gen`` (the same kind of bit generator).

    Raises:
        StateDictError: a state of another kind of bit generator, or not a state at all.
    """
    try:
        gen.bit_generator.state = state
    except (TypeError, ValueError) as exc:
        kind = type(gen.bit_generator).__name__
        raise StateDictError(key, f": not a state of {kind} ({exc})") from None


def prefixed(prefix: str, state: Mapping) -> dict:
    """``state`` with every key nested under ``prefix`` (``<prefix>/<key>``)."""
    return {f"{prefix}/{k}": v for k, v in state.items()}


def section(state: Mapping, prefix: str) -> dict:
    """The part of ``state`` under ``prefix``, the prefix stripped (inverse of :func:`prefixed`)."""
    start = len(prefix) + 1
    return {k[start:]: v for k, v in state.items() if k.startswith(prefix + "/")}


def load_part(prefix: str, part, state: Mapping, env: int | None) -> None:
    """``part.load_state_dict(section(state, prefix), env)``, errors naming the nested field.

    Raises:
        StateDictError: from the part (its key nested under ``prefix``), or any ``ValueError``
            of a part outside this convention, reported under ``prefix``.
    """
    try:
        part.load_state_dict(section(state, prefix), env)
    except StateDictError as exc:
        raise exc.under(prefix) from None
    except ValueError as exc:
        raise StateDictError(prefix, f": {exc}") from None


def parts_state_dict(parts: Mapping, env: int | None) -> dict:
    """The state of a composite stage: every part's ``state_dict(env)`` (``parts``: prefix ->
    part), its keys under its prefix (:func:`prefixed`)."""
    out: dict = {}
    for prefix, part in parts.items():
        out.update(prefixed(prefix, part.state_dict(env)))
    return out


def load_parts(parts: Mapping, state: Mapping, env: int | None) -> None:
    """Inverse of :func:`parts_state_dict`: :func:`load_part` for every part, in order.

    Raises:
        StateDictError: from a part, its key nested under the part's prefix (the parts before it
            are loaded).
    """
    for prefix, part in parts.items():
        load_part(prefix, part, state, env)
