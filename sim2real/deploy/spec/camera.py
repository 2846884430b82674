"""A depth camera's image input of a policy (:class:`DepthImageBlock`, a spec's ``images``): which
camera, what it delivers, and how a frame becomes the graph's image input.

A depth frame is (height, width) metres along the camera's optical axis (the z-depth a RealSense
reports, and MuJoCo's linearised depth buffer); 0 or a non-finite value is an invalid pixel
(no stereo match: RealSense writes 0). :func:`preprocess` makes the graph's image of a batch of
frames, in this order (Extreme Parkour's student, ``legged_gym/envs/base/legged_robot.py``
``process_depth_image`` and ``normalize_depth_image``, chengxuxin/extreme-parkour):

1. crop ``(top, bottom, left, right)`` pixels off the edges (Extreme Parkour
   ``crop_depth_image``: ``depth_image[:-2, 4:-4]``, i.e. ``(0, 2, 4, 4)``);
2. an invalid pixel reads ``far`` (our choice, documented: no return is "nothing near");
3. clip to ``[near, far]`` m (Extreme Parkour ``near_clip`` 0, ``far_clip`` 2);
4. resize to ``resize`` (rows, columns) by ``interpolation`` (``bilinear``: half-pixel centres,
   torch's ``F.interpolate(mode="bilinear", align_corners=False)`` without antialiasing;
   ``nearest``); Extreme Parkour's ``resized`` (87, 58) is (columns, rows): ``resize`` (58, 87);
5. normalise: ``centered``, ``(d - near) / (far - near) - 0.5`` in [-0.5, 0.5] (Extreme Parkour's
   ``normalize_depth_image``); ``unit``, ``(d - near) / (far - near)`` in [0, 1].

The graph's input ``input`` is float32 (batch, frames, rows, columns), the oldest frame first
(Extreme Parkour's ``depth_buffer``, ``buffer_len`` 2, appends the newest last); consecutive
entries are ``skip`` delivered frames apart (1: every frame). ``rate`` is the camera's frame rate
the policy was trained with (Extreme Parkour: ``update_interval`` 5 control ticks of 20 ms, 10 Hz),
``latency`` the longest delay from a frame's capture to its use in training (s; Robot Parkour
Learning's Go1 student trains with 0.25-0.30 s, ``go1_field_distill_config.py``).
The camera's own geometry (the MJCF ``<camera>``'s pose and ``fovy``) is the robot description's.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from sim2real.robots.errors import Sim2RealError

#: Extreme Parkour ``LeggedRobotCfg.depth.original`` (106, 60) as (rows, columns).
EXTREME_PARKOUR_SHAPE = (60, 106)
#: Its crop ``[:-2, 4:-4]`` as (top, bottom, left, right) pixels.
EXTREME_PARKOUR_CROP = (0, 2, 4, 4)
#: Its ``resized`` (87, 58) as (rows, columns).
EXTREME_PARKOUR_RESIZE = (58, 87)
#: Its ``near_clip`` and ``far_clip``, m.
EXTREME_PARKOUR_RANGE = (0.0, 2.0)
#: Its ``buffer_len``.
EXTREME_PARKOUR_FRAMES = 2
#: Its depth rate: ``update_interval`` 5 x 0.02 s control period, Hz.
EXTREME_PARKOUR_RATE = 10.0
INTERPOLATIONS = ("bilinear", "nearest")
NORMALISATIONS = ("centered", "unit")


#: The JSON Schema's words for a spec's ``images`` (sim2real/deploy/spec/schema.py).
IMAGES_DESCRIPTION = (
    "Depth image inputs of the graph (sim2real/deploy/spec/camera.py DepthImageBlock: input, "
    "camera, shape, crop, resize, interpolation, near, far, normalisation, frames, skip, rate, "
    "latency); "
    "left out: none."
)


class CameraError(Sim2RealError, ValueError):
    """A camera frame or a camera configuration refused; the message names where and what was
    expected."""


@dataclass(frozen=True)
class DepthImageBlock:
    """One depth image input of a policy (module docstring; JSON: an entry of a spec's
    ``images``).

    Attributes:
        input: The graph's input name (float32 (batch, frames, rows, columns)).
        camera: The camera's name: the MJCF ``<camera name>`` in simulation, the device on
            hardware.
        shape: (rows, columns) of a frame as the camera delivers it.
        crop: (top, bottom, left, right) pixels cut off, each >= 0.
        resize: (rows, columns) of the graph's image.
        interpolation: ``bilinear`` or ``nearest``.
        near, far: The depth clip, m (0 <= near < far).
        normalisation: ``centered`` or ``unit``.
        frames: Frames of history the graph reads (>= 1). skip: Delivered frames between two
            entries of the history (>= 1).
        rate: The camera's frame rate in training, Hz (> 0).
        latency: The longest capture-to-use delay in training, s (>= 0): the runtime's camera
            is stale past the robot's stale limit plus it plus three frame periods.
    """

    input: str = "depth"
    camera: str = "depth_camera"
    shape: tuple[int, int] = EXTREME_PARKOUR_SHAPE
    crop: tuple[int, int, int, int] = EXTREME_PARKOUR_CROP
    resize: tuple[int, int] = EXTREME_PARKOUR_RESIZE
    interpolation: str = "bilinear"
    near: float = EXTREME_PARKOUR_RANGE[0]
    far: float = EXTREME_PARKOUR_RANGE[1]
    normalisation: str = "centered"
    frames: int = EXTREME_PARKOUR_FRAMES
    skip: int = 1
    rate: float = EXTREME_PARKOUR_RATE
    latency: float = 0.0

    @property
    def cropped(self) -> tuple[int, int]:
        """(rows, columns) after the crop."""
        t, b, left, r = self.crop
        return self.shape[0] - t - b, self.shape[1] - left - r

    @property
    def input_shape(self) -> tuple[int, int, int]:
        """The graph input's shape without the batch: (frames, rows, columns)."""
        return (self.frames, *self.resize)

    def problems(self, where: str) -> list[str]:
        """The block's first problem as a one-entry list naming ``where`` and the field, or []."""
        ints = {"shape": self.shape, "crop": self.crop, "resize": self.resize}
        for name, value in ints.items():
            if not all(isinstance(v, int | np.integer) and v >= 0 for v in value):
                return [f"{where}.{name}: expected non-negative integers, got {list(value)}"]
        if min(self.shape) < 1 or min(self.resize) < 1:
            return [f"{where}: shape and resize need at least 1 x 1 pixels"]
        if min(self.cropped) < 1:
            return [
                f"{where}.crop: {list(self.crop)} leaves {list(self.cropped)} of a "
                f"{list(self.shape)} frame; expected at least 1 x 1 pixels"
            ]
        if self.interpolation not in INTERPOLATIONS:
            return [f"{where}.interpolation: '{self.interpolation}', expected {INTERPOLATIONS}"]
        if self.normalisation not in NORMALISATIONS:
            return [f"{where}.normalisation: '{self.normalisation}', expected {NORMALISATIONS}"]
        if not (np.isfinite(self.near) and np.isfinite(self.far) and 0 <= self.near < self.far):
            return [f"{where}: near {self.near} m, far {self.far} m; expected 0 <= near < far"]
        if self.frames < 1 or self.skip < 1:
            return [f"{where}: frames {self.frames}, skip {self.skip}; expected both >= 1"]
        if not (np.isfinite(self.rate) and self.rate > 0):
            return [f"{where}.rate: {self.rate} Hz, expected a positive frame rate"]
        if not (np.isfinite(self.latency) and self.latency >= 0):
            return [f"{where}.latency: {self.latency} s, expected >= 0"]
        if not self.input or not self.camera:
            return [f"{where}: input and camera need a name"]
        return []

    def to_dict(self) -> dict:
        d = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict, where: str = "images[0]") -> DepthImageBlock:
        """A block from its JSON object (missing fields take Extreme Parkour's defaults).

        Raises:
            CameraError: an unknown field, a value of the wrong type or a block
                :meth:`problems` refuses (naming ``where`` and the field).
        """
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise CameraError(f"{where}: unknown field(s) {unknown}")
        kw = {}
        try:
            for k, v in d.items():
                if k in ("shape", "crop", "resize"):
                    if not isinstance(v, list | tuple) or not all(
                        isinstance(x, int) and not isinstance(x, bool) for x in v
                    ):
                        raise TypeError(f"a list of integers, got {v!r}")
                    kw[k] = tuple(v)
                elif k in ("near", "far", "rate", "latency"):
                    if isinstance(v, bool) or not isinstance(v, int | float):
                        raise TypeError(f"a number, got {v!r}")
                    kw[k] = float(v)
                elif k in ("frames", "skip"):
                    if isinstance(v, bool) or not isinstance(v, int):
                        raise TypeError(f"an integer, got {v!r}")
                    kw[k] = v
                else:
                    if not isinstance(v, str):
                        raise TypeError(f"a string, got {v!r}")
                    kw[k] = v
        except TypeError as exc:
            raise CameraError(f"{where}.{k}: expected {exc}") from None
        if len(kw.get("shape", (0, 0))) != 2 or len(kw.get("resize", (0, 0))) != 2:
            raise CameraError(f"{where}: shape and resize are [rows, columns]")
        if len(kw.get("crop", (0,) * 4)) != 4:
            raise CameraError(f"{where}.crop: expected [top, bottom, left, right]")
        block = cls(**kw)
        problems = block.problems(where)
        if problems:
            raise CameraError(problems[0])
        return block


