"""LeRobot's Diffusion Policy folder to ONNX (:func:`export_lerobot_diffusion`), through
lerobot's own classes (the extra ``lerobot``), checked against lerobot's own ``select_action``
with the same noise.

The graph is lerobot's inference path for one call of the network
(``DiffusionModel.generate_actions``, ``lerobot/policies/diffusion/modeling_diffusion.py``,
lerobot 0.4.4): the preprocessor's normalisation of the observation history, the observation
encoder (each camera's centre crop in eval mode, the ResNet backbone with its GroupNorm and
spatial softmax: lerobot's ``_prepare_global_conditioning``, traced), then the whole denoising
loop unrolled: ``num_inference_steps`` calls of the U-Net, each followed by the scheduler's step
(:class:`Sampler`: DDPM's or DDIM's arithmetic, as diffusers 0.35's ``DDPMScheduler.step`` and
``DDIMScheduler.step`` compute it with lerobot's arguments, written out with the scheduler's own
``alphas_cumprod`` and ``timesteps`` as constants), the slice of the contract's ``chunk_size``
actions from index ``n_obs_steps - 1`` of the ``horizon``, and the postprocessor's unnormalisation.

Inputs (float32): ``observation.state`` ``[1, n_obs_steps, state_dim]`` (the robot's units),
``observation.environment_state`` ``[1, n_obs_steps, env_dim]`` when the policy has one, one
``observation.images.<camera>`` ``[1, n_obs_steps, 3, H, W]`` in ``[0, 1]`` RGB per camera
(oldest first: the history :class:`~sim2real.deploy.policy.obs_history.ObservationHistory`
keeps), ``noise`` ``[1, horizon, action_dim]`` (the initial sample, standard normal) and, for
DDPM, ``variance_noise`` ``[steps, 1, horizon, action_dim]`` (the noise each step adds, standard
normal; a step whose timestep is 0 adds none and ignores its slice). DDIM runs with lerobot's
``eta`` 0 (``DDIMScheduler.step``'s default): no noise after the first. Output ``action_chunk``
``[1, chunk_size, action_dim]``.

Parity: the sampling is stochastic, so it is checked with the same noise on both sides
(:func:`select_action_parity`).
"""

from __future__ import annotations

import io
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sim2real.deploy.export.errors import ExportError, _first_line
from sim2real.deploy.export.lerobot_act import (
    LeRobotExport,
    action_scale,
    load_lerobot,
    norm_module,
    random_observation,
    save_checked,
)
from sim2real.deploy.policy.action_chunks import ActionChunks
from sim2real.deploy.policy.obs_history import ObservationHistory
from sim2real.deploy.spec.foreign import lerobot as lr

OPSET = 18
#: Ticks of the select_action parity: with n_action_steps 4, six calls of the sampler.
PARITY_TICKS = 24
#: Max |onnx - lerobot| of an action relative to the action's statistic scale. One U-Net call
#: in float32 through ONNX Runtime differs from torch by ~1e-6 of the normalised sample; the
#: unrolled loop adds one such difference per denoising step (at worst linearly: 100 steps,
#: 1e-4), and the unnormalisation scales it to the action's scale.
PARITY_RTOL = 1e-4
OUTPUT = "action_chunk"
NOISE, VARIANCE_NOISE = "noise", "variance_noise"


def load_policy(folder: Path):
    """lerobot's ``DiffusionPolicy`` and its processors from ``folder``, eval mode, CPU."""
    return load_lerobot(folder, "lerobot.policies.diffusion.modeling_diffusion", "DiffusionPolicy")


