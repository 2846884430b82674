"""Checkpoints of soak sessions: the complete state of one env of a batched runtime, on disk.

A soak session (:mod:`sim2real.eval.soak`) is one env of a :class:`~sim2real.deploy.runtime.Runtime` over a
batched :class:`~sim2real.deploy.backends.sim.plant.SimBackend`. So that an interrupted session resumes with
nothing lost, to the same report as an uninterrupted run, a checkpoint holds everything a later
tick reads: the composition of the stages' state dicts (``state_dict(env)``,
:mod:`sim2real.deploy.core.stateful`; each stage's documents its fields), each the env's slice, keyed
``<prefix>/<field>``. Prefixes: none for the :class:`~sim2real.deploy.runtime.Runtime`; ``estimator/``,
``guard/``, ``smoother/``, ``observation/`` (the policy's gait clocks and frame history),
``policy/`` (a recurrent policy's state; nothing for a feed-forward one), ``backend/`` (MuJoCo's
integration state, friction, sensor buffers and random stream, thermal nodes), ``goals/``,
``violations/``, ``interventions/`` and ``injector/`` (the session's
armed fault injector, if any). The soak harness adds its own book-keeping (``stats/`` arrays;
fault progress, latches, drift, curves and report accumulators in the metadata). Ruckig's
trajectory cannot be read from its binding; a restored smoother recalculates it from its input
(:meth:`~sim2real.deploy.smoothing.CommandSmoother.state_dict`; :mod:`sim2real.eval.soak.batch` has every step
recalculate anyway, so a restored session continues bit for bit).

On disk (:func:`write_checkpoint`): ``state-<tick>.npz`` (the arrays; compressed, no pickles)
and ``checkpoint.json`` (``FORMAT``, ``VERSION``, the npz's name and SHA-256, the state's scalars
and the JSON metadata), each written atomically (:func:`sim2real.robots.files.atomic_write`); the JSON is
written last and is the commit point, and the previous npz is removed only after it. A crash at
any moment leaves the previous checkpoint or the new one, never a mixture. A checkpoint that
cannot be read or does not fit the session is a :class:`CheckpointError` naming the file.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sim2real.deploy.core.stateful import StateDictError, section
from sim2real.robots.errors import Sim2RealError
from sim2real.robots.files import atomic_write, sha256_file

FORMAT = "soak-checkpoint"
#: 3: the composition of the stages' state dicts (2 read and wrote their private attributes).
#: 4: the runtime's safe-stop timeout (``stop_ticks``, ``counters/safe_stop_timeouts``); a
#: version 3 checkpoint has neither, and its sessions restart.
#: 5: the guard's distance per collision pair (``pair_clearance``, its per-pair screen); a
#: version 4 checkpoint has none.
#: 6: a legged robot's fall check (``fall_detector/low_ticks``: the height must persist); a
#: version 5 checkpoint has none.
#: 7: the violation monitor's ticks of a legged robot lying damped after a stop
#: (``violations/down/...``, ``violations/down_any``); a version 6 checkpoint has none.
#: 8: a legged robot's error-state base filter (``base_estimator/covariance``, ...), its fall
#: check's sinking count, the plant's IMU attitude and drive velocity readings; a version 7
#: checkpoint has the complementary filter's state.
#: 9: the base filter's accelerometer bias (``base_estimator/accel_bias``, a 12-state
#: covariance) and the soak's base-estimate figures (``estimation/...``); a version 8
#: checkpoint has neither.
#: 10: a legged robot's planar displacement (``tracker/displacement``, ``tracker/start_yaw``) and
#: its heading from the yaw tick to tick (``tracker/last_yaw``), the interventions that are not
#: the policy's style (``interventions/safety``), the command's last change
#: (``tracker/changed_at``, ``tracker/last_command``); a version 9 checkpoint has none.
#: 11: each joint's largest true speed (``stats/speed_peak``: the wheels' in the report); a
#: version 10 checkpoint has none.
#: 12: the policy's observation: its gait clocks and frame history (``observation/...``); a
#: version 11 checkpoint has neither, and a resume from it started them again.
#: 13: the interventions of a legged robot's ticks lying down after a stop, apart
#: (``interventions/down/...``, ``down_any``, ``down_safety``, ``down_ticks``), and the domain
#: pushes' RUNNING at the last tick (``push_force.running``); a version 12 checkpoint has neither.
#: 14: the self-collision ticks a motion clip's own contacts account for
#: (``violations/reference_ticks``, ``reference_pair_ticks``) and the scheduled pushes not applied
#: (``skipped_pushes``); a version 13 checkpoint has neither.
#: 15: a motion-tracking session's judged figures and play log (``figures/...``: its clips,
#: their errors and heat); a version 14 checkpoint has none, and a resume from it lost the clips
#: played before the checkpoint.
#: 16: a legged robot's yaw-rate tracking (``tracker/yaw_tracked_time``, ``yaw_ring``, ...) and
#: the schedule's heading commands (``commands/heading``, ``heading_ended``, ``heading_error``);
#: a version 15 checkpoint has neither, and its resumed yaw figure would lack the time before.
#: 17: how far past its hard limit each joint went, up and lying down, and its ticks lying down
#: (``violations/hard_joint_depth``, ``violations/down/hard_joint_ticks``,
#: ``violations/down/hard_joint_depth``), and each joint's ticks above its velocity and effort
#: limits and how far (``violations/speed_joint_*``, ``violations/effort_joint_*``); a version
#: 16 checkpoint has none.
#: 18: the base orientation the IMU's own attitude gives (``state/sensed_orientation``, a
#: tracking policy's anchor) and the simulated IMU's heading drift (``backend/imu/heading_*``);
#: a version 17 checkpoint has neither.
#: 18 (also): a motion-tracking session's base travel against its clip's root path (``travel/...``,
#: with the estimate's summed velocity ``travel/dead_reckoned``), its hand-over and after-clip
#: ticks (``figures/handed_over``, ``after_counts``, ``vseen``) and each play's rest
#: interventions and violations (``figures/play`` (envs, 12)); a version 17 checkpoint has none.
#: 19: a camera policy's verdict (``camera_verdict/verdict``: the camera faults each session
#: survived, stopped safely after or failed after) and the guard's floor of an arm escaping back
#: into its workspace box (``guard/escape_floor``); a version 18 checkpoint has neither (18 was
#: not bumped when the verdict was added: its camera sessions restart); a policy with several
#: cameras keeps each camera's stage and source under its name (``camera/<name>/...``).
VERSION = 19
MANIFEST = "checkpoint.json"


class CheckpointError(Sim2RealError, ValueError):
    """A checkpoint cannot be read or does not fit the session; the message names the file."""


def _hint(where: Path | str) -> str:
    return f"delete {Path(where).parent} to restart this session from the beginning"


def load_stage(stage, state: Mapping, env: int | None, where, prefix: str | None = None) -> None:
    """Load a checkpoint's state into one stage: ``stage.load_state_dict(part, env)``, ``part``
    the fields under ``prefix`` (the whole state without one).

    Args:
        stage: Any object with ``load_state_dict(state, env)`` (:mod:`sim2real.deploy.core.stateful`).
        state: The checkpoint's state (:func:`read_checkpoint`).
        env: The env to load (None: every env of the stage).
        where: The checkpoint's file, for messages.
        prefix: The stage's key prefix.

    Raises:
        CheckpointError: a missing field or one that does not fit; the message names ``where``
            and the field with its prefix.
    """
    part = state if prefix is None else section(state, prefix)
    try:
        stage.load_state_dict(part, env)
    except StateDictError as exc:
        err = exc if prefix is None else exc.under(prefix)
        raise CheckpointError(f"{where}: {err}; {_hint(where)}") from None
    except ValueError as exc:
        name = prefix or type(stage).__name__
        raise CheckpointError(f"{where}: field '{name}': {exc}; {_hint(where)}") from None


def optional_stages(batch) -> dict:
    """The stages only some soak batches have, by checkpoint prefix: a legged robot's
    ``estimation``, a terrain's ``terrain`` figures and ``curriculum`` walk, a camera policy's
    ``camera_verdict`` (:mod:`sim2real.eval.soak.camera_verdict`); those the batch has."""
    parts = {
        "estimation": batch.estimation,
        "terrain": batch.terrain_figures,
        "curriculum": batch.curriculum,
        "camera_verdict": batch.camera_verdict,
    }
    return {k: v for k, v in parts.items() if v is not None}


def split_state(state: Mapping) -> tuple[dict[str, np.ndarray], dict]:
    """A state's arrays (for the npz) and its scalars (int, float, bool or str, for the JSON).

    Raises:
        TypeError: a value that is neither (the message names the key).
    """
    arrays, scalars = {}, {}
    for key, value in state.items():
        if isinstance(value, np.ndarray):
            arrays[key] = value
        elif isinstance(value, bool | int | float | str | np.generic):
            scalars[key] = value.item() if isinstance(value, np.generic) else value
        else:
            raise TypeError(
                f"checkpoint field '{key}': expected an array or a scalar, got {type(value)}"
            )
    return arrays, scalars


# ---------------------------------------------------------------------- files
def write_checkpoint(directory: str | os.PathLike, state: Mapping, meta: dict) -> Path:
    """Write a checkpoint into ``directory`` atomically (see the module docstring).

    Args:
        directory: The session's folder (created if needed).
        state: Name -> numpy array (numeric or bool; no objects) or scalar (int, float, bool,
            str): a composition of state dicts.
        meta: JSON-ready metadata; must hold ``tick`` (int), which names the npz file.

    Returns:
        The path of ``checkpoint.json``.

    Raises:
        TypeError: a state value that is neither an array nor a scalar.
    """
    arrays, scalars = split_state(state)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    name = f"state-{int(meta['tick']):012d}.npz"
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    data = buffer.getvalue()
    atomic_write(directory / name, data)
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "arrays": name,
        "sha256": hashlib.sha256(data).hexdigest(),
        "scalars": scalars,
        "meta": meta,
    }
    manifest = directory / MANIFEST
    atomic_write(manifest, json.dumps(doc))
    for old in directory.glob("state-*.npz*"):
        if old.name != name:
            old.unlink(missing_ok=True)
    return manifest


def read_checkpoint(directory: str | os.PathLike) -> tuple[dict, dict] | None:
    """Read the checkpoint in ``directory``; None if there is none.

    Returns:
        ``(state, meta)`` as written by :func:`write_checkpoint` (the state's arrays and scalars
        in one dict).

    Raises:
        CheckpointError: the manifest is not valid JSON or not a soak checkpoint of this version
            (one written before the state dicts, version 2, included), or its npz is missing,
            does not match its SHA-256 (truncated or altered) or cannot be read. The message names
            the file and the field; delete the session's folder to start it afresh.
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
            f"{manifest}: field 'version': expected {VERSION}, got {doc.get('version')!r} "
            f"(a checkpoint of another version of the toolkit cannot be resumed); {hint}"
        )
    for key in ("arrays", "sha256", "scalars", "meta"):
        if key not in doc:
            raise CheckpointError(f"{manifest}: field '{key}' is missing; {hint}")
    npz = directory / str(doc["arrays"])
    if npz.parent != directory or not npz.is_file():
        raise CheckpointError(f"{manifest}: field 'arrays': {npz} does not exist; {hint}")
    if sha256_file(npz) != doc["sha256"]:
        raise CheckpointError(
            f"{npz}: its SHA-256 differs from the one in {manifest} (truncated or altered); {hint}"
        )
    try:
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{npz}: cannot be read ({exc}); {hint}") from None
    if not isinstance(doc["scalars"], dict):
        raise CheckpointError(f"{manifest}: field 'scalars': expected an object; {hint}")
    return {**arrays, **doc["scalars"]}, doc["meta"]
