"""The camera arm policy's network (:class:`CameraActor`), its contract (:func:`student_spec`) and
its ONNX graph (:func:`export_camera_actor`): arm3 reaching a goal it sees only in a depth image.

The student reads the shipped state policy's proprioceptive blocks without the goal
(``joint_position``, ``joint_velocity``, ``ee_position``: 9 entries) and one depth frame of the
task scene's ``goal_camera`` (``sim2real/robots/arm3/arm3_scene.xml``: a fixed camera 1.3 m in
front of the arm's plane, the goal marker 15 cm in front of the goal), clipped to 1.00-1.22 m
so that the marker is the only thing in range (the arm lies at 1.255 m and beyond).

Network (ours, small enough to train on two CPU cores in minutes): a fixed marker detector
(:class:`MarkerCentroid`: the centroid of the pixels in range, weighted by how near they are,
and their share of the frame; no learned weights, so the camera's image needs no convolution
trained on a CPU) beside the 9 proprioceptive entries into the teacher's actor shape (64, 64,
tanh), the action clipped to [-1, 1] (baked, as the shipped policy's). The MLP learns the
image-to-goal geometry (the camera's pose and field of view) from the teacher's actions.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from sim2real.deploy.spec.camera import DepthImageBlock

#: The image block: ``goal_camera`` at 96 x 72 (rows x columns; 1.9 cm per pixel at the arm's
#: plane), resized to 48 x 36, clipped to 1.00-1.22 m (the marker's 1.09-1.15 m in range, the arm
#: out of it), one frame at 30 Hz (the issue's camera rate), 40 ms latency (ours: a USB camera's
#: capture-to-use delay; the runtime's stale limit for it is 0.05 + 0.04 + 3/30 = 0.19 s).
BLOCK = DepthImageBlock(
    input="depth",
    camera="goal_camera",
    shape=(96, 72),
    crop=(0, 0, 0, 0),
    resize=(48, 36),
    interpolation="bilinear",
    near=1.0,
    far=1.22,
    normalisation="centered",
    frames=1,
    skip=1,
    rate=30.0,
    latency=0.04,
)

#: The teacher's blocks the student reads (the goal's are the camera's to see).
PROPRIOCEPTIVE = ("joint_position", "joint_velocity", "ee_position")


def student_spec(teacher_spec, block: DepthImageBlock = BLOCK):
    """The student's contract: the teacher's (its robot, hash, action and rate) with only the
    :data:`PROPRIOCEPTIVE` blocks and ``block`` as its image input.

    Raises:
        ValueError: the teacher's spec lacks one of the proprioceptive blocks."""
    blocks = tuple(b for b in teacher_spec.observation_blocks if b.name in PROPRIOCEPTIVE)
    if tuple(b.name for b in blocks) != PROPRIOCEPTIVE:
        raise ValueError(f"teacher spec: expected the blocks {PROPRIOCEPTIVE}")
    return replace(teacher_spec, observation_blocks=blocks, images=(block,), parity={})


class MarkerCentroid(nn.Module):
    """(batch, frames, rows, columns) centred depth -> (batch, 3): the newest frame's in-range
    pixels' centroid (x along the columns, y along the rows, each in [-1, 1]) and their weight
    (summed over the pixels, over 10: a marker about 0.2), each pixel weighted by
    ``relu(threshold - depth)`` (the marker reads -0.1 to 0.2, the clip's far end and a hole
    0.5, a noisy pixel of the arm leaking past the clip above 0.4: weight 0). Fixed, not learned:
    a classic marker detector in the graph."""

    def __init__(self, rows: int, columns: int, threshold: float = 0.4):
        super().__init__()
        ys, xs = torch.meshgrid(
            torch.linspace(-1, 1, rows), torch.linspace(-1, 1, columns), indexing="ij"
        )
        self.register_buffer("grid", torch.stack([xs.flatten(), ys.flatten()], 1))  # (rc, 2)
        self.threshold = float(threshold)

    def forward(self, depth: torch.Tensor) -> torch.Tensor:
        b = depth.shape[0]
        w = torch.relu(self.threshold - depth[:, -1].reshape(b, -1))  # (b, rc)
        mass = w.sum(dim=1, keepdim=True)
        centre = torch.matmul(w, self.grid) / (mass + 1e-6)
        return torch.cat([centre, mass / 10.0], dim=1)