@dataclass(frozen=True)
class Sampler:
    """The denoising loop's constants, from lerobot's own scheduler object.

    Attributes:
        kind: ``DDPM`` or ``DDIM``. prediction: ``epsilon`` or ``sample``.
        clip: The x0 clip range (None: no clip).
        timesteps: Per step, its timestep (descending).
        coef: Per step, the float32 scalars of its arithmetic (:meth:`step`).
    """

    kind: str
    prediction: str
    clip: float | None
    timesteps: tuple[int, ...]
    coef: tuple[dict[str, float], ...]

    @classmethod
    def of(cls, model, where: str) -> Sampler:
        """From lerobot's ``DiffusionModel`` (its ``noise_scheduler`` after ``set_timesteps``
        with its ``num_inference_steps``, as ``conditional_sample`` does).

        Raises:
            ExportError: a scheduler configured beyond what lerobot 0.4.4 sets (a variance type
                other than ``fixed_small``, thresholding), named in one line.
        """
        import torch

        sch = model.noise_scheduler
        cfg = sch.config
        kind = type(sch).__name__.replace("Scheduler", "")
        if kind not in ("DDPM", "DDIM"):
            raise ExportError(f"{where}: noise scheduler {kind} is not exported (DDPM or DDIM)")
        if cfg.get("thresholding"):
            raise ExportError(f"{where}: the scheduler's thresholding is not exported (False)")
        if kind == "DDPM" and cfg.get("variance_type") != "fixed_small":
            raise ExportError(
                f"{where}: DDPM variance_type {cfg.get('variance_type')!r} is not exported "
                "(fixed_small, lerobot's)"
            )
        sch.set_timesteps(model.num_inference_steps)
        ts = [int(t) for t in sch.timesteps.tolist()]
        ac = sch.alphas_cumprod.to(torch.float32)
        one = torch.tensor(1.0, dtype=torch.float32)
        coef = []
        for j, t in enumerate(ts):
            a_t = ac[t]
            if kind == "DDPM":  # prev: the next timestep of the list (previous_timestep)
                prev = ts[j + 1] if j + 1 < len(ts) else -1
                a_prev = ac[prev] if prev >= 0 else one
            else:  # DDIM: t - T // S, final_alpha_cumprod below 0
                prev = t - cfg.num_train_timesteps // model.num_inference_steps
                a_prev = ac[prev] if prev >= 0 else sch.final_alpha_cumprod.to(torch.float32)
            b_t, b_prev = 1 - a_t, 1 - a_prev
            c = {"sqrt_a_t": a_t**0.5, "sqrt_b_t": b_t**0.5}
            if kind == "DDPM":
                cur_a = a_t / a_prev
                cur_b = 1 - cur_a
                c["x0"] = (a_prev**0.5 * cur_b) / b_t
                c["x"] = cur_a**0.5 * b_prev / b_t
                var = torch.clamp((1 - a_prev) / (1 - a_t) * cur_b, min=1e-20)
                c["sigma"] = var**0.5 if t > 0 else torch.tensor(0.0)
            else:
                c["sqrt_a_prev"] = a_prev**0.5
                c["sqrt_dir"] = (1 - a_prev) ** 0.5
            coef.append({k: float(v) for k, v in c.items()})
        clip = float(cfg.clip_sample_range) if cfg.clip_sample else None
        return cls(kind, str(cfg.prediction_type), clip, tuple(ts), tuple(coef))

    def step(self, j: int, out, x, z):
        """Step ``j``: the sample before it ``x``, the U-Net's output ``out``, DDPM's noise
        ``z`` (None for DDIM) -> the sample after it (torch tensors, traced)."""
        c = self.coef[j]
        if self.prediction == "epsilon":
            x0 = (x - c["sqrt_b_t"] * out) / c["sqrt_a_t"]
            eps = out
        else:
            x0 = out
            eps = (x - c["sqrt_a_t"] * x0) / c["sqrt_b_t"]  # DDIM: from the unclipped x0
        if self.clip is not None:
            x0 = x0.clamp(-self.clip, self.clip)
        if self.kind == "DDPM":
            prev = c["x0"] * x0 + c["x"] * x
            if self.timesteps[j] > 0:
                prev = prev + c["sigma"] * z
            return prev
        return c["sqrt_a_prev"] * x0 + c["sqrt_dir"] * eps


