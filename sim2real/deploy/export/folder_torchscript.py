"""A TorchScript policy in a folder whose training stack's contract the toolkit reads: rl_sar ships
``policy/<robot>/<stack>/policy.pt`` (``torch.jit.save`` of its actor; its C++ runs it with
``torch::jit::load`` on one ``(1, n)`` observation) beside ``config.yaml`` and ``../base.yaml``.
``policy-export policy.pt`` (no ``--spec``) writes it as the bare graph that contract is read
beside (:func:`export_folder_torchscript`):

1. the folder's contract (:func:`~sim2real.deploy.spec.foreign.registry.read_folder_contract`, the
   reader of the ONNX file later); the observation's size from its terms (a per-joint term one
   entry per joint of ``joint_mapping``, times the ``observations_history`` frames), the
   action's its joints (:func:`contract_sizes`);
2. ``torch.jit.load`` (:func:`~sim2real.deploy.export.torchscript.load_torchscript`): TorchScript
   is not unpickled, so no ``--trust-pickle``, as for any TorchScript source. Its ``forward`` must
   take one tensor, answer one ``(1, obs_dim)`` observation with one ``(1, act_dim)`` tensor and
   keep no state (:func:`check_module`); anything else (rl_sar's robomimic or himloco exports
   whose input is not the contract's) is refused in one line naming the file and what it takes;
3. the bare graph (:func:`~sim2real.deploy.export.graph.to_bare_onnx`: ``obs`` -> ``actions``,
   batch 1, no metadata but the source's hash, the tool versions and the parity figures: no
   ``policy_spec``, so the folder's contract stays what the runtime reads), written under a
   temporary name beside the source;
4. the parity gate, ONNX Runtime against the module at batch 1 on ``PARITY_SAMPLES`` uniform
   and edge-case observations, within ``NOISE_MULTIPLIER x`` the float32 noise floor
   (:mod:`~sim2real.deploy.export.noise_floor`; of a module that fixes float32, the exported
   graph's in float64: :mod:`~sim2real.deploy.export.graph_twin`); a failure kept aside;
5. the clip the contract names in the ``motion`` metadata (:func:`motion_metadata`); the
   written file read back by the same contract reader (its format and sizes); with
   ``--robot``, loaded by the runtime (:class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy`:
   the contract mapped onto the robot) and replayed ``REPLAY_TICKS`` ticks in closed loop on the
   MuJoCo plant, torch and ONNX compared at every tick. Only then is it moved onto its name.
"""

from __future__ import annotations

import json
import time
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
import torch

from sim2real.deploy.export import torchscript_lstm as lstm_ts
from sim2real.deploy.export.errors import ExportError, ParityError, _first_line
from sim2real.deploy.export.file_kind import zip_kind
from sim2real.deploy.export.graph import OPSET, set_metadata, to_bare_onnx, tool_versions
from sim2real.deploy.export.network import check_finite_tensors
from sim2real.deploy.export.noise_floor import NoiseFloor, _max_abs, gate_passed
from sim2real.deploy.export.parity import PARITY_SAMPLES, closed_loop_parity
from sim2real.deploy.export.pipeline import check_tolerance, failed_path, parity_errors
from sim2real.deploy.export.torchscript import load_torchscript
from sim2real.deploy.spec.foreign.contract import ForeignContract, ForeignFormatError
from sim2real.deploy.spec.foreign.mapping import term_history
from sim2real.deploy.spec.foreign.registry import OnnxFacts, read_contract, read_folder_contract
from sim2real.deploy.spec.history import stacked_dim
from sim2real.robots import Robot
from sim2real.robots.files import atomic_path, atomic_write, sha256_file

#: The least bound of an observation entry in the edge cases (and of an unclipped term's).
EDGE = 1.2


