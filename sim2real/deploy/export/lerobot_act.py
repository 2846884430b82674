"""LeRobot's ACT policy folder to ONNX (:func:`export_lerobot_act`), through lerobot's own classes
(the optional extra ``lerobot``; without it one line names the extra), checked against lerobot's
own ``select_action``.

The graph is the whole of lerobot's inference path for one call of the network: the
preprocessor's normalisation of the state and of every camera image, ``ACT.forward`` (the VAE
encoder off: a zero latent, as ``ACTPolicy.predict_action_chunk`` runs it in eval mode) and the
postprocessor's unnormalisation of the actions. Its inputs are ``observation.state``
``[1, state_dim]`` (the robot's units, as recorded), ``observation.environment_state``
``[1, env_state_dim]`` when the policy has one, and one ``observation.images.<camera>``
``[1, 3, H, W]`` float32 in ``[0, 1]`` RGB per camera; its output ``action_chunk``
``[1, chunk_size, action_dim]``. What the runtime does with the chunk (the action queue or
temporal ensembling) is :class:`~sim2real.deploy.policy.action_chunks.ActionChunks`; the contract
(:class:`~sim2real.deploy.spec.foreign.lerobot.LeRobotContract`, camera keys and shapes, the
statistics, fps, ``chunk_size``, ``n_action_steps``, ``temporal_ensemble_coeff``) is stored in
the file's metadata under ``lerobot_contract``.

Parity: the ONNX graph and :class:`ActionChunks` against lerobot's preprocessor,
``ACTPolicy.select_action`` and postprocessor, tick by tick over ``PARITY_TICKS`` ticks of
random observations (images uniform in ``[0, 1]``, states and actions around their statistics),
so that several chunks and their boundaries are compared.
"""

from __future__ import annotations

import importlib
import io
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim2real.deploy.export.errors import ExportError, ParityError, _first_line
from sim2real.deploy.policy.action_chunks import ActionChunks
from sim2real.deploy.spec.foreign import lerobot as lr

OPSET = 18
#: Ticks of the select_action parity (several chunks of the queue, or every tick's call).
PARITY_TICKS = 24
#: Max |onnx - lerobot| of an action, in the action's own units after unnormalisation, relative
#: to the action's statistic scale (std, or max - min): ResNet-18 and a transformer in float32
#: through two runtimes differ by ~1e-6 of the normalised value.
PARITY_RTOL = 1e-4
OUTPUT = "action_chunk"


@dataclass
class LeRobotExport:
    """What :func:`export_lerobot_act` wrote and measured.

    Attributes:
        path: The ONNX file. contract: Its contract. max_abs_error: Max |onnx - select_action|
        over the parity ticks (action units). max_rel_error: The same over the action's scale.
        ticks: Parity ticks. calls: Network calls in them. seconds: Export time.
    """

    path: Path
    contract: lr.LeRobotContract
    max_abs_error: float
    max_rel_error: float
    ticks: int
    calls: int
    seconds: float


def _lerobot(module: str, name: str):
    try:
        policy_class = getattr(importlib.import_module(module), name)
        from lerobot.policies.factory import make_pre_post_processors
    except ImportError as e:
        raise ExportError(
            f"exporting a LeRobot policy needs lerobot's own classes: pip install "
            f"'sim2real-deploy[lerobot]' (in its own environment; {_first_line(e)})"
        ) from None
    return policy_class, make_pre_post_processors


def load_lerobot(folder: Path, module: str, name: str):
    """lerobot's policy class ``name`` of ``module`` and its processors from ``folder``, eval
    mode, on the CPU (ACT's, Diffusion Policy's).

    Raises:
        ExportError: lerobot is not installed, or it could not load the folder (one line)."""
    policy_class, make_pre_post_processors = _lerobot(module, name)
    try:
        policy = policy_class.from_pretrained(str(folder))
        policy.config.device = "cpu"
        policy.to("cpu").eval()
        pre, post = make_pre_post_processors(
            policy.config,
            pretrained_path=str(folder),
            preprocessor_overrides={"device_processor": {"device": "cpu"}},
        )
    except Exception as e:  # noqa: BLE001 - lerobot's loaders raise many kinds
        raise ExportError(
            f"{folder}: lerobot could not load the policy ({_first_line(e)})"
        ) from None
    return policy, pre, post