def graph_module(policy, contract: lr.LeRobotContract, sampler: Sampler):
    """The torch module the graph is traced from: ``(state, [env_state], *images, noise,
    [variance_noise]) -> action_chunk`` (module docstring)."""
    from torch import nn

    keys = [lr.STATE_KEY, *contract.camera_keys, lr.ACTION_KEY]
    if contract.env_state_dim:
        keys.append(lr.ENV_STATE_KEY)
    start = contract.n_obs_steps - 1
    end = start + contract.chunk_size
    crop_shape = contract.diffusion.get("crop_shape")

    def crop(img):
        """torchvision's ``center_crop`` of lerobot's encoder in eval mode, as slices (its
        offsets ``int(round((size - crop) / 2.0))``; the reader refused a crop past the image):
        traced with constant offsets, where torchvision's own rounds a traced size."""
        if not crop_shape:
            return img
        (rows, cols), (h, w) = crop_shape, img.shape[-2:]
        top, left = int(round((int(h) - rows) / 2.0)), int(round((int(w) - cols) / 2.0))
        return img[..., top : top + rows, left : left + cols]

    class Graph(nn.Module):
        def __init__(self):
            super().__init__()
            self.diffusion = policy.diffusion
            self.n = norm_module(contract, keys)

        def forward(self, state, *rest):
            import torch
            from lerobot.utils.constants import OBS_ENV_STATE, OBS_IMAGES, OBS_STATE

            rest = list(rest)
            batch = {OBS_STATE: self.n.norm(lr.STATE_KEY, state)}
            if contract.env_state_dim:
                batch[OBS_ENV_STATE] = self.n.norm(lr.ENV_STATE_KEY, rest.pop(0))
            if contract.cameras:
                images = [crop(self.n.norm(k, rest.pop(0))) for k in contract.camera_keys]
                batch[OBS_IMAGES] = torch.stack(images, dim=-4)  # (1, n_obs, cams, 3, H, W)
            x = rest.pop(0)
            z = rest.pop(0) if sampler.kind == "DDPM" else None
            # lerobot's encoder of the history: images, state and environment state, flattened
            cond = self.diffusion._prepare_global_conditioning(batch)
            for j, t in enumerate(sampler.timesteps):
                tt = torch.full((1,), t, dtype=torch.long)
                out = self.diffusion.unet(x, tt, global_cond=cond)
                x = sampler.step(j, out, x, None if z is None else z[j])
            return self.n.unnorm(lr.ACTION_KEY, x[:, start:end])

    return Graph().eval()


def _rgb_encoders(policy) -> list:
    """lerobot's image encoders of the policy (one, or one per camera)."""
    enc = getattr(policy.diffusion, "rgb_encoder", None)
    if enc is None:
        return []
    return list(enc) if isinstance(enc, (list, tuple)) or hasattr(enc, "__len__") else [enc]


def inputs(contract: lr.LeRobotContract) -> list[tuple[str, tuple[int, ...]]]:
    """The graph's inputs in order: (name, shape)."""
    k = contract.n_obs_steps
    out = [(lr.STATE_KEY, (1, k, contract.state_dim))]
    if contract.env_state_dim:
        out.append((lr.ENV_STATE_KEY, (1, k, contract.env_state_dim)))
    out += [(key, (1, k, *shape)) for key, shape in contract.cameras]
    out += [(name, tuple(s)) for name, s in contract.diffusion["noise_inputs"].items()]
    return out


def _to_onnx(module, contract: lr.LeRobotContract):
    import onnx
    import torch

    names_shapes = inputs(contract)
    args = tuple(torch.zeros(s) for _, s in names_shapes)
    buf = io.BytesIO()
    try:
        with torch.no_grad():
            torch.onnx.export(
                module,
                args,
                buf,
                input_names=[n for n, _ in names_shapes],
                output_names=[OUTPUT],
                opset_version=OPSET,
                dynamo=False,
                do_constant_folding=True,
            )
        model = onnx.load_from_string(buf.getvalue())
        onnx.checker.check_model(model, full_check=True)
    except Exception as e:  # noqa: BLE001 - exporter and checker failures of all kinds
        raise ExportError(
            f"torch.onnx.export (LeRobot Diffusion Policy) failed: {_first_line(e)}"
        ) from None
    return model


