"""A camera's image input of a policy (a spec's ``images``: which camera, what it delivers, how a
frame becomes the graph's input): a depth camera's (:class:`DepthImageBlock`) or, JSON ``"kind":
"rgb"``, a colour camera's (:class:`RgbImageBlock`, whose docstring gives its preprocessing); what
both share (:class:`ImageGeometry`) is written once, each block's ``input_shape`` the one source
of truth of its graph input's layout.

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
#: An RGB block's ``normalisation``, ``channel_order`` and ``layout`` choices.
RGB_NORMALISATIONS = ("unit", "mean_std")
CHANNEL_ORDERS = ("RGB", "BGR")
LAYOUTS = ("CHW", "HWC")
#: ImageNet's per-channel mean and standard deviation (R, G, B) of a [0, 1] image: torchvision's
#: ``ResNet18_Weights.IMAGENET1K_V1`` transforms (the backbone weights LeRobot's ACT
#: configuration names).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
#: The cameras of LeRobot's SO-100 examples (huggingface/lerobot
#: ``examples/tutorial/async-inf/robot_client.py``: ``OpenCVCameraConfig(..., width=640,
#: height=480, fps=30)``), a UVC webcam's usual default profile.
LEROBOT_SHAPE = (480, 640)
LEROBOT_FPS = 30.0


#: The JSON Schema's words for a spec's ``images`` (sim2real/deploy/spec/schema.py).
IMAGES_DESCRIPTION = (
    "Camera image inputs of the graph (sim2real/deploy/spec/camera.py). A depth camera's "
    "(DepthImageBlock: input, camera, shape, crop, resize, interpolation, near, far, "
    'normalisation, frames, skip, rate, latency) or, with "kind": "rgb", a colour camera\'s '
    "(RgbImageBlock: input, camera, shape, crop, resize, interpolation, channel_order, layout, "
    "normalisation, mean, std, frames, skip, rate, latency); "
    "left out: none."
)


class CameraError(Sim2RealError, ValueError):
    """A camera frame or a camera configuration refused; the message names where and what was
    expected."""


#: Each field's JSON type, shared by both blocks (:meth:`ImageGeometry.from_dict`).
_INT_LISTS = ("shape", "crop", "resize")
_FLOAT_LISTS = ("mean", "std")
_FLOATS = ("near", "far", "rate", "latency")
_INTS = ("frames", "skip")


class ImageGeometry:
    """What a depth and an RGB block share (no fields of its own: each block declares them):
    ``input``, ``camera``, ``shape`` (rows, columns), ``crop`` (top, bottom, left, right),
    ``resize`` (rows, columns; at most the cropped frame's: a resize bigger than the render is
    refused), ``interpolation``, ``frames``, ``skip``, ``rate`` (Hz) and
    ``latency`` (s), their checks and the JSON reading."""

    #: ``kind`` in the JSON (a depth block writes none: it is the default)
    kind = "depth"

    @property
    def cropped(self) -> tuple[int, int]:
        """(rows, columns) after the crop."""
        t, b, left, r = self.crop
        return self.shape[0] - t - b, self.shape[1] - left - r

    @property
    def frame_shape(self) -> tuple[int, ...]:
        """A delivered frame's shape without the env axis: (rows, columns) of depth."""
        return tuple(self.shape)

    def geometry_problems(self, where: str) -> list[str]:
        """The first problem of the shared fields as a one-entry list, or []."""
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
        if self.resize[0] > self.cropped[0] or self.resize[1] > self.cropped[1]:
            return [
                f"{where}.resize: {list(self.resize)} is bigger than the cropped render "
                f"{list(self.cropped)}; expected at most {list(self.cropped)} (rows, columns)"
            ]
        if self.interpolation not in INTERPOLATIONS:
            return [f"{where}.interpolation: '{self.interpolation}', expected {INTERPOLATIONS}"]
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
        d = {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}
        return d if self.kind == "depth" else {"kind": self.kind, **d}

    @classmethod
    def from_dict(cls, d: dict, where: str = "images[0]"):
        """A block from its JSON object (missing fields take the block's defaults; a ``kind``
        key, when there, must be the block's).

        Raises:
            CameraError: an unknown field, a value of the wrong type or a block
                :meth:`problems` refuses (naming ``where`` and the field).
        """
        d = dict(d)
        if d.pop("kind", cls.kind) != cls.kind:
            raise CameraError(f"{where}.kind: expected '{cls.kind}'")
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise CameraError(f"{where}: unknown field(s) {unknown}")
        kw = {}
        try:
            for k, v in d.items():
                if k in _INT_LISTS:
                    if not isinstance(v, list | tuple) or not all(
                        isinstance(x, int) and not isinstance(x, bool) for x in v
                    ):
                        raise TypeError(f"a list of integers, got {v!r}")
                    kw[k] = tuple(v)
                elif k in _FLOAT_LISTS:
                    if not isinstance(v, list | tuple) or not all(
                        isinstance(x, int | float) and not isinstance(x, bool) for x in v
                    ):
                        raise TypeError(f"a list of numbers, got {v!r}")
                    kw[k] = tuple(float(x) for x in v)
                elif k in _FLOATS:
                    if isinstance(v, bool) or not isinstance(v, int | float):
                        raise TypeError(f"a number, got {v!r}")
                    kw[k] = float(v)
                elif k in _INTS:
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


