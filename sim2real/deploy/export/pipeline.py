"""The export itself: :func:`export_policy` (and :func:`run_export`, which returns the figures as
an :class:`ExportResult`) loads the source, builds the ONNX graph, writes it under a temporary name
in the destination folder, runs the parity gate on it, and moves it into place only if every check
passes. A candidate that fails the gate is kept under :func:`failed_path` (``<stem>.parity-failed
.onnx`` beside the destination, its ``parity`` metadata saying ``"passed": false``) for
inspection; nothing is written under the real name.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnx

from sim2real.deploy.export.errors import ExportError, ParityError, _first_line
from sim2real.deploy.export.graph import (
    OPSET,
    _recurrent_to_onnx,
    set_metadata,
    to_onnx,
    tool_versions,
)
from sim2real.deploy.export.load import load_source
from sim2real.deploy.export.noise_floor import (
    NoiseFloor,
    _max_abs,
    _num,
    describe_tolerance,
    gate_passed,
)
from sim2real.deploy.export.parity import (
    PARITY_SAMPLES,
    closed_loop_parity,
    parity_observations,
    sequence_parity,
    source_sequence_parity,
    static_parity,
)
from sim2real.deploy.export.recurrent import RecurrentStepper
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError
from sim2real.deploy.spec.subset import run_spec
from sim2real.robots import Robot, load_robot
from sim2real.robots.files import atomic_path, atomic_write, sha256_file

#: The name a candidate that fails the parity gate is kept under (see :func:`failed_path`).
FAILED_SUFFIX = ".parity-failed.onnx"


@dataclass(frozen=True)
class ExportResult:
    """What an export produced.

    Attributes:
        path: The ONNX file. source_format: Detected input format. parity: Parity figures.
        seconds: Wall time of the whole export. spec: The spec stored in the file.
    """

    path: Path
    source_format: str
    parity: dict[str, Any]
    seconds: float
    spec: PolicySpec
    exporter: str


def _resolve_robot(robot: Robot | str | os.PathLike | None, spec: PolicySpec, where: str) -> Robot:
    if isinstance(robot, Robot):
        return robot
    name = spec.robot if robot is None else robot
    try:
        return load_robot(name)
    except Exception as exc:  # noqa: BLE001 - RobotSpecError, FileNotFoundError, ...
        raise ExportError(f"{where}: cannot load robot '{name}': {_first_line(exc)}") from None


def _write(model: onnx.ModelProto, path: Path) -> None:
    path.write_bytes(model.SerializeToString())  # fsync-ed by atomic_path before the rename


def failed_path(out: str | os.PathLike) -> Path:
    """Where a candidate that failed the parity gate is kept: ``<stem>.parity-failed.onnx``
    beside ``out`` (``h1.onnx`` -> ``h1.parity-failed.onnx``)."""
    out = Path(out)
    return out.with_name(out.stem + FAILED_SUFFIX)


def check_tolerance(tolerance: float | None) -> None:
    """Refuse a ``--parity-tolerance`` that is not a finite number > 0.

    Raises:
        ExportError: naming the flag and the value.
    """
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance > 0):
        raise ExportError(f"--parity-tolerance: expected a finite number > 0, got {tolerance}")


def parity_errors(f: dict[str, Any]) -> str:
    """Each part of the gate in ``f``, its error with its tolerance and floor, comma-separated
    (an absolute tolerance's reason said once)."""
    parts = [
        ("", f"{f['samples']} observations"),
        ("replay_", f"the {f.get('replay_ticks')}-tick closed-loop replay"),
        ("state_", "the recurrent state"),
    ]
    said, text = "", []
    for prefix, where in parts:
        if f"{prefix}max_abs_error" not in f:
            continue
        tolerance = describe_tolerance(f, prefix, said)
        said = f.get(f"{prefix}tolerance_note", said)
        text.append(f"{_num(f[prefix + 'max_abs_error'])} over {where} ({tolerance})")
    return ", ".join(text)


def _parity_message(source: Path, f: dict[str, Any]) -> str:
    """What the gate found, in one line: each part's error with its tolerance and floor."""
    return f"{source}: ONNX and torch disagree: max abs error {parity_errors(f)}"


def run_export(
    source: str | os.PathLike,
    out: str | os.PathLike | None = None,
    spec: PolicySpec | str | os.PathLike | None = None,
    trust_pickle: bool = False,
    vecnormalize: str | os.PathLike | None = None,
    activation: str | None = None,
    robot: Robot | str | os.PathLike | None = None,
    exporter: str = "torchscript",
    seed: int = 0,
    tolerance: float | None = None,
    metadata: dict[str, str] | None = None,
) -> ExportResult:
    """:func:`export_policy` (the arguments are documented there), returning the parity figures
    and the timing as well: the :class:`ExportResult`. ``metadata``: more entries of the file's
    metadata (e.g. ``training_domain``, :mod:`sim2real.eval.world.domain`).
    """
    t0 = time.perf_counter()
    source = Path(source)
    check_tolerance(tolerance)
    src = load_source(source, spec, trust_pickle, vecnormalize, activation)
    out = output_path(source, out)
    the_robot = _resolve_robot(robot, src.spec, str(source))
    try:  # a policy over some of the robot's joints: the rest held (sim2real.deploy.spec.subset)
        run_spec(src.spec, the_robot).check_robot(the_robot)
    except SpecError as exc:
        raise ExportError(f"{source}: {exc}") from None

    module = src.module()
    if src.recurrent:
        model = _recurrent_to_onnx(module, src.spec.obs_dim, exporter)
    else:
        model = to_onnx(module, src.spec.obs_dim, exporter)
    baked = {"observation_normalizer": src.normalizer is not None, "action_clip": True}
    exporter_text = f"torch.onnx.export(dynamo={exporter == 'dynamo'}), opset {OPSET}" + (
        " (TorchScript-based)" if exporter == "torchscript" else " (torch.export-based)"
    )
    base_meta = _base_metadata(source, src, exporter_text, metadata)

    # the file is written and checked under a temporary name, moved onto ``out`` only if it passes
    try:
        with atomic_path(out) as tmp:
            pending = dataclasses.replace(src.spec, baked=baked, parity={})
            set_metadata(model, {"policy_spec": pending.to_json(), **base_meta})
            model.doc_string = (
                f"{src.spec.robot} policy exported by policy-export from {source.name}"
            )
            _write(model, tmp)
            try:
                policy = OnnxPolicy(tmp, the_robot)
            except PolicyLoadError as exc:
                raise ExportError(
                    f"the exported graph does not load in the runtime: {exc}"
                ) from None
            try:
                figures = _parity_gate(source, policy, module, src, the_robot, seed, tolerance)
            except ParityError as exc:
                kept = _keep_failed(model, pending, base_meta, exc.figures, out)
                message = f"{exc}; nothing written, the candidate kept as {kept}"
                raise ParityError(message, exc.figures) from None
            final = dataclasses.replace(src.spec, baked=baked, parity=figures)
            set_metadata(
                model,
                {"policy_spec": final.to_json(), **base_meta, "parity": json.dumps(figures)},
            )
            _write(model, tmp)
            _same_actions(tmp, the_robot, policy, src.spec, seed, f"{source}", figures)
    except OSError as exc:
        raise ExportError(f"{out}: cannot write in {out.parent}: {exc.strerror or exc}") from None
    failed_path(out).unlink(missing_ok=True)  # a candidate kept by an earlier failed export
    return ExportResult(
        path=out,
        source_format=src.source_format,
        parity=figures,
        seconds=time.perf_counter() - t0,
        spec=final,
        exporter=exporter_text,
    )


def _same_actions(path: Path, robot, policy, spec, seed: int, source: str, figures) -> None:
    """The final bytes at ``path`` load and give ``policy``'s actions, bit for bit, on 16
    probe observations (``ParityError`` where not)."""
    check = OnnxPolicy(path, robot)
    probe = parity_observations(spec, 16, np.random.default_rng(seed + 1))
    if _max_abs(check(probe).copy(), policy(probe).copy()) != 0.0:
        raise ParityError(f"{source}: the final file gives different actions", figures)


def output_path(source: Path, out, default: Path | None = None) -> Path:
    """The ONNX file to write: ``out``, else ``default``, else the source's name with
    ``.onnx`` beside it.

    Raises:
        ExportError: it would overwrite the source, or its folder does not exist.
    """
    out = (default or source.with_suffix(".onnx")) if out is None else Path(out)
    if out.resolve() == source.resolve():
        raise ExportError(f"{out}: the output would overwrite the source")
    if not out.parent.is_dir():
        raise ExportError(f"{out}: the output folder {out.parent} does not exist")
    return out


def _base_metadata(source: Path, src, exporter_text: str, metadata: dict | None) -> dict:
    """The file's metadata besides the spec and the parity: the source's hash and format, the
    tools' versions, the exporter, the normalizer, and ``metadata``'s entries."""
    base_meta = {
        "source_sha256": sha256_file(source),
        "source_format": src.source_format,
        "tool_versions": json.dumps(tool_versions(), sort_keys=True),
        "exporter": exporter_text,
        **src.extra_hashes,
    }
    if src.normalizer_kind:
        base_meta["observation_normalizer"] = src.normalizer_kind
    base_meta.update(metadata or {})
    return base_meta


def _parity_gate(
    source: Path, policy, module, src, robot: Robot, seed: int, tolerance: float | None
) -> dict:
    """Run the parity runs (:mod:`sim2real.deploy.export.parity`) with the float32 noise floor measured
    beside them (:mod:`sim2real.deploy.export.noise_floor`) and judge them.

    Returns:
        The parity figures (errors, observations compared, replay, floors, tolerances).

    Raises:
        ParityError: an error above its tolerance (actions, or a recurrent state).
    """
    spec = src.spec
    floor = NoiseFloor(module, src.recurrent, spec.obs_dim)
    reference, state_err = None, None
    if src.recurrent:
        static_err, state_err, n_samples = sequence_parity(policy, module, spec, seed, floor)
        reference = RecurrentStepper(module)
    else:
        static_err, n_samples = static_parity(policy, module, spec, PARITY_SAMPLES, seed, floor)
    loop = closed_loop_parity(policy, module, robot, seed=seed, reference=reference, floor=floor)
    figures = {
        "max_abs_error": static_err,
        "samples": n_samples,
        "replay_max_abs_error": loop["max_abs_error"],
        "replay_ticks": loop["ticks"],
        "replay_envs": loop["envs"],
        "replay_mode": loop["mode"],
        "replay_plant_resets": loop["plant_resets"],
    }
    if src.sequence_reference is not None:
        src_err, src_steps = source_sequence_parity(
            policy, src.sequence_reference(), spec, seed, floor
        )
        figures.update(source_max_abs_error=src_err, source_steps=src_steps)
        figures["max_abs_error"] = max(static_err, src_err)
    if state_err is not None:
        figures["state_max_abs_error"] = state_err
    figures.update(floor.tolerances(tolerance))
    if not gate_passed(figures):
        raise ParityError(_parity_message(source, figures), figures)
    figures["passed"] = True
    return figures


def _keep_failed(
    model: onnx.ModelProto, spec: PolicySpec, meta: dict, figures: dict, out: Path
) -> Path:
    """Write the candidate that failed the gate to :func:`failed_path` (its ``parity`` metadata
    with ``"passed": false``); returns the path."""
    figures = {**figures, "passed": False}
    failed = dataclasses.replace(spec, parity=figures)
    set_metadata(model, {"policy_spec": failed.to_json(), **meta, "parity": json.dumps(figures)})
    return atomic_write(failed_path(out), model.SerializeToString())


def export_policy(
    source: str | os.PathLike,
    out: str | os.PathLike | None = None,
    spec: PolicySpec | str | os.PathLike | None = None,
    trust_pickle: bool = False,
    vecnormalize: str | os.PathLike | None = None,
    activation: str | None = None,
    robot: Robot | str | os.PathLike | None = None,
    exporter: str = "torchscript",
    seed: int = 0,
    tolerance: float | None = None,
    metadata: dict[str, str] | None = None,
) -> Path:
    """Export a trained policy to ONNX with its PolicySpec, after the parity gate.

    Args:
        source: Policy file: our checkpoint, TorchScript, SB3 PPO/SAC zip, rsl_rl checkpoint, or a
            pickled nn.Module (see :mod:`sim2real.deploy.export`).
        out: Destination; default ``source`` with the suffix ``.onnx``. Its folder must exist.
        spec: PolicySpec or spec JSON file; required unless the source is our checkpoint.
        trust_pickle: Allow unpickling (pickled modules, VecNormalize pickles). Never needed for
            the other formats.
        vecnormalize: SB3 VecNormalize statistics (``.npz``, ``.json``, or pickle if trusted).
        activation: Override the hidden activation of rebuilt SB3 / rsl_rl networks.
        robot: Robot (or name / path) to check against and replay on; default the spec's robot.
        exporter: 'torchscript' (default) or 'dynamo'.
        seed: Seed of the parity observations, goals and plant noise.
        tolerance: The parity tolerance (max abs error, action units and recurrent state);
            default ``max(TOLERANCE, NOISE_MULTIPLIER x`` the source's float32 noise floor``)``
            (:mod:`sim2real.deploy.export.noise_floor`).
        metadata: More entries of the file's metadata (e.g. ``training_domain``,
            :mod:`sim2real.eval.world.domain`).

    Returns:
        The ONNX file written.

    Raises:
        ExportError: bad input (missing, truncated or corrupt file; unknown format; missing spec;
            wrong input or output size; non-finite weights; spec/robot mismatch; untrusted
            pickle). Nothing is written.
        ParityError: ONNX Runtime and torch disagree by more than the tolerance. Nothing is
            written under ``out``; the candidate is kept under :func:`failed_path`.
    """
    return run_export(
        source, out, spec, trust_pickle, vecnormalize, activation, robot, exporter, seed,
        tolerance, metadata,
    ).path  # fmt: skip