def load_policy(folder: Path):
    """lerobot's ``ACTPolicy`` and its processors from ``folder``, eval mode, on the CPU."""
    return load_lerobot(folder, "lerobot.policies.act.modeling_act", "ACTPolicy")


def norm_module(contract: lr.LeRobotContract, keys):
    """A torch module whose ``norm(key, x)`` / ``unnorm(key, y)`` are lerobot's normaliser and
    unnormaliser of each of ``keys`` (the contract's statistics as buffers; module docstring of
    :mod:`sim2real.deploy.spec.foreign.lerobot`)."""
    import torch
    from torch import nn

    def buffers(key: str):
        n = contract.normalization[key]
        if n.mode == "MEAN_STD":
            return n.mode, torch.from_numpy(n.stats["mean"]), torch.from_numpy(n.stats["std"])
        if n.mode == "MIN_MAX":
            return n.mode, torch.from_numpy(n.stats["min"]), torch.from_numpy(n.stats["max"])
        return n.mode, None, None

    class Norm(nn.Module):
        def __init__(self):
            super().__init__()
            self.keys = list(keys)
            self.modes = {}
            self.eps = {}
            for i, key in enumerate(self.keys):
                mode, a, b = buffers(key)
                self.modes[key] = mode
                self.eps[key] = contract.normalization[key].eps
                if a is not None:
                    self.register_buffer(f"a{i}", a.clone())
                    self.register_buffer(f"b{i}", b.clone())

        def _ab(self, key):
            i = self.keys.index(key)
            return getattr(self, f"a{i}"), getattr(self, f"b{i}")

        def norm(self, key, x):
            mode = self.modes[key]
            if mode == "MEAN_STD":
                mean, std = self._ab(key)
                return (x - mean) / (std + self.eps[key])
            if mode == "MIN_MAX":
                lo, hi = self._ab(key)
                d = hi - lo
                d = torch.where(d == 0, torch.full_like(d, self.eps[key]), d)
                return 2 * (x - lo) / d - 1
            return x

        def unnorm(self, key, y):
            mode = self.modes[key]
            if mode == "MEAN_STD":
                mean, std = self._ab(key)
                return y * std + mean
            if mode == "MIN_MAX":
                lo, hi = self._ab(key)
                d = hi - lo
                d = torch.where(d == 0, torch.full_like(d, self.eps[key]), d)
                return (y + 1) / 2 * d + lo
            return y

    return Norm()


def graph_module(policy, contract: lr.LeRobotContract):
    """The torch module the ONNX graph is traced from: ``(state, *images) -> action_chunk``."""
    from torch import nn

    keys = [lr.STATE_KEY, *contract.camera_keys, lr.ACTION_KEY]
    if contract.env_state_dim:
        keys.append(lr.ENV_STATE_KEY)

    class Graph(nn.Module):
        def __init__(self):
            super().__init__()
            self.model = policy.model
            self.n = norm_module(contract, keys)

        def forward(self, state, *rest):
            from lerobot.utils.constants import OBS_ENV_STATE, OBS_IMAGES, OBS_STATE

            batch = {OBS_STATE: self.n.norm(lr.STATE_KEY, state)}
            images = rest
            if contract.env_state_dim:
                batch[OBS_ENV_STATE] = self.n.norm(lr.ENV_STATE_KEY, rest[0])
                images = rest[1:]
            if images:
                batch[OBS_IMAGES] = [
                    self.n.norm(k, img) for k, img in zip(contract.camera_keys, images, strict=True)
                ]
            actions = self.model(batch)[0]
            return self.n.unnorm(lr.ACTION_KEY, actions)

    return Graph().eval()