def image_blocks(items: list) -> tuple[DepthImageBlock, ...]:
    """A spec document's ``images`` entries as blocks (:meth:`DepthImageBlock.from_dict`, each
    named ``images[i]``).

    Raises:
        CameraError: an entry refused (naming ``images[i]`` and the field)."""
    return tuple(DepthImageBlock.from_dict(d, f"images[{i}]") for i, d in enumerate(items))


def check_frames(frames, block: DepthImageBlock, envs: int, where: str) -> np.ndarray:
    """The batch of frames ``frames`` as float (envs, rows, columns) m, or a refusal.

    Raises:
        CameraError: a frame that is not floating-point metres (strings, objects, booleans, or
            integer depth units such as a RealSense's uint16 millimetres, which would be read as
            metres) or of another shape than (envs, *block.shape), in one line naming ``where``,
            the camera and what was expected.
    """
    a = np.asarray(frames)
    if a.dtype.kind != "f":
        unit = " (integer depth units: multiply by the device's depth scale)" * (
            a.dtype.kind in "iu"
        )
        raise CameraError(
            f"{where}: camera '{block.camera}' gave a frame of dtype {a.dtype}; expected depth "
            f"as floating-point metres{unit}"
        )
    if a.shape != (envs, *block.shape):
        raise CameraError(
            f"{where}: camera '{block.camera}' gave a frame of shape {a.shape}; expected "
            f"{(envs, *block.shape)} (envs, rows, columns) as the policy's images entry says"
        )
    return a


