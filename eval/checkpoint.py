"""Checkpoints of soak sessions: the complete state of one env of a batched runtime, on disk.

A soak session (:mod:`eval.soak`) is one env of a :class:`~deploy.runtime.Runtime` over a batched
:class:`~deploy.backends.sim.SimBackend`. To resume an interrupted session with nothing lost, and
with the same report as an uninterrupted run, a checkpoint holds everything a later tick reads:

=====================  =========================================================================
component              state captured (the env's slice of every batched array)
=====================  =========================================================================
MuJoCo                 ``mj_getState(mjSTATE_INTEGRATION)``: time, qpos, qvel, act, warm start,
                       ctrl, applied forces (pushes, cable); the model's ``dof_frictionloss``
                       (drift edits it in place)
SimBackend             latency buffers, command, torque, sensor settings, the last frame (the
                       drive repeats its temperature between reports), thermal nodes, tick, and
                       the env's sensor random stream (``bit_generator.state``)
JointStateEstimator    filter state and covariance, filter time, freshness, counters
CommandSmoother        Ruckig's input (current and target position, velocity, acceleration), the
                       held target, commanded position, stop flags, counters
SafetyGuard            counters, hard-violation flag, derating, last accepted target
OnnxPolicy             a recurrent policy's state (``state_dict(env)``; nothing for a
                       feed-forward policy)
Runtime                modes, causes, counters, non-finite streak, last actions, goal, estimated
                       state, ticks and time, latency histograms
GoalScheduler          goal times (running and issue), reached flags, best distances, counts,
                       times to reach, per-window counts, missed goals, intervention counters at
                       issue, its random stream
ViolationMonitor       true-state violation counters (``state_dict``)
InterventionMonitor    intervention counters and the guard's and smoother's counters at the last
                       tick (``state_dict``)
FaultInjector          schedule, base sensor settings, active faults, frozen frame, log
=====================  =========================================================================

The soak harness adds its own book-keeping (fault progress, latches, drift, curves and report
accumulators) to the same files (:mod:`eval.soak`).

Ruckig keeps its last trajectory inside the ``Ruckig`` object (it resamples that trajectory while
its input is unchanged, and recalculates otherwise; the results agree to ~1e-16, not bit for bit),
and the Python binding can neither read nor pickle it. The soak harness therefore calls
``Ruckig.reset()`` after every tick, so that every step recalculates from the input (as it does
anyway whenever a target changes) and the object holds nothing a later tick needs; a restored
smoother gets a fresh one (:func:`fresh_trajectory_generator`).

The objects are not changed: these functions read and write their attributes (private ones
included, which ties this module to the classes it captures; the tests of :mod:`eval.soak` run a
kill-and-resume against an uninterrupted run to catch any drift).

On disk (:func:`write_checkpoint`): ``state-<tick>.npz`` (arrays; compressed, no pickles) and
``checkpoint.json`` (format, version, the npz's name and SHA-256, and the JSON metadata), each
written to a temporary file and moved into place with ``os.replace``; the JSON is written last and
is the commit point, and the previous npz is removed only after it. A crash at any moment leaves
the previous checkpoint or the new one, never a mixture.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import mujoco
import numpy as np

FORMAT = "soak-checkpoint"
VERSION = 2
MANIFEST = "checkpoint.json"
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


class CheckpointError(ValueError):
    """A checkpoint cannot be read or does not fit the session; the message names the file."""


# ---------------------------------------------------------------------- random generators
def generator_state(gen: np.random.Generator) -> dict:
    """JSON-ready state of a numpy ``Generator`` (its ``bit_generator.state``)."""
    return gen.bit_generator.state


def set_generator_state(gen: np.random.Generator, state: dict) -> None:
    """Restore a state from :func:`generator_state` into ``gen`` (same bit generator kind)."""
    gen.bit_generator.state = state


# ---------------------------------------------------------------------- one env of a runtime
def _dofs(smoother, env: int) -> slice:
    n = smoother.n_joints
    return slice(env * n, (env + 1) * n)


#: Per-env fields a checkpoint keeps, each indexed by the env: (key prefix, the component of the
#: runtime that holds them, attribute names). One table serves capture_env and restore_env.
_PER_ENV_FIELDS = (
    (
        "runtime",
        lambda rt: rt,
        ("mode", "cause", "goal", "_action", "_last_valid_action", "_nan_streak")
        + ("_target", "_cmd", "_tracking"),
    ),
    (
        "state",
        lambda rt: rt.state,
        ("q", "dq", "ee_position", "ee_rotation", "winding_temperature", "last_action"),
    ),
    (
        "counters",
        lambda rt: rt.counters,
        ("non_finite_actions", "safe_stops", "resyncs", "anchors"),
    ),
    (
        "backend",
        lambda rt: rt.backend,
        ("_command", "_torque", "noise_sigma", "dropout_probability", "latency_ticks"),
    ),
    (
        "frame",
        lambda rt: rt.backend.frame,
        ("time", "position", "position_stamp", "winding_temperature", "temperature_stamp"),
    ),
    (
        "thermal",
        lambda rt: rt.backend.thermal,
        ("winding_temperature", "housing_temperature", "current", "power", "ambient"),
    ),
    (
        "estimator",
        lambda rt: rt.estimator,
        ("filter_time", "time_since_fresh", "stale_per_joint", "missing_per_joint")
        + ("reinitializations_per_joint", "_initialized"),
    ),
    (
        "smoother",
        lambda rt: rt.smoother,
        ("stopping", "non_finite_per_joint", "target_clamps_per_joint")
        + ("extrema_violations_per_joint", "stopping_distance_clamps_per_joint"),
    ),
)
#: The smoother's per-DoF arrays (indexed by the env's DoF slice).
_SMOOTHER_DOF_FIELDS = (
    "_pos",
    "_vel",
    "_acc",
    "_mean_acc",
    "_cmd",
    "_cmd_position",
    "_held",
    "_stop_dof",
)
#: Ruckig's input parameter fields (per DoF).
_RUCKIG_FIELDS = (
    "current_position",
    "current_velocity",
    "current_acceleration",
    "target_position",
    "target_velocity",
    "target_acceleration",
)


def capture_env(rt, env: int) -> tuple[dict[str, np.ndarray], dict]:
    """The state of env ``env`` of runtime ``rt`` (and of its SimBackend).

    Returns:
        ``(arrays, meta)``: arrays keyed ``component/field`` (the env's slices), and JSON-ready
        metadata (the env's sensor random stream, if the backend keeps one per env).
    """
    a: dict[str, np.ndarray] = {}
    meta: dict = {}
    e = env
    # runtime
    for prefix, owner, names in _PER_ENV_FIELDS:
        obj = owner(rt)
        for name in names:
            a[f"{prefix}/{name}"] = getattr(obj, name)[e]
    c = rt.counters
    for cause, values in c.faults.items():
        a[f"counters/faults/{cause}"] = values[e]
    # backend
    b = rt.backend
    m, d = b.models[e], b.datas[e]
    state = np.empty(mujoco.mj_stateSize(m, _STATE))
    mujoco.mj_getState(m, d, state, _STATE)
    a["backend/mj_state"] = state
    a["backend/dof_frictionloss"] = m.dof_frictionloss
    a["backend/warnings"] = np.array([w.number for w in d.warning])
    a["backend/buf_position"] = b._buf_position[:, e]
    a["backend/buf_stamp"] = b._buf_stamp[:, e]
    generators = getattr(b._rng, "generators", None)
    if generators is not None:
        meta["sensor_rng"] = generator_state(generators[e])
    # estimator
    est = rt.estimator
    a["estimator/x"] = est._x[:, e]
    a["estimator/p"] = est._p[:, e]
    # smoother
    sm = rt.smoother
    dof = _dofs(sm, e)
    for name in _SMOOTHER_DOF_FIELDS:
        a[f"smoother/{name}"] = getattr(sm, name)[dof]
    if sm.mode != "torque":
        inp = sm._inp
        for name in _RUCKIG_FIELDS:
            a[f"ruckig/{name}"] = np.asarray(getattr(inp, name), dtype=np.float64)[dof]
    # guard
    g = rt.guard
    for check, values in g.counts.items():
        a[f"guard/counts/{check}"] = values[e]
    a["guard/hard_violation"] = g.hard_violation[e]
    a["guard/effort_scale"] = g.effort_scale[e]
    a["guard/last_valid"] = g._last_valid[e]
    # policy: a recurrent policy's state (nothing for a feed-forward one)
    state_dict = getattr(rt.policy, "state_dict", None)
    if state_dict is not None:
        a.update({f"policy/{k}": v for k, v in state_dict(e).items()})
    return {k: np.array(v, copy=True) for k, v in a.items()}, meta


def restore_env(rt, env: int, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Write a state from :func:`capture_env` into env ``env`` of ``rt`` (built for the same
    robot, control mode and session models, and started).

    Raises:
        CheckpointError: a missing field, or a shape or MuJoCo state size that does not fit.
    """
    e = env

    def put(target: np.ndarray, index, key: str) -> None:
        if key not in arrays:
            raise CheckpointError(f"checkpoint field '{key}' is missing")
        value = arrays[key]
        if np.shape(target[index]) != np.shape(value):
            raise CheckpointError(
                f"checkpoint field '{key}': expected shape {np.shape(target[index])}, "
                f"got {np.shape(value)}"
            )
        target[index] = value

    for prefix, owner, names in _PER_ENV_FIELDS:
        obj = owner(rt)
        for name in names:
            put(getattr(obj, name), e, f"{prefix}/{name}")
    c = rt.counters
    for cause, values in c.faults.items():
        put(values, e, f"counters/faults/{cause}")

    b = rt.backend
    m, d = b.models[e], b.datas[e]
    state = arrays.get("backend/mj_state")
    if state is None or state.shape != (mujoco.mj_stateSize(m, _STATE),):
        raise CheckpointError(
            "checkpoint field 'backend/mj_state': the MuJoCo state does not fit the session's "
            f"model (expected {mujoco.mj_stateSize(m, _STATE)} values)"
        )
    mujoco.mj_setState(m, d, state, _STATE)  # no mj_forward: it would rewrite the warm start
    warnings = arrays.get("backend/warnings")
    if warnings is not None:
        for i, number in enumerate(warnings[: len(d.warning)]):
            d.warning[i].number = int(number)
    put(m.dof_frictionloss, slice(None), "backend/dof_frictionloss")
    put(b._buf_position, (slice(None), e), "backend/buf_position")
    put(b._buf_stamp, (slice(None), e), "backend/buf_stamp")
    generators = getattr(b._rng, "generators", None)
    if generators is not None:
        if "sensor_rng" not in meta:
            raise CheckpointError("checkpoint field 'sensor_rng' is missing")
        set_generator_state(generators[e], meta["sensor_rng"])

    est = rt.estimator
    put(est._x, (slice(None), e), "estimator/x")
    put(est._p, (slice(None), e), "estimator/p")
    est._all_initialized = bool(est._initialized.all())

    sm = rt.smoother
    dof = _dofs(sm, e)
    for name in _SMOOTHER_DOF_FIELDS:
        put(getattr(sm, name), dof, f"smoother/{name}")
    if sm.mode != "torque":
        inp = sm._inp
        for name in _RUCKIG_FIELDS:
            values = np.asarray(getattr(inp, name), dtype=np.float64)
            put(values, dof, f"ruckig/{name}")
            setattr(inp, name, values)
        sm._set_interfaces()  # the per-DoF interfaces follow the stop flags
        fresh_trajectory_generator(sm)
    sm._synced = True

    g = rt.guard
    for check, values in g.counts.items():
        put(values, e, f"guard/counts/{check}")
    put(g.hard_violation, e, "guard/hard_violation")
    put(g.effort_scale, e, "guard/effort_scale")
    put(g._last_valid, e, "guard/last_valid")

    load_state_dict = getattr(rt.policy, "load_state_dict", None)
    if load_state_dict is not None:
        state = {k[len("policy/") :]: v for k, v in arrays.items() if k.startswith("policy/")}
        try:
            load_state_dict(state, e)
        except ValueError as exc:
            raise CheckpointError(f"checkpoint field 'policy': {exc}") from None


def capture_shared(rt) -> tuple[dict[str, np.ndarray], dict]:
    """State every env of a batch shares: ticks and time, the backend tick, the overrun window and
    the latency histograms (wall-clock measurements, not seeded)."""
    arrays = {
        "shared/overrun_ring": rt._overrun_ring.copy(),
        "shared/latency_counts": rt.latency.counts.copy(),
        "shared/latency_max_ns": rt.latency.max_ns.copy(),
        "shared/tick_cost_counts": rt.tick_cost.counts.copy(),
        "shared/tick_cost_max_ns": rt.tick_cost.max_ns.copy(),
    }
    meta = {"ticks": rt.ticks, "time": rt.time, "backend_tick": rt.backend.tick}
    if getattr(rt.backend._rng, "generators", None) is None:
        meta["backend_rng"] = generator_state(rt.backend._rng)
    return arrays, meta


def restore_shared(rt, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Inverse of :func:`capture_shared`.

    Raises:
        CheckpointError: a missing field.
    """
    try:
        rt.ticks = int(meta["ticks"])
        rt.time = float(meta["time"])
        rt.backend.tick = int(meta["backend_tick"])
        rt._overrun_ring[:] = arrays["shared/overrun_ring"]
        rt.latency.counts[:] = arrays["shared/latency_counts"]
        rt.latency.max_ns[:] = arrays["shared/latency_max_ns"]
        rt.tick_cost.counts[:] = arrays["shared/tick_cost_counts"]
        rt.tick_cost.max_ns[:] = arrays["shared/tick_cost_max_ns"]
        if "backend_rng" in meta:
            set_generator_state(rt.backend._rng, meta["backend_rng"])
    except KeyError as exc:
        raise CheckpointError(f"checkpoint field {exc} is missing") from None


def fresh_trajectory_generator(smoother) -> None:
    """Give ``smoother`` a new ``Ruckig`` and ``OutputParameter``: its next step recalculates
    the trajectory from its input (see the module docstring). No-op in torque mode."""
    if smoother.mode == "torque":
        return
    from ruckig import OutputParameter, Ruckig

    smoother._ruckig = Ruckig(smoother.dofs, smoother.control_period)
    smoother._out = OutputParameter(smoother.dofs)


# ---------------------------------------------------------------------- monitors
def capture_monitor(prefix: str, monitor, e: int) -> dict[str, np.ndarray]:
    """Env ``e``'s slice of a monitor's ``state_dict`` (:class:`deploy.violations.ViolationMonitor`,
    :class:`deploy.interventions.InterventionMonitor`), keyed ``<prefix>/<field>``."""
    return {f"{prefix}/{k}": v for k, v in monitor.state_dict(e).items()}


def restore_monitor(prefix: str, monitor, e: int, arrays: dict[str, np.ndarray], where) -> None:
    """Inverse of :func:`capture_monitor`.

    Raises:
        CheckpointError: a missing field or a shape that does not fit (the message names the file
            ``where`` and the field).
    """
    start = len(prefix) + 1
    state = {k[start:]: v for k, v in arrays.items() if k.startswith(prefix + "/")}
    try:
        monitor.load_state_dict(state, e)
    except ValueError as exc:
        raise CheckpointError(f"{where}: checkpoint field '{prefix}': {exc}") from None


# ---------------------------------------------------------------------- goal scheduler, faults
def capture_goals(goals, e: int) -> tuple[dict[str, np.ndarray], dict]:
    """State of env ``e`` of a :class:`deploy.goals.GoalScheduler` with one stream per env."""
    arrays = {
        "goals/t_goal": goals.t_goal[e : e + 1].copy(),
        "goals/issued_at": goals.issued_at[e : e + 1].copy(),
        "goals/reached": goals.reached[e : e + 1].copy(),
        "goals/best_distance": goals.best_distance[e : e + 1].copy(),
        "goals/missed_dropped": goals.missed_dropped[e : e + 1].copy(),
        "goals/intervention_base": goals.intervention_base[:, e : e + 1].copy(),
    }
    meta = {
        "goals": int(goals.issued[e]),
        "hits": int(goals.hit_count[e]),
        "times": list(goals.hit_times[e]),
        "window_issued": list(goals.window_issued[e]),
        "window_reached": list(goals.window_reached[e]),
        "missed": list(goals.missed[e]),
        "rng": generator_state(goals.streams[e]),
    }
    return arrays, meta


def restore_goals(goals, e: int, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Inverse of :func:`capture_goals`.

    Raises:
        CheckpointError: a missing field, or an intervention base of another shape.
    """
    try:
        base = arrays["goals/intervention_base"]
        if base.shape != goals.intervention_base[:, e : e + 1].shape:
            raise CheckpointError(
                "checkpoint field 'goals/intervention_base': expected shape "
                f"{goals.intervention_base[:, e : e + 1].shape}, got {base.shape}"
            )
        goals.t_goal[e : e + 1] = arrays["goals/t_goal"]
        goals.issued_at[e : e + 1] = arrays["goals/issued_at"]
        goals.reached[e : e + 1] = arrays["goals/reached"]
        goals.best_distance[e : e + 1] = arrays["goals/best_distance"]
        goals.missed_dropped[e : e + 1] = arrays["goals/missed_dropped"]
        goals.intervention_base[:, e : e + 1] = base
        goals.issued[e] = int(meta["goals"])
        goals.hit_count[e] = int(meta["hits"])
        goals.hit_times[e] = [float(t) for t in meta["times"]]
        goals.window_issued[e] = [int(n) for n in meta["window_issued"]]
        goals.window_reached[e] = [int(n) for n in meta["window_reached"]]
        goals.missed[e] = list(meta["missed"])
        set_generator_state(goals.streams[e], meta["rng"])
    except KeyError as exc:
        raise CheckpointError(f"checkpoint field {exc} of the goal scheduler is missing") from None


def capture_injector(injector) -> tuple[dict[str, np.ndarray], dict]:
    """State of a :class:`deploy.faults.FaultInjector` (its schedule, base sensor settings,
    active faults, frozen frame of a stale fault, and log)."""
    from eval.fault_schedule import fault_to_dict

    arrays = {
        "injector/base_dropout": injector._base_dropout.copy(),
        "injector/base_latency": injector._base_latency.copy(),
    }
    frozen = injector._frozen
    if frozen is not None:
        for name, value in vars(frozen).items():
            arrays[f"injector/frozen/{name}"] = np.array(value, copy=True)
    meta = {
        "faults": [fault_to_dict(f) for f in injector.faults],
        "active": sorted(injector._active),
        "log": json.loads(json.dumps(injector.log)),
        "frozen": frozen is not None,
    }
    return arrays, meta


def restore_injector(injector, arrays: dict[str, np.ndarray], meta: dict) -> None:
    """Inverse of :func:`capture_injector`, into an injector built with the same schedule."""
    from deploy.backends.base import SensorFrame

    try:
        injector._base_dropout[:] = arrays["injector/base_dropout"]
        injector._base_latency[:] = arrays["injector/base_latency"]
        if meta["frozen"]:
            fields = SensorFrame.__dataclass_fields__
            injector._frozen = SensorFrame(
                **{k: arrays[f"injector/frozen/{k}"].copy() for k in fields}
            )
        else:
            injector._frozen = None
        injector._active = {int(i) for i in meta["active"]}
        injector.log = list(meta["log"])
    except KeyError as exc:
        raise CheckpointError(f"checkpoint field {exc} of the fault injector is missing") from None


# ---------------------------------------------------------------------- files
def atomic_write(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write ``data`` (str as UTF-8) to ``path`` through ``path.part``, fsync, then
    ``os.replace``: a file under the final name is always complete. Returns the path."""
    path = Path(path)
    tmp = path.with_name(path.name + ".part")
    with open(tmp, "wb") as f:
        f.write(data.encode("utf-8") if isinstance(data, str) else data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    return path


def write_checkpoint(
    directory: str | os.PathLike, arrays: dict[str, np.ndarray], meta: dict
) -> Path:
    """Write a checkpoint into ``directory`` atomically (see the module docstring).

    Args:
        directory: The session's folder (created if needed).
        arrays: Name -> numpy array (numeric or bool; no objects).
        meta: JSON-ready metadata; must hold ``tick`` (int), which names the npz file.

    Returns:
        The path of ``checkpoint.json``.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    name = f"state-{int(meta['tick']):012d}.npz"
    npz = directory / name
    tmp = directory / (name + ".part")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, npz)
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "arrays": name,
        "sha256": hashlib.sha256(npz.read_bytes()).hexdigest(),
        "meta": meta,
    }
    manifest = directory / MANIFEST
    atomic_write(manifest, json.dumps(doc))
    for old in directory.glob("state-*.npz*"):
        if old.name != name:
            old.unlink(missing_ok=True)
    return manifest


def read_checkpoint(directory: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict] | None:
    """Read the checkpoint in ``directory``; None if there is none.

    Returns:
        ``(arrays, meta)`` as written by :func:`write_checkpoint`.

    Raises:
        CheckpointError: the manifest is not valid JSON or not a soak checkpoint of this version,
            or its npz is missing, does not match its SHA-256 (truncated or altered) or cannot be
            read. The message names the file; delete the session's folder to start it afresh.
    """
    directory = Path(directory)
    manifest = directory / MANIFEST
    if not manifest.exists():
        return None
    hint = f"delete {directory} to restart this session from the beginning"
    try:
        doc = json.loads(manifest.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointError(f"{manifest}: not a readable checkpoint ({exc}); {hint}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise CheckpointError(f"{manifest}: field 'format': expected '{FORMAT}'; {hint}")
    if doc.get("version") != VERSION:
        raise CheckpointError(
            f"{manifest}: field 'version': expected {VERSION}, got {doc.get('version')!r}; {hint}"
        )
    for key in ("arrays", "sha256", "meta"):
        if key not in doc:
            raise CheckpointError(f"{manifest}: field '{key}' is missing; {hint}")
    npz = directory / str(doc["arrays"])
    if npz.parent != directory or not npz.is_file():
        raise CheckpointError(f"{manifest}: field 'arrays': {npz} does not exist; {hint}")
    data = npz.read_bytes()
    if hashlib.sha256(data).hexdigest() != doc["sha256"]:
        raise CheckpointError(
            f"{npz}: its SHA-256 differs from the one in {manifest} (truncated or altered); {hint}"
        )
    try:
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{npz}: cannot be read ({exc}); {hint}") from None
    return arrays, doc["meta"]