def _to_onnx(module, contract: lr.LeRobotContract):
    import onnx
    import torch

    state = [torch.zeros(1, contract.state_dim)]
    names = [lr.STATE_KEY]
    if contract.env_state_dim:
        state.append(torch.zeros(1, contract.env_state_dim))
        names.append(lr.ENV_STATE_KEY)
    images = [torch.full((1, *shape), 0.5) for _, shape in contract.cameras]
    names += list(contract.camera_keys)
    buf = io.BytesIO()
    try:
        with torch.no_grad():
            torch.onnx.export(
                module,
                (*state, *images),
                buf,
                input_names=names,
                output_names=[OUTPUT],
                opset_version=OPSET,
                dynamo=False,
                do_constant_folding=True,
            )
        model = onnx.load_from_string(buf.getvalue())
        onnx.checker.check_model(model, full_check=True)
    except Exception as e:  # noqa: BLE001 - exporter and checker failures of all kinds
        raise ExportError(f"torch.onnx.export (LeRobot ACT) failed: {_first_line(e)}") from None
    return model


def random_observation(contract: lr.LeRobotContract, rng: np.random.Generator) -> dict:
    """One observation as lerobot's policies take it (no batch axis): the state around its
    statistics, every image uniform in ``[0, 1]``."""
    obs = {lr.STATE_KEY: _around(contract, lr.STATE_KEY, (contract.state_dim,), rng)}
    if contract.env_state_dim:
        obs[lr.ENV_STATE_KEY] = _around(contract, lr.ENV_STATE_KEY, (contract.env_state_dim,), rng)
    for key, shape in contract.cameras:
        obs[key] = rng.uniform(0.0, 1.0, size=shape).astype(np.float32)
    return obs


def _around(contract, key, shape, rng) -> np.ndarray:
    n = contract.normalization.get(key)
    z = rng.standard_normal(shape).astype(np.float32)
    if n is not None and n.mode == "MEAN_STD":
        return (n.stats["mean"] + z * n.stats["std"]).astype(np.float32)
    if n is not None and n.mode == "MIN_MAX":
        lo, hi = n.stats["min"], n.stats["max"]
        return (lo + (hi - lo) * rng.uniform(0, 1, shape)).astype(np.float32)
    return z


def action_scale(contract: lr.LeRobotContract) -> np.ndarray:
    """Per action entry, the scale its error is measured against (std, or max - min; 1 for
    identity)."""
    n = contract.normalization[lr.ACTION_KEY]
    if n.mode == "MEAN_STD":
        return np.maximum(n.stats["std"], 1e-6)
    if n.mode == "MIN_MAX":
        return np.maximum(n.stats["max"] - n.stats["min"], 1e-6)
    return np.ones(contract.action_dim, dtype=np.float32)


def select_action_parity(
    path: Path, policy, pre, post, contract: lr.LeRobotContract, ticks: int, seed: int
):
    """Max abs and relative error of the ONNX file + :class:`ActionChunks` against lerobot's
    preprocessor, ``select_action`` and postprocessor over ``ticks`` ticks; and the calls."""
    import onnxruntime as ort
    import torch

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    chunks = ActionChunks(
        contract.chunk_size, contract.n_action_steps, contract.temporal_ensemble_coeff
    )
    policy.reset()
    rng = np.random.default_rng(seed)
    scale = action_scale(contract)
    worst_abs = worst_rel = 0.0
    for _ in range(ticks):
        obs = random_observation(contract, rng)
        with torch.no_grad():
            batch = pre({k: torch.from_numpy(v) for k, v in obs.items()})
            ref = post(policy.select_action(batch)).numpy().reshape(-1)

        def predict(obs=obs):
            feed = {k: v[None] for k, v in obs.items()}
            return sess.run([OUTPUT], feed)[0]

        got = chunks.step(predict)
        err = np.abs(got - ref)
        worst_abs = max(worst_abs, float(err.max()))
        worst_rel = max(worst_rel, float((err / scale).max()))
    return worst_abs, worst_rel, chunks.calls