def _resize_axis(n_in: int, n_out: int, nearest: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Source indices (lo, hi) and weights of hi along one axis, half-pixel centres."""
    scale = n_in / n_out
    src = (np.arange(n_out) + 0.5) * scale - 0.5
    if nearest:  # torch's 'nearest': floor(dst * scale)
        lo = np.minimum(np.floor(np.arange(n_out) * scale).astype(np.intp), n_in - 1)
        return lo, lo, np.zeros(n_out)
    src = np.clip(src, 0.0, n_in - 1)
    lo = np.floor(src).astype(np.intp)
    hi = np.minimum(lo + 1, n_in - 1)
    return lo, hi, src - lo


def resize(images: np.ndarray, shape: tuple[int, int], interpolation: str) -> np.ndarray:
    """(n, rows, columns) images resized to (n, *shape) (module docstring, step 4), float32."""
    nearest = interpolation == "nearest"
    r0, r1, wr = _resize_axis(images.shape[1], shape[0], nearest)
    c0, c1, wc = _resize_axis(images.shape[2], shape[1], nearest)
    top = images[:, r0][:, :, c0] * (1 - wc) + images[:, r0][:, :, c1] * wc
    bottom = images[:, r1][:, :, c0] * (1 - wc) + images[:, r1][:, :, c1] * wc
    return (top * (1 - wr)[:, None] + bottom * wr[:, None]).astype(np.float32)


def preprocess(frames: np.ndarray, block: DepthImageBlock) -> np.ndarray:
    """The graph's image of each frame: (envs, rows, columns) m -> float32 (envs, *resize)
    (module docstring, steps 1-5). ``frames`` as :func:`check_frames` returns them."""
    t, b, left, r = block.crop
    rows, cols = block.shape
    d = np.asarray(frames, dtype=np.float64)[:, t : rows - b, left : cols - r]
    d = np.where(np.isfinite(d) & (d > 0), d, block.far)
    d = np.clip(d, block.near, block.far)
    if d.shape[1:] != tuple(block.resize):
        d = resize(d, block.resize, block.interpolation)
    d = (d - block.near) / (block.far - block.near)
    if block.normalisation == "centered":
        d = d - 0.5
    return d.astype(np.float32)