@dataclass(frozen=True)
class FolderExportResult:
    """What :func:`export_folder_torchscript` wrote.

    Attributes:
        path: The ONNX file. contract: The folder's contract, as read from the written file.
        obs_dim, act_dim: The graph's input and output sizes. parity: The gate's figures
            (``max_abs_error``, ``samples``, ``tolerance``, ...; with a robot ``replay_*``).
        seconds: Wall time. exporter: How the graph was written. spec: The spec the runtime
            builds from the contract for the robot (None without one).
    """

    path: Path
    contract: ForeignContract
    obs_dim: int
    act_dim: int
    parity: dict[str, Any]
    seconds: float
    exporter: str
    spec: Any = None


def folder_contract(path: str | Path) -> ForeignContract | None:
    """The contract of the folder of ``path`` when ``path`` is a TorchScript archive that a
    stack's contract files sit beside (rl_sar's ``config.yaml``); None otherwise.

    Raises:
        ExportError: the folder's contract is recognised but cannot be read (naming the file
            and the key).
    """
    path = Path(path)
    if not path.is_file() or not zipfile.is_zipfile(path):
        return None
    if zip_kind(path, ExportError)[0] != "torchscript":
        return None
    try:
        return read_folder_contract(path)
    except ForeignFormatError as exc:
        raise ExportError(str(exc)) from None


def contract_sizes(contract: ForeignContract) -> tuple[int, int, np.ndarray]:
    """``(obs_dim, act_dim, clips)`` the contract gives the graph: the terms' entries (a
    per-joint term one per policy joint) stacked over its history, the joints, and each input
    entry's bound (the term's clip, at least ``EDGE``) for the parity's edge cases.

    Raises:
        ExportError: the joints are not recorded, or a term's size is unknown (one this toolkit
            does not map; naming it and why).
    """
    joints = contract.joint_names or contract.joint_slots
    if not joints:
        raise contract.error("its joints are not recorded, so the action's size is unknown")
    n = len(joints)
    for t in contract.terms:
        if t.kind is None:
            raise ExportError(
                f"{contract.source}: observation '{t.name}': {t.reason}, so the observation's "
                "size is unknown"
            )
    if not contract.terms:
        raise ExportError(f"{contract.source}: no observation terms, so the input is unknown")
    sizes = tuple(n if t.size < 0 else t.size for t in contract.terms)
    bounds = [max(EDGE, t.clip if t.clip is not None else EDGE) for t in contract.terms]
    try:
        history = term_history(contract)
    except ForeignFormatError as exc:
        raise ExportError(str(exc)) from None
    obs_dim = stacked_dim(history, sizes)
    if history is None:
        clips = np.concatenate([np.full(s, b) for s, b in zip(sizes, bounds, strict=True)])
    elif history.layout == "per_frame":
        frame = np.concatenate([np.full(s, b) for s, b in zip(sizes, bounds, strict=True)])
        clips = np.tile(frame, history.length)
    else:
        ticks = history.ticks(len(sizes))
        clips = np.concatenate(
            [np.full(s * k, b) for s, k, b in zip(sizes, ticks, bounds, strict=True)]
        )
    return obs_dim, n, clips


def motion_metadata(motion) -> str:
    """The ``motion`` metadata entry of a contract's clip (:class:`~sim2real.deploy.spec.foreign.
    contract.MotionSource`): JSON ``{"file": name beside the graph, "sha256", "fps" Hz,
    "timing", "columns"}`` (``columns``: the joint of each clip column, the contract's names, so
    that a re-export whose spec is stored, no longer read from the folder, still plays it).
    The clip stays a file beside the graph, as the stack keeps it (a 1,749-frame
    CSV is 0.6 MB: the graph's metadata would carry it twice); its hash tells a changed clip.

    Raises:
        ExportError: the clip is not a readable file (naming the contract's key).
    """
    path = Path(motion.file)
    if not path.is_file():
        raise ExportError(f"{path}: the contract's motion_file is not a file beside the policy")
    return json.dumps(
        {
            "file": path.name,
            "sha256": sha256_file(path),
            "fps": motion.fps,
            "timing": motion.timing,
            "columns": list(motion.columns),
        }
    )