def export_lerobot_act(
    folder: str | Path,
    out: str | Path | None = None,
    fps: float | None = None,
    robot: str | None = None,
    seed: int = 0,
    ticks: int = PARITY_TICKS,
) -> LeRobotExport:
    """Export the ACT policy of a LeRobot folder to ONNX with its contract, after the parity
    check against lerobot's ``select_action``.

    Args:
        folder: The ``pretrained_model`` directory ``lerobot-train`` wrote.
        out: The ONNX file (default ``<folder>/policy.onnx``).
        fps: The policy's rate (Hz), when ``train_config.json`` has no ``env.fps``.
        robot: Our robot the policy drives (stored as ``robot`` metadata), or None.
        seed: Seed of the parity observations. ticks: Parity ticks.

    Raises:
        ExportError: lerobot absent, the folder unreadable, no fps, a state-less policy.
        ParityError: The file disagrees with ``select_action`` beyond :data:`PARITY_RTOL`; the
            candidate is kept as ``<stem>.parity-failed.onnx`` and nothing is written at ``out``.
    """

    t0 = time.perf_counter()
    folder = Path(folder)
    try:
        contract = lr.read(folder, fps=fps)
    except lr.LeRobotFormatError as e:
        raise ExportError(str(e)) from None
    if contract.fps is None:
        raise ExportError(
            f"{folder}: the policy's rate is unknown (train_config.json has no env.fps); give "
            "--fps, the dataset's meta/info.json fps"
        )
    if contract.state_dim == 0:
        raise ExportError(
            f"{folder / 'config.json'}: input_features must hold observation.state (a robot's "
            "policy)"
        )
    policy, pre, post = load_policy(folder)
    model = _to_onnx(graph_module(policy, contract), contract)
    return save_checked(
        model,
        contract,
        folder,
        out,
        robot,
        "lerobot_act",
        lambda candidate: select_action_parity(candidate, policy, pre, post, contract, ticks, seed),
        (PARITY_RTOL, "ONNX + action chunks vs lerobot's select_action"),
        ticks,
        t0,
    )


def save_checked(model, contract, folder, out, robot, source_format, parity, check, ticks, t0):
    """Write ``model`` with its contract's metadata (``source_format``, ``robot``, the tools'
    versions) as a candidate beside ``out`` (default ``folder/policy.onnx``), check it with
    ``parity(candidate) -> (max abs error, max error of the action's scale, calls)`` against
    ``check`` = ``(tolerance, what was compared)``, and keep it as ``out`` only if it passes
    (ACT's and Diffusion Policy's exports).

    Raises:
        ParityError: the error over the tolerance; the candidate kept as
            ``<out>.parity-failed.onnx``, the figures attached.
    """
    import onnx

    from sim2real.deploy.export.graph import set_metadata, tool_versions

    meta = {lr.METADATA_KEY: contract.to_json(), "source_format": source_format}
    if robot is not None:
        meta["robot"] = robot
    meta.update({f"version.{k}": v for k, v in tool_versions().items()})
    set_metadata(model, meta)
    out = Path(out) if out is not None else folder / "policy.onnx"
    out.parent.mkdir(parents=True, exist_ok=True)
    candidate = out.with_name(out.stem + ".candidate.onnx")
    onnx.save(model, str(candidate))
    abs_err, rel_err, calls = parity(candidate)
    figures = {"max_abs_error": abs_err, "max_rel_error": rel_err, "ticks": ticks, "calls": calls}
    rtol, what = check
    if not rel_err <= rtol:
        failed = out.with_name(out.stem + ".parity-failed.onnx")
        candidate.replace(failed)
        raise ParityError(
            f"{out}: {what}: max error {rel_err:.2e} of the action's scale > {rtol:.0e} "
            f"(candidate kept as {failed})",
            figures,
        )
    candidate.replace(out)
    return LeRobotExport(out, contract, abs_err, rel_err, ticks, calls, time.perf_counter() - t0)
