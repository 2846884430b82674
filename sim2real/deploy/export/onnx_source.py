"""A policy another stack already exported to ONNX, given our contract: ``policy-export
POLICY.onnx --robot ROBOT`` (the contract its stack wrote) or ``policy-export POLICY.onnx --spec
FILE --robot ROBOT`` (a spec written by hand, for a graph whose stack wrote none).

A published policy arrives as an ONNX graph with its contract beside it or in its metadata
(mjlab, holosoma, Unitree's deploy.yaml, Isaac Lab's env.yaml: :mod:`sim2real.deploy.spec.foreign`), its
weights sometimes in a ``policy.onnx.data`` file. :func:`export_onnx_policy` writes one
self-contained file for a robot: the same graph with its weights inlined and our
``policy_spec`` metadata (joint order, observation layout and scales, action mapping, the
policy's PD gains and default pose, the control rate), so the deployment needs neither the
sidecar files nor the training stack's contract. The graph is not rebuilt, so its parity with
the source is exact: both files run in the runtime's :class:`OnnxPolicy` on the parity
observations (:func:`sim2real.deploy.export.parity.parity_observations`) and must give the same actions
to the bit.
The source's own metadata is kept under ``source_metadata`` (JSON).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import onnx

from sim2real.deploy.export.errors import ExportError, ParityError
from sim2real.deploy.export.graph import set_metadata, tool_versions
from sim2real.deploy.export.parity import PARITY_SAMPLES, parity_observations
from sim2real.deploy.export.pipeline import ExportResult, output_path
from sim2real.deploy.policy.onnx_policy import OnnxPolicy
from sim2real.deploy.policy.onnx_spec import METADATA_SPEC
from sim2real.deploy.spec.onnx_checks import PolicyLoadError
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots import Robot
from sim2real.robots.files import atomic_path, sha256_file


def _actions(policy: OnnxPolicy, obs: np.ndarray) -> np.ndarray:
    """The policy's actions for each row of ``obs`` in turn (batch 1: exported graphs often fix
    the batch to 1), float32 (rows, act_dim)."""
    return np.concatenate([policy(row[None]).copy() for row in obs])


def export_onnx_policy(
    source: str | Path,
    robot: Robot,
    out: str | Path | None = None,
    seed: int = 0,
    spec: PolicySpec | str | Path | None = None,
    metadata: dict[str, str] | None = None,
) -> ExportResult:
    """Write ``source`` (an ONNX policy with a foreign contract, or given its spec) for ``robot``
    with our spec.

    Args:
        source: The ONNX file; its external data (``<name>.data``) beside it is read.
        robot: The robot the contract is mapped onto.
        out: The file to write (default ``<stem>.<robot>.onnx`` beside the source).
        seed: Seed of the parity observations.
        spec: The policy's spec (a PolicySpec or a spec JSON file), stored instead of one built
            from the file's own contract (which is then not read).
        metadata: More metadata entries to write (``policy-export --domain``'s
            ``training_domain``); they may not replace ``policy_spec`` or ``parity``.

    Returns:
        An :class:`~sim2real.deploy.export.pipeline.ExportResult`; ``parity`` has ``samples`` and
        ``max_abs_error`` (0.0: the same actions to the bit).

    Raises:
        ExportError: the file does not load for the robot (its contract cannot be read or
            mapped, naming the file and the key; the spec given is invalid or does not describe
            the graph), it already carries our spec, or ``out`` is the source or cannot be
            written.
        ParityError: the written file's actions differ from the source's.
    """
    t0 = time.perf_counter()
    source = Path(source)
    out = output_path(source, out, source.with_name(f"{source.stem}.{robot.name}.onnx"))
    model = onnx.load(str(source))  # external data inlined
    original = {p.key: p.value for p in model.metadata_props}
    if METADATA_SPEC in original:
        raise ExportError(
            f"{source}: already carries its policy_spec (our own export); nothing to add"
        )
    try:
        policy = OnnxPolicy(source, robot, spec=spec)
    except PolicyLoadError as exc:
        raise ExportError(str(exc)) from None
    spec = policy.spec
    obs = parity_observations(spec, PARITY_SAMPLES, np.random.default_rng(seed))
    reference = _actions(policy, obs)
    meta = _metadata(source, policy, original, metadata)
    try:
        with atomic_path(out) as tmp:
            figures = {"samples": int(len(obs)), "max_abs_error": 0.0, "passed": True}
            set_metadata(
                model, {"policy_spec": spec.to_json(), **meta, "parity": json.dumps(figures)}
            )
            model.doc_string = f"{robot.name} policy: {source.name} with its PolicySpec"
            onnx.save(model, str(tmp))
            written = OnnxPolicy(tmp, robot)  # it loads in the runtime with our spec
            error = float(np.max(np.abs(_actions(written, obs) - reference), initial=0.0))
            if error != 0.0:
                figures.update(max_abs_error=error, passed=False)
                raise ParityError(
                    f"{source}: the written graph's actions differ by {error:.3g}", figures
                )
    except OSError as exc:
        raise ExportError(f"{out}: cannot write in {out.parent}: {exc.strerror or exc}") from None
    return ExportResult(
        path=out,
        source_format=meta["source_format"],
        parity=figures,
        seconds=time.perf_counter() - t0,
        spec=spec,
        exporter=meta["exporter"],
    )


def _metadata(source: Path, policy: OnnxPolicy, original: dict, metadata: dict | None) -> dict:
    """The written file's metadata besides the spec and the parity: the source's hash, format
    and own metadata, the tools, the command ranges of its contract (or holosoma's as written),
    the clip its contract names (``motion``: read back by
    :func:`sim2real.deploy.tasks.motion.source.motion_for`, the stored spec naming none),
    and ``metadata``'s entries (never ``policy_spec`` or ``parity``)."""
    given = policy.foreign is None
    meta = {
        "source_sha256": sha256_file(source),
        "source_format": "onnx (a spec given)"
        if given
        else f"onnx ({policy.foreign.format} contract)",
        "tool_versions": json.dumps(tool_versions(), sort_keys=True),
        "exporter": "the source graph, unchanged (weights inlined)",
        "source_metadata": json.dumps(original, sort_keys=True),
    }
    ranges = None if given else policy.foreign.command_ranges
    if ranges is not None:  # the soak's commands (sim2real.eval.world.domain.contract_commands)
        names = {"vx": "lin_vel_x", "vy": "lin_vel_y", "yaw_rate": "ang_vel_z"}
        meta["command_ranges"] = json.dumps({names[k]: list(v) for k, v in ranges.items()})
    elif "command_ranges" in original:  # holosoma's, kept as it wrote it
        meta["command_ranges"] = original["command_ranges"]
    motion = None if given else policy.foreign.motion
    if motion is not None:  # the clip: the written spec is stored, the contract no longer read
        from sim2real.deploy.export.folder_torchscript import motion_metadata

        meta["motion"] = motion_metadata(motion)
    elif "motion" in original:
        meta["motion"] = original["motion"]
    meta.update({k: v for k, v in (metadata or {}).items() if k not in ("policy_spec", "parity")})
    return meta