class CameraActor(nn.Module):
    """``(obs (batch, obs_dim), depth (batch, frames, rows, columns)) -> action (batch, act)``
    in [-1, 1] (module docstring): :class:`MarkerCentroid`'s 3 features beside the
    proprioceptive vector into an MLP (tanh), the action clipped."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        image: tuple[int, int, int],
        hidden: tuple[int, ...] = (64, 64),
    ):
        super().__init__()
        self.arch = {
            "obs_dim": obs_dim,
            "act_dim": act_dim,
            "image": list(image),
            "hidden": list(hidden),
        }
        self.marker = MarkerCentroid(image[1], image[2])
        layers, width = [], obs_dim + 3
        for h in hidden:
            layers += [nn.Linear(width, h), nn.Tanh()]
            width = h
        self.mlp = nn.Sequential(*layers, nn.Linear(width, act_dim))

    def features(self, obs: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """(batch, obs_dim + 3): the MLP's input."""
        return torch.cat([obs, self.marker(depth)], dim=1)

    def forward(self, obs: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        return torch.clamp(self.mlp(self.features(obs, depth)), -1.0, 1.0)


def save_camera_actor(path: Path, actor: CameraActor, spec, info: dict) -> None:
    """The student's ``.pt``: ``{"format": "sim2real-camera-actor", "architecture",
    "state_dict", "spec" (JSON), "info"}`` (plain data and tensors: ``weights_only`` loads it)."""
    torch.save(
        {
            "format": "sim2real-camera-actor",
            "architecture": actor.arch,
            "state_dict": {k: v.detach().cpu() for k, v in actor.state_dict().items()},
            "spec": spec.to_json(),
            "info": info,
        },
        path,
    )


def load_camera_actor(path: Path):
    """``(actor in eval mode, spec, info)`` of a ``.pt`` written by :func:`save_camera_actor`.

    Raises:
        ValueError: another file (one line naming it and the field)."""
    from sim2real.deploy.spec.policy_spec import PolicySpec

    d = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(d, dict) or d.get("format") != "sim2real-camera-actor":
        raise ValueError(f"{path}: field 'format': expected 'sim2real-camera-actor'")
    a = d["architecture"]
    actor = CameraActor(a["obs_dim"], a["act_dim"], tuple(a["image"]), tuple(a["hidden"]))
    actor.load_state_dict(d["state_dict"])
    return actor.eval(), PolicySpec.from_json(d["spec"], source=str(path)), d["info"]


class _Graph(nn.Module):
    """What the ONNX graph computes (the goal head left out)."""

    def __init__(self, actor: CameraActor):
        super().__init__()
        self.actor = actor

    def forward(self, obs, depth):
        return self.actor(obs, depth)


def export_camera_actor(actor: CameraActor, spec, path: Path, samples: int = 256) -> dict:
    """Write the two-input ONNX graph (inputs ``obs`` (batch, obs_dim) and the block's image
    input, output ``action``; opset 18) with ``spec`` in its ``policy_spec`` metadata, then
    compare ONNX Runtime with torch on ``samples`` random inputs.

    Returns:
        The parity figures (``max_abs_error``, ``samples``), also in the spec written.

    Raises:
        RuntimeError: ONNX Runtime and torch differ by more than 1e-4."""
    import onnx
    import onnxruntime as ort

    from sim2real.deploy.export.graph import set_metadata, tool_versions

    block = spec.images[0]
    actor = actor.eval()
    obs = torch.zeros(1, spec.obs_dim)
    depth = torch.zeros(1, *block.input_shape)
    torch.onnx.export(
        _Graph(actor),
        (obs, depth),
        str(path),
        input_names=["obs", block.input],
        output_names=["action"],
        dynamic_axes={"obs": {0: "batch"}, block.input: {0: "batch"}, "action": {0: "batch"}},
        opset_version=18,
        dynamo=False,
    )
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (samples, spec.obs_dim)).astype(np.float32)
    img = np.full((samples, *block.input_shape), 0.5, np.float32)
    for i in range(samples):  # a marker-sized blob somewhere, with noise
        r, c = rng.integers(2, block.resize[0] - 2), rng.integers(2, block.resize[1] - 2)
        img[i, :, r - 1 : r + 2, c - 1 : c + 2] = rng.uniform(-0.2, 0.0)
    img += rng.normal(0, 0.02, img.shape).astype(np.float32)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = session.run(["action"], {"obs": x, block.input: img})[0]
    with torch.no_grad():
        want = actor(torch.from_numpy(x), torch.from_numpy(img)).numpy()
    error = float(np.abs(got - want).max())
    if not error <= 1e-4:
        raise RuntimeError(f"{path}: ONNX Runtime and torch differ by {error:.2e} (> 1e-4)")
    parity = {"max_abs_error": error, "samples": samples, "tolerance": 1e-4, "passed": True}
    model = onnx.load(str(path))
    baked = {"action_clip": True, "observation_normalizer": False}  # the graph clamps
    written = replace(spec, parity=parity, baked=baked)
    set_metadata(model, {"policy_spec": written.to_json(), **tool_versions()})
    onnx.save(model, str(path))
    return parity
