"""Shared pieces of the benchmark suite: the benchmark policy, histograms, machine facts, JSON.

Every latency here goes through :class:`sim2real.deploy.core.latency.LatencyHistogram` (1 us bins up to
20 ms, percentiles exact to the bin width, reported at the bin centre), the same histogram the
runtime keeps of its own stages, so that figures of the full runtime and of the bare loop are
comparable.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import sim2real.policies
from sim2real.deploy.core.latency import BIN_NS, BINS, LatencyHistogram
from sim2real.robots.files import atomic_write

#: The shipped policies' folder (``sim2real/policies``, package data: in a checkout and in an
#: installed wheel alike).
POLICIES = Path(sim2real.policies.__file__).resolve().parent
#: Hidden layers and seed of the benchmark policy (a deterministic MLPActor, ELU).
POLICY_HIDDEN = (64, 64)
POLICY_SEED = 0


@dataclass(frozen=True)
class BenchPolicy:
    """The benchmark policy of one robot.

    Attributes:
        robot: The :class:`robots.Robot`.
        spec: Its PolicySpec (``PolicySpec.for_robot(robot)``: default blocks, default control
            mode: arm3 velocity, arm6 position).
        actor: The torch :class:`~sim2real.deploy.policy.mlp_checkpoint.MLPActor` (eval mode), for the bare
        loop; None for a shipped policy (a legged robot: no bare loop).
        path: The ONNX file exported from it by ``sim2real.deploy.export.run_export`` (parity gate passed).
        export_seconds: Wall time of the export, s.
        given: A legged robot's ONNX policy given to the bench (``--legged-policy``), not
            exported from a shipped one.
    """

    robot: Any
    spec: Any
    actor: Any
    path: Path
    export_seconds: float
    given: bool = False


#: Spread of the random part of the benchmark policy's action, in physical units: rad around the
#: holding target (position mode), rad/s (velocity mode), fraction of the effort limit (torque).
WIGGLE = {"position": 0.15, "velocity": 0.5, "torque": 0.05}
#: Velocity mode: rate (1/s) of the proportional pull toward the home pose.
HOME_PULL = 2.0
#: Velocity mode: bias that keeps the pass-through units in ELU's identity region (|obs| <= clip).
_SHIFT = 6.0


def tame_actor(actor, spec, robot, seed: int = POLICY_SEED) -> None:
    """Make a seeded random MLPActor behave like a policy that holds its robot near home.

    A purely random MLP parks the arm against a limit: it can drive arm6 into an over-temperature
    safe stop (a high-torque pose held) and hold arm3 at its workspace edge with a rejected target
    on every tick, so a benchmark would measure the runtime in a regime a trained policy never sees.
    In place, on ``actor``'s three Linear layers:

    - the random part (the network as seeded) is re-centred and scaled, per action, to a spread
      of ``WIGGLE`` physical units over observations uniform in [-1, 1] (it still depends on the
      whole observation, goals included, so the arm moves when the goal changes);
    - position mode: the output bias holds the home pose (``(home - offset) / scale``);
    - velocity mode: ``n`` units of each hidden layer pass the normalized joint positions through
      ELU's identity region (bias ``_SHIFT``) and the output adds ``HOME_PULL * (home - q)``
      (joints covered by the ``joint_position`` block only);
    - torque mode: the random part only.

    Args:
        actor: An MLPActor with two hidden layers, each at least ``n_joints`` wide.
        spec: Its PolicySpec. robot: The robot. seed: Seed of the probe observations.
    """
    import torch
    from torch import nn

    l1, l2, l3 = [m for m in actor.net if isinstance(m, nn.Linear)]
    a = spec.action
    scale = np.asarray(a.scale, dtype=np.float64)
    home = np.asarray(robot.home, dtype=np.float64)
    pull = a.mode == "velocity" and "joint_position" in spec.block_slices()
    with torch.no_grad():
        if pull:
            block = next(b for b in spec.observation_blocks if b.name == "joint_position")
            start = spec.block_slices()["joint_position"].start
            u = list(range(l1.out_features - len(block.joints), l1.out_features))
            v = list(range(l2.out_features - len(block.joints), l2.out_features))
            l2.weight[:, u] = 0.0
            l3.weight[:, v] = 0.0
            for k in range(len(block.joints)):
                l1.weight[u[k]] = 0.0
                l1.weight[u[k], start + k] = 1.0
                l1.bias[u[k]] = _SHIFT
                l2.weight[v[k]] = 0.0
                l2.weight[v[k], u[k]] = 1.0
                l2.bias[v[k]] = 0.0
        probe = np.random.default_rng(seed).uniform(-1, 1, (4096, spec.obs_dim))
        out = actor(torch.as_tensor(probe, dtype=torch.float32)).double().numpy()
        spread = WIGGLE[a.mode] * (robot.effort_limit if a.mode == "torque" else 1.0) / scale
        gain = spread / np.maximum(out.std(axis=0), 1e-9)
        bias = (l3.bias.double().numpy() - out.mean(axis=0)) * gain
        l3.weight.mul_(torch.as_tensor(gain, dtype=torch.float32)[:, None])
        if a.mode == "position":
            bias += (home - np.asarray(a.offset)) / scale
        if pull:
            for k, j in enumerate(block.joints):
                k_gain = HOME_PULL * block.scale[k] / scale[j]  # action per normalized rad
                l3.weight[j, v[k]] = -k_gain
                bias[j] += k_gain * (_SHIFT + (home[j] - block.offset[k]) / block.scale[k])
        l3.bias.copy_(torch.as_tensor(bias, dtype=torch.float32))


#: A legged robot's benchmark command (``--command``: vx, vy, wz in m/s, m/s, rad/s): a random
#: policy cannot walk, so a legged robot runs its shipped policy walking forward.
LEGGED_COMMAND = "0.5,0,0"


def is_legged(robot) -> bool:
    """Whether ``robot`` is a legged kind (:func:`sim2real.deploy.robot_kind.robot_kind`)."""
    from sim2real.deploy.kinds import robot_kind

    return robot_kind(robot).floating_base


def make_policy(
    robot, folder: Path, seed: int = POLICY_SEED, onnx: Path | None = None
) -> BenchPolicy:
    """The benchmark policy of ``robot``: :func:`make_random_policy` for an arm, the shipped
    policy (``sim2real/policies/ROBOT.pt`` exported to ``folder``, ``actor`` None: no bare loop)
    for a legged robot, which a random policy would lay down, or the ONNX policy ``onnx`` given
    for it (an imported robot's, ``policy-export``'s file: ``export_seconds`` 0).

    Raises:
        FileNotFoundError: a legged robot without a shipped policy nor ``onnx``.
        sim2real.deploy.export.ExportError, sim2real.deploy.export.ParityError: the export failed.
        sim2real.deploy.policy.onnx_policy.PolicyLoadError: ``onnx`` does not load for ``robot``.
    """
    if not is_legged(robot):
        return make_random_policy(robot, folder, seed)
    from sim2real.deploy.export import export_policy
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy

    if onnx is not None:
        path = Path(onnx).resolve()
        return BenchPolicy(robot, OnnxPolicy(path, robot).spec, None, path, 0.0, given=True)

    src = POLICIES / f"{robot.name}.pt"
    if not src.is_file():
        raise FileNotFoundError(f"bench: legged robot {robot.name} has no shipped policy {src}")
    t = time.perf_counter()
    path = export_policy(src, out=folder / f"{robot.name}.onnx")
    seconds = time.perf_counter() - t
    return BenchPolicy(robot, OnnxPolicy(path, robot).spec, None, path, seconds)


def make_random_policy(robot, folder: Path, seed: int = POLICY_SEED) -> BenchPolicy:
    """Build the deterministic benchmark policy of ``robot`` and export it to ONNX in ``folder``.

    An :class:`~sim2real.deploy.policy.mlp_checkpoint.MLPActor` (obs_dim of the default PolicySpec -> 64 ->
    64 -> n_joints, ELU, no normalizer) with weights from ``torch.manual_seed(seed)``, tamed by
    :func:`tame_actor` (small actions around holding the home pose), saved with
    ``save_checkpoint`` and exported with ``run_export`` (the ``policy-export`` code path: parity
    gate, metadata), exactly as a trained policy would be.

    Raises:
        sim2real.deploy.export.ExportError, sim2real.deploy.export.ParityError: the export failed.
    """
    import torch

    from sim2real.deploy.export import run_export
    from sim2real.deploy.policy.mlp_checkpoint import MLPActor, save_checkpoint
    from sim2real.deploy.spec.policy_spec import PolicySpec

    spec = PolicySpec.for_robot(robot)
    torch.manual_seed(seed)
    actor = MLPActor(spec.obs_dim, spec.act_dim, hidden=POLICY_HIDDEN, activation="elu").eval()
    tame_actor(actor, spec, robot, seed)
    src = save_checkpoint(folder / f"bench_{robot.name}.pt", actor, spec, info={"seed": seed})
    t = time.perf_counter()
    result = run_export(src, out=folder / f"bench_{robot.name}.onnx")
    return BenchPolicy(robot, spec, actor, result.path, time.perf_counter() - t)


def policy_info(p: BenchPolicy) -> dict[str, Any]:
    """JSON description of a benchmark policy."""
    common = {
        "obs_dim": p.spec.obs_dim,
        "act_dim": p.spec.act_dim,
        "observation_blocks": [b.name for b in p.spec.observation_blocks],
        "control_mode": p.spec.action.mode,
        "control_rate_hz": p.spec.control_rate,
        "export_s": p.export_seconds,
    }
    if p.actor is None:
        source = f"the shipped policy sim2real/policies/{p.robot.name}.pt"
        if p.given:
            source = f"the policy {p.path} (--legged-policy)"
        return {"kind": f"{source}, command {LEGGED_COMMAND}", **common}
    return {
        "kind": "MLPActor, seeded random weights tamed to hold near home (bench.common.tame_actor)",
        "hidden": list(POLICY_HIDDEN),
        "activation": "elu",
        "seed": POLICY_SEED,
        **common,
    }


# ---------------------------------------------------------------------- histograms
def histogram(samples_ns: np.ndarray) -> LatencyHistogram:
    """A one-stage :class:`LatencyHistogram` of ``samples_ns`` (int ns), filled in bulk."""
    h = LatencyHistogram()
    ns = np.asarray(samples_ns, dtype=np.int64)
    if ns.size:
        idx = np.minimum(np.maximum(ns, 0) // BIN_NS, BINS)
        h.counts[0] = np.bincount(idx, minlength=BINS + 1)
        h.max_ns[0] = ns.max()
    return h


def summary(h: LatencyHistogram, stage: int = 0) -> dict[str, float]:
    """``LatencyHistogram.summary`` plus the mean (us, from the bin centres; overflow bin at the
    maximum)."""
    s = h.summary(stage)
    c = h.counts[stage]
    total = c.sum()
    if total:
        centres = (np.arange(BINS + 1) + 0.5) * BIN_NS / 1e3
        centres[BINS] = h.max_ns[stage] / 1e3
        s["mean_us"] = float((c * centres).sum() / total)
    else:
        s["mean_us"] = float("nan")
    return s


def clear(h: LatencyHistogram) -> None:
    """Empty a histogram in place (after a warm-up)."""
    h.counts[:] = 0
    h.max_ns[:] = 0


def ratio(a: float, b: float) -> float:
    """``a / b``, NaN when ``b`` is not a positive finite number."""
    return float(a / b) if np.isfinite(b) and b > 0 else float("nan")


@contextlib.contextmanager
def environment(**values: str) -> Iterator[None]:
    """Set these environment variables of this process (name=value) for the ``with`` block, for
    it and the child processes it starts there; restore each (or remove one that was not set)
    however the block ends."""
    saved = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, old in saved.items():
            if old is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = old


# ---------------------------------------------------------------------- machine, JSON
def machine_info() -> dict[str, Any]:
    """Platform, CPU count, load average and library versions (numpy, mujoco, onnxruntime, pin,
    ruckig, torch)."""
    from importlib.metadata import PackageNotFoundError, version

    versions = {}
    for pkg in ("numpy", "mujoco", "onnxruntime", "pin", "ruckig", "filterpy", "torch"):
        try:
            versions[pkg] = version(pkg)
        except PackageNotFoundError:
            versions[pkg] = None
    try:
        load = list(os.getloadavg())
    except OSError:
        load = None
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "load_average_at_start": load,
        "versions": versions,
    }


def json_safe(obj: Any) -> Any:
    """JSON-safe copy: NaN and inf become None, numpy scalars become Python numbers."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def write_json_atomic(path: Path, data: dict[str, Any]) -> Path:
    """Write ``data`` as JSON to ``path`` atomically (temporary file in the same folder, fsync,
    ``os.replace``); non-finite floats are written as null.

    Raises:
        OSError: the folder is not writable.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write(path, json.dumps(json_safe(data), indent=2, allow_nan=False) + "\n")