def _describe(contract: ForeignContract, obs_dim: int) -> str:
    """``"rl_sar contract .../config.yaml: (1, 57)"``: where the input size comes from."""
    return f"{contract.format} contract {contract.source}: one observation (1, {obs_dim})"


def check_module(
    net: torch.jit.ScriptModule, path: Path, contract: ForeignContract, obs_dim: int, act_dim: int
) -> None:
    """Refuse a module the contract's one observation does not run: its ``forward`` takes
    anything but one tensor, fails on ``(1, obs_dim)``, returns anything but one float tensor
    ``(1, act_dim)``, or keeps state between calls.

    Raises:
        ExportError: one line naming the file, what its forward takes or returns, and what the
            contract gives it.
    """
    given = _describe(contract, obs_dim)
    try:
        args = list(net.forward.schema.arguments)[1:]  # without self
        takes = ", ".join(f"{a.name}: {a.type}" for a in args) or "nothing"
    except Exception:  # noqa: BLE001 - a module without a scripted forward
        args, takes = None, "no scripted forward"
    if args is None or len(args) != 1 or str(args[0].type) != "Tensor":
        raise ExportError(f"{path}: its forward takes ({takes}); the {given} tensor")
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            y = net(torch.zeros(1, obs_dim))
    except Exception as exc:  # noqa: BLE001 - arbitrary TorchScript
        first = _first_parameter(net)
        raise ExportError(
            f"{path}: its forward ({takes}{first}) fails on the {given}: {_first_line(exc)}"
        ) from None
    if not isinstance(y, torch.Tensor) or not y.is_floating_point():
        raise ExportError(
            f"{path}: its forward returns {type(y).__name__}, expected one float tensor "
            f"(1, {act_dim}) for the {given}"
        )
    if tuple(y.shape) != (1, act_dim):
        raise ExportError(
            f"{path}: its forward returns {tuple(y.shape)} for the {given}; the contract's "
            f"joints need (1, {act_dim})"
        )
    lstm_ts.check_stateless(net, obs_dim, path, ExportError)


def _first_parameter(net: torch.nn.Module) -> str:
    """``"; its first layer takes 45 inputs"`` from the first 2-D parameter ('' without one)."""
    for name, p in net.named_parameters():
        if p.ndim == 2:
            return f"; its first matrix '{name}' takes {p.shape[1]} inputs"
    return ""


def parity_rows(clips: np.ndarray, samples: int, rng: np.random.Generator) -> np.ndarray:
    """float32 (samples + 7 + 2 obs_dim, obs_dim): uniform in [-1.2, 1.2], then 0, +-1, +-1.2,
    +-``clips`` (each entry's bound) and each unit vector and its negative."""
    d = len(clips)
    ones = np.ones(d)
    edges = [np.zeros(d), ones, -ones, EDGE * ones, -EDGE * ones, clips, -clips]
    rows = [rng.uniform(-EDGE, EDGE, (samples, d)), np.stack(edges), np.eye(d), -np.eye(d)]
    return np.concatenate(rows).astype(np.float32)