@dataclass(frozen=True)
class DepthImageBlock(ImageGeometry):
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
    def input_shape(self) -> tuple[int, int, int]:
        """The graph input's shape without the batch: (frames, rows, columns)."""
        return (self.frames, *self.resize)

    @property
    def layout_names(self) -> str:
        """The graph input's axes, for messages."""
        return "[batch, frames, rows, columns]"

    def problems(self, where: str) -> list[str]:
        """The block's first problem as a one-entry list naming ``where`` and the field, or []."""
        problems = self.geometry_problems(where)
        if problems:
            return problems
        if self.normalisation not in NORMALISATIONS:
            return [f"{where}.normalisation: '{self.normalisation}', expected {NORMALISATIONS}"]
        if not (np.isfinite(self.near) and np.isfinite(self.far) and 0 <= self.near < self.far):
            return [f"{where}: near {self.near} m, far {self.far} m; expected 0 <= near < far"]
        return []


@dataclass(frozen=True)
class RgbImageBlock(ImageGeometry):
    """One colour image input of a policy (JSON: an entry of a spec's ``images`` with ``"kind":
    "rgb"``). Defaults: the cameras of LeRobot's SO-100 examples (640 x 480 at 30 fps;
    ``LEROBOT_SHAPE``), one frame, CHW RGB in [0, 1].

    A frame is (height, width, 3) uint8 in R, G, B order (a driver delivering OpenCV's BGR flips
    it first). :func:`preprocess`: crop; resize (as a depth block's, each channel); scale to
    [0, 1] (``x / 255``, torchvision's ``to_tensor`` and LeRobot's image features);
    ``normalisation`` ``mean_std``: ``(x - mean) / std`` per channel (the graph's channel order;
    ImageNet's by default, the statistics of torchvision's ImageNet ResNet-18 weights that
    LeRobot's ACT configuration names as its backbone's ``pretrained_backbone_weights``; a LeRobot
    policy's own dataset statistics, per channel, go in ``mean`` and ``std``); then the graph's
    ``channel_order`` (``BGR`` flips the channels) and ``layout``: ``CHW`` gives float32 (batch,
    frames, 3, rows, columns), ``HWC`` (batch, frames, rows, columns, 3).

    Attributes:
        input: The graph's input name: float32 (batch, frames, 3, rows, columns) with ``CHW``,
            (batch, frames, rows, columns, 3) with ``HWC``.
        camera: The MJCF ``<camera name>`` in simulation, the device on hardware.
        shape: (rows, columns) of a frame as the camera delivers it (uint8 RGB).
        crop: (top, bottom, left, right) pixels cut off. resize: (rows, columns) of the graph's
            image (at most the cropped frame's, as a depth block's: a policy is not fed
            invented pixels).
        interpolation: ``bilinear`` or ``nearest``.
        channel_order: ``RGB`` or ``BGR`` (the graph's). layout: ``CHW`` or ``HWC``.
        normalisation: ``unit`` (x / 255) or ``mean_std`` (then ``(x - mean) / std``).
        mean, std: Per channel, of a [0, 1] image, in the graph's channel order (ImageNet's).
        frames, skip, rate, latency: As a depth block's.
    """

    kind = "rgb"
    input: str = "rgb"
    camera: str = "rgb_camera"
    shape: tuple[int, int] = LEROBOT_SHAPE
    crop: tuple[int, int, int, int] = (0, 0, 0, 0)
    resize: tuple[int, int] = LEROBOT_SHAPE
    interpolation: str = "bilinear"
    channel_order: str = "RGB"
    layout: str = "CHW"
    normalisation: str = "unit"
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    frames: int = 1
    skip: int = 1
    rate: float = LEROBOT_FPS
    latency: float = 0.0

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """A delivered frame's shape without the env axis: (rows, columns, 3)."""
        return (*self.shape, 3)

    @property
    def input_shape(self) -> tuple[int, int, int, int]:
        """The graph input's shape without the batch: (frames, 3, rows, columns) with ``CHW``,
        (frames, rows, columns, 3) with ``HWC``."""
        if self.layout == "HWC":
            return (self.frames, *self.resize, 3)
        return (self.frames, 3, *self.resize)

    @property
    def layout_names(self) -> str:
        """The graph input's axes, for messages."""
        if self.layout == "HWC":
            return "[batch, frames, rows, columns, 3]"
        return "[batch, frames, 3, rows, columns]"

    def problems(self, where: str) -> list[str]:
        """The block's first problem as a one-entry list naming ``where`` and the field, or []."""
        problems = self.geometry_problems(where)
        if problems:
            return problems
        choices = {
            "channel_order": CHANNEL_ORDERS,
            "layout": LAYOUTS,
            "normalisation": RGB_NORMALISATIONS,
        }
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                return [f"{where}.{name}: '{getattr(self, name)}', expected one of {allowed}"]
        if len(self.mean) != 3 or not all(np.isfinite(self.mean)):
            return [f"{where}.mean: {list(self.mean)}, expected 3 finite numbers (per channel)"]
        if len(self.std) != 3 or not all(np.isfinite(v) and v > 0 for v in self.std):
            return [f"{where}.std: {list(self.std)}, expected 3 positive numbers (per channel)"]
        return []