def select_action_parity(path, policy, pre, post, contract, ticks: int, seed: int):
    """Max abs and relative error of the ONNX file with :class:`ObservationHistory` and
    :class:`ActionChunks` against lerobot's preprocessor, ``select_action`` and postprocessor
    over ``ticks`` ticks of random observations; and the calls.

    The same noise on both sides: at each network call the initial noise is drawn and given to
    lerobot's ``select_action(batch, noise=...)``; DDPM's per-step noise is what torch's global
    generator, seeded per call, draws inside ``DDPMScheduler.step`` (``randn_tensor``, generator
    None): the same seed draws it first for the graph's ``variance_noise``, then again for
    lerobot's call."""
    import onnxruntime as ort
    import torch

    from sim2real.deploy.policy.lerobot_diffusion_policy import draw_noise, history_shapes

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    hist = ObservationHistory(contract.n_obs_steps, history_shapes(contract))
    chunks = ActionChunks(contract.chunk_size, contract.n_action_steps)
    noise_shapes = contract.diffusion["noise_inputs"]
    sampler_ts = contract.diffusion["timesteps"]
    policy.reset()
    rng = np.random.default_rng(seed)
    scale = action_scale(contract)
    worst_abs = worst_rel = 0.0
    for tick in range(ticks):
        obs = random_observation(contract, rng)
        hist.push(obs)  # env 0
        noise = None
        if chunks.needs_call():
            noise = draw_noise(noise_shapes, rng)
            if VARIANCE_NOISE in noise:  # what DDPMScheduler.step draws, seeded per call
                torch.manual_seed(seed * 1000 + tick)
                z = noise[VARIANCE_NOISE]
                for j, t in enumerate(sampler_ts):
                    z[j] = torch.randn(z.shape[1:]).numpy() if t > 0 else 0.0
                torch.manual_seed(seed * 1000 + tick)
        with torch.no_grad():
            batch = pre({k: torch.from_numpy(v) for k, v in obs.items()})
            given = None if noise is None else torch.from_numpy(noise[NOISE])
            ref = post(policy.select_action(batch, noise=given)).numpy().reshape(-1)

        def predict(noise=noise):
            feed = {k: v[None] for k, v in hist.stacked(0).items()}
            feed.update(noise)
            return sess.run([OUTPUT], feed)[0]

        got = chunks.step(predict)
        err = np.abs(got - ref)
        worst_abs = max(worst_abs, float(err.max()))
        worst_rel = max(worst_rel, float((err / scale).max()))
    return worst_abs, worst_rel, chunks.calls


def export_lerobot_diffusion(
    folder: str | Path,
    out: str | Path | None = None,
    fps: float | None = None,
    robot: str | None = None,
    seed: int = 0,
    ticks: int = PARITY_TICKS,
) -> LeRobotExport:
    """Export the Diffusion Policy of a LeRobot folder to ONNX with its contract, after the
    parity check against lerobot's ``select_action`` with the same noise (module docstring).

    Args and returns: as :func:`sim2real.deploy.export.lerobot_act.export_lerobot_act`.

    Raises:
        ExportError: lerobot absent, the folder unreadable or refused (one line naming the
            ``config.json`` field), no fps.
        ParityError: beyond :data:`PARITY_RTOL`; the candidate is kept as
            ``<stem>.parity-failed.onnx`` and nothing is written at ``out``.
    """

    t0 = time.perf_counter()
    folder = Path(folder)
    try:
        contract = lr.read(folder, fps=fps)
    except lr.LeRobotFormatError as e:
        raise ExportError(str(e)) from None
    if contract.policy_type != "diffusion":
        raise ExportError(
            f"{folder / 'config.json'}: type {contract.policy_type!r}; expected diffusion"
        )
    if contract.fps is None:
        raise ExportError(
            f"{folder}: the policy's rate is unknown (train_config.json has no env.fps); give "
            "--fps, the dataset's meta/info.json fps"
        )
    policy, pre, post = load_policy(folder)
    sampler = Sampler.of(policy.diffusion, str(folder / "config.json"))
    h, a = contract.horizon, contract.action_dim
    noise_inputs = {NOISE: [1, h, a]}
    if sampler.kind == "DDPM":
        noise_inputs[VARIANCE_NOISE] = [len(sampler.timesteps), 1, h, a]
    contract = replace(
        contract,
        diffusion={
            **contract.diffusion,
            "timesteps": list(sampler.timesteps),
            "noise_inputs": noise_inputs,
        },
    )
    encoders = _rgb_encoders(policy)
    crops = [e.do_crop for e in encoders]
    try:  # the graph crops (graph_module's crop); lerobot's own encoder again for the parity
        for e in encoders:
            e.do_crop = False
        model = _to_onnx(graph_module(policy, contract, sampler), contract)
    finally:
        for e, c in zip(encoders, crops, strict=True):
            e.do_crop = c
    return save_checked(
        model,
        contract,
        folder,
        out,
        robot,
        "lerobot_diffusion",
        lambda candidate: select_action_parity(candidate, policy, pre, post, contract, ticks, seed),
        (PARITY_RTOL, "ONNX + action queue vs lerobot's select_action (same noise)"),
        ticks,
        t0,
    )