def _static_parity(model: onnx.ModelProto, net, obs: np.ndarray, floor: NoiseFloor) -> float:
    """Max abs error of ONNX Runtime against ``net`` over ``obs``, one row at a time (batch 1),
    the float32 noise floor measured on the same rows."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(
        model.SerializeToString(), options, providers=["CPUExecutionProvider"]
    )
    ref, got = [], []
    with torch.no_grad():
        for row in obs:
            x = row[None]
            r = net(torch.from_numpy(x)).numpy()
            floor.stateless(x, r)
            ref.append(r)
            got.append(session.run(["actions"], {"obs": x})[0])
    return _max_abs(np.concatenate(got), np.concatenate(ref))


def _row_by_row(net):
    """The torch side of the closed-loop replay: ``net`` on each env's observation in turn."""

    def reference(obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return np.concatenate([net(torch.from_numpy(r[None])).numpy() for r in obs])

    return reference


def export_folder_torchscript(
    source: str | Path,
    out: str | Path | None = None,
    robot: Robot | None = None,
    seed: int = 0,
    tolerance: float | None = None,
    contract: ForeignContract | None = None,
) -> FolderExportResult:
    """Export the TorchScript ``source`` to the bare ONNX graph its folder's contract is read
    beside (module docstring).

    Args:
        source: The TorchScript file (rl_sar's ``policy.pt``).
        out: The ONNX file; default ``source`` with the suffix ``.onnx``. It must be in the
            source's folder (the contract is read beside it).
        robot: The robot to map the contract onto and replay on (None: no replay; the contract
            is mapped when ``deploy-run`` loads the file).
        seed: Seed of the parity observations and the replay.
        tolerance: The parity tolerance (max abs error, action units); default ``max(TOLERANCE,
            NOISE_MULTIPLIER x`` the float32 noise floor``)``.
        contract: The folder's contract when already read (:func:`folder_contract`).

    Returns:
        A :class:`FolderExportResult`.

    Raises:
        ExportError: no contract beside the file, or one that gives no input size; a module its
            contract's observation does not run (one line naming the file and what it takes);
            ``out`` elsewhere or the source; the written file not read by the contract reader
            or, with ``robot``, not loaded for it. Nothing is written.
        ParityError: ONNX Runtime and TorchScript disagree beyond the tolerance; nothing is
            written under ``out``, the candidate is kept under
            :func:`~sim2real.deploy.export.pipeline.failed_path`.
    """
    t0 = time.perf_counter()
    source = Path(source)
    contract, out = _checked_paths(source, out, contract)
    check_tolerance(tolerance)
    obs_dim, act_dim, clips = contract_sizes(contract)
    net = load_torchscript(source)
    net.eval()
    check_finite_tensors(dict(net.state_dict()), str(source))
    check_module(net, source, contract, obs_dim, act_dim)
    model = to_bare_onnx(net, obs_dim)

    obs = parity_rows(clips, PARITY_SAMPLES, np.random.default_rng(seed))
    floor = NoiseFloor(net, False, obs_dim)
    floor.use_graph(model)  # a module whose code fixes float32: the graph's own floor
    err = _static_parity(model, net, obs, floor)
    figures: dict[str, Any] = {"max_abs_error": err, "samples": int(len(obs)), "batch": 1}
    exporter = (
        f"torch.onnx.export(dynamo=False), opset {OPSET} (TorchScript-based), batch 1, "
        f"obs -> actions"
    )
    meta = _metadata(source, contract, exporter)
    model.doc_string = f"policy-export of {source.name} ({contract.format} contract beside it)"
    try:
        spec = _write_checked(
            model, meta, figures, out, source, contract, (net, robot, seed, floor, tolerance)
        )
    except ForeignFormatError as exc:
        raise ExportError(str(exc)) from None
    except OSError as exc:
        raise ExportError(f"{out}: cannot write in {out.parent}: {exc.strerror or exc}") from None
    failed_path(out).unlink(missing_ok=True)
    contract = read_contract(OnnxFacts.of(out, model))
    return FolderExportResult(
        path=out,
        contract=contract,
        obs_dim=obs_dim,
        act_dim=act_dim,
        parity=figures,
        seconds=time.perf_counter() - t0,
        exporter=exporter,
        spec=spec,
    )


def _metadata(source: Path, contract, exporter: str) -> dict[str, str]:
    """The graph's metadata: the source's SHA-256 and format, the tools' versions, the
    exporter, and the motion clip the runtime plays (found beside the file and checked)."""
    meta = {
        "source_sha256": sha256_file(source),
        "source_format": f"torchscript ({contract.format} contract)",
        "tool_versions": json.dumps(tool_versions(), sort_keys=True),
        "exporter": exporter,
    }
    if contract.motion is not None:
        meta["motion"] = motion_metadata(contract.motion)
    return meta


def _checked_paths(source: Path, out, contract):
    """The folder's contract (read beside ``source`` when None) and the output path (default
    ``source`` with ``.onnx``).

    Raises:
        ExportError: no contract beside the file, or ``out`` the source or outside its folder.
    """
    contract = contract or folder_contract(source)
    if contract is None:
        raise ExportError(
            f"{source}: not a TorchScript file with a training stack's contract beside it "
            "(rl_sar's config.yaml and ../base.yaml); pass its spec with --spec FILE.json"
        )
    out = source.with_suffix(".onnx") if out is None else Path(out)
    if out.resolve() == source.resolve():
        raise ExportError(f"{out}: the output would overwrite the source")
    if out.resolve().parent != source.resolve().parent:
        raise ExportError(
            f"{out}: the graph must sit beside {source.name} in {source.parent}, where its "
            f"{contract.format} contract is read"
        )
    return contract, out


def _write_checked(model, meta: dict, figures: dict, out: Path, source: Path, contract, replay):
    """Write ``model`` to ``out`` atomically once the contract reader reads it back as
    ``contract``'s format and, with a robot, its closed-loop replay passes (``figures`` updated
    in place, the parity figures in its metadata); returns the replay's spec or None.

    Args:
        replay: ``(net, robot, seed, floor, tolerance)``; ``robot`` None: no replay.

    Raises:
        ExportError: the written graph is not read as the contract's format.
        ParityError: the gate failed; the candidate is kept under ``failed_path(out)``.
    """
    net, robot, seed, floor, tolerance = replay
    spec = None
    with atomic_path(out) as tmp:
        tmp.write_bytes(model.SerializeToString())
        read = read_contract(OnnxFacts.of(tmp, model))
        if read is None or read.format != contract.format:
            raise ExportError(
                f"{out}: the written graph is not read as a {contract.format} policy "
                f"(read: {None if read is None else read.format})"
            )
        if robot is not None:
            spec, loop = _replay(tmp, net, robot, seed, floor)
            figures.update(loop)
        figures.update(_tolerances(floor, tolerance, robot is not None))
        passed = gate_passed(figures)
        figures["passed"] = passed
        set_metadata(model, {**meta, "parity": json.dumps(figures)})
        if not passed:
            kept = atomic_write(failed_path(out), model.SerializeToString())
            raise ParityError(_parity_message(source, figures, kept), figures)
        tmp.write_bytes(model.SerializeToString())
    return spec


def _replay(path: Path, net, robot: Robot, seed: int, floor: NoiseFloor):
    """Load ``path`` for ``robot`` (the contract mapped onto it) and replay it in closed loop on
    one env (the graph's batch is 1); returns ``(spec, replay figures)``."""
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.deploy.spec.onnx_checks import PolicyLoadError

    try:
        policy = OnnxPolicy(path, robot)
    except PolicyLoadError as exc:
        raise ExportError(f"{path.name} does not load for robot {robot.name}: {exc}") from None
    reference = _row_by_row(net)

    def with_floor(obs: np.ndarray) -> np.ndarray:
        ref = reference(obs)
        floor.stateless(obs, ref, "replay")
        return ref

    loop = closed_loop_parity(policy, net, robot, envs=1, seed=seed, reference=with_floor)
    figures = {
        "replay_max_abs_error": loop["max_abs_error"],
        "replay_ticks": loop["ticks"],
        "replay_envs": loop["envs"],
        "replay_mode": loop["mode"],
        "replay_plant_resets": loop["plant_resets"],
    }
    return policy.spec, figures


def _tolerances(floor: NoiseFloor, tolerance: float | None, replay: bool) -> dict:
    """The gate's tolerances (:meth:`NoiseFloor.tolerances`), the replay's only after one."""
    out = floor.tolerances(tolerance)
    if not replay:
        out = {k: v for k, v in out.items() if not k.startswith("replay_")}
    return out


def _parity_message(source: Path, f: dict, kept: Path) -> str:
    """One line: the errors against their tolerances (:func:`~sim2real.deploy.export.pipeline.
    parity_errors`), and where the candidate is kept."""
    return (
        f"{source}: ONNX Runtime and TorchScript disagree: max abs error {parity_errors(f)}; "
        f"nothing written, the candidate kept as {kept}"
    )