#: A block of each ``kind`` (JSON ``images[i].kind``; absent: depth).
IMAGE_KINDS = {"depth": DepthImageBlock, "rgb": RgbImageBlock}


def image_blocks(items: list) -> tuple[DepthImageBlock | RgbImageBlock, ...]:
    """A spec document's ``images`` entries as blocks (each by its ``kind``, default ``depth``;
    :meth:`ImageGeometry.from_dict`, each named ``images[i]``).

    Raises:
        CameraError: an entry refused (naming ``images[i]`` and the field)."""
    blocks = []
    for i, d in enumerate(items):
        where = f"images[{i}]"
        if not isinstance(d, dict):
            raise CameraError(f"{where}: expected a table, got {d!r}")
        kind = d.get("kind", "depth")
        if kind not in IMAGE_KINDS:
            raise CameraError(f"{where}.kind: '{kind}', expected one of {tuple(IMAGE_KINDS)}")
        blocks.append(IMAGE_KINDS[kind].from_dict(d, where))
    return tuple(blocks)


def check_frames(frames, block, envs: int, where: str) -> np.ndarray:
    """The batch of frames ``frames`` as the block reads them, or a refusal: a depth block's
    float (envs, rows, columns) m; an RGB block's uint8 (envs, rows, columns, 3).

    Raises:
        CameraError: a depth frame that is not floating-point metres (strings, objects,
            booleans, or integer depth units such as a RealSense's uint16 millimetres, which
            would be read as metres), an RGB frame that is not uint8, or a frame of another shape
            than (envs, *block.frame_shape), in one line naming ``where``, the camera and what
            was expected.
    """
    a = np.asarray(frames)
    if block.kind == "rgb":
        if a.dtype != np.uint8:
            raise CameraError(
                f"{where}: camera '{block.camera}' gave a frame of dtype {a.dtype}; expected "
                "uint8 RGB (0-255 per channel)"
            )
        if a.shape != (envs, *block.frame_shape):
            raise CameraError(
                f"{where}: camera '{block.camera}' gave a frame of shape {a.shape}; expected "
                f"{(envs, *block.frame_shape)} (envs, rows, columns, RGB) as the policy's images "
                "entry says"
            )
        return a
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
    """(n, rows, columns, ...) images resized to (n, *shape, ...) (module docstring, step 4;
    trailing axes, an RGB frame's channels, each resized alike), float32."""
    nearest = interpolation == "nearest"
    r0, r1, wr = _resize_axis(images.shape[1], shape[0], nearest)
    c0, c1, wc = _resize_axis(images.shape[2], shape[1], nearest)
    tail = (1,) * (images.ndim - 3)  # the weights broadcast over the channels
    wr, wc = wr.reshape(-1, 1, *tail), wc.reshape(-1, *tail)
    top = images[:, r0][:, :, c0] * (1 - wc) + images[:, r0][:, :, c1] * wc
    bottom = images[:, r1][:, :, c0] * (1 - wc) + images[:, r1][:, :, c1] * wc
    return (top * (1 - wr) + bottom * wr).astype(np.float32)


def preprocess(frames: np.ndarray, block) -> np.ndarray:
    """The graph's image of each frame: float32 (envs, *block.input_shape[1:]) (module
    docstring: a depth block's steps 1-5, an RGB block's crop, resize, scale, normalisation,
    channel order and layout). ``frames`` as :func:`check_frames` returns them."""
    if block.kind == "rgb":
        return _preprocess_rgb(frames, block)
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


def _preprocess_rgb(frames: np.ndarray, block: RgbImageBlock) -> np.ndarray:
    """(envs, rows, columns, 3) uint8 RGB -> float32 (envs, *block.input_shape[1:])."""
    t, b, left, r = block.crop
    rows, cols = block.shape
    x = np.asarray(frames, dtype=np.float32)[:, t : rows - b, left : cols - r] / 255.0
    if x.shape[1:3] != tuple(block.resize):
        x = resize(x, block.resize, block.interpolation)
    if block.channel_order == "BGR":
        x = x[..., ::-1]
    if block.normalisation == "mean_std":
        x = (x - np.asarray(block.mean, np.float32)) / np.asarray(block.std, np.float32)
    if block.layout == "CHW":
        x = np.moveaxis(x, -1, 1)
    return np.ascontiguousarray(x, dtype=np.float32)
