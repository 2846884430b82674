"""A hardware camera's frame made what a policy's image block reads (:func:`to_target`), whatever
the driver delivered, named by its ROS encoding (``sensor_msgs/image_encodings.hpp``):

========  ===========================================================================
encoding  what the array holds
========  ===========================================================================
rgb8      (rows, columns, 3) uint8, red first (a ROS camera driver's usual colour)
bgr8      (rows, columns, 3) uint8, blue first (OpenCV's decoders and V4L2 capture)
mono8     (rows, columns) uint8 grey
16UC1     (rows, columns) uint16 depth units: millimetres in ROS (REP 118, "Depth
          images", 16UC1 in mm), the device's depth scale on a RealSense (z16)
mono16    as 16UC1 (a depth camera publishing grey16)
32FC1     (rows, columns) float32 depth, metres (REP 118); NaN or 0 where unknown
========  ===========================================================================

The target (:class:`FrameTarget`) is block-agnostic: a (rows, columns) shape and a ``kind``:
``depth`` (float32 metres, what :class:`sim2real.deploy.spec.camera.DepthImageBlock` reads, 0 an
invalid pixel as librealsense writes it), ``rgb`` or ``bgr`` (three channels in that order, of the
target's ``dtype``, values 0-255 as the driver counted them: a colour block normalises them
itself), ``mono`` (one channel, 0-255). :func:`target_for` makes the target of a spec's image
block. A frame of another shape is refused, never resized (a camera set to another resolution
than the policy was trained with is a configuration to fix, not to hide); so is a frame that is
not numbers, and one whose encoding cannot become the target (a colour picture for a depth block,
depth for a colour block).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.deploy.spec.camera import CameraError

#: The encodings :func:`to_target` reads: their channels and element type (module docstring).
ENCODINGS = {
    "rgb8": (3, np.uint8),
    "bgr8": (3, np.uint8),
    "mono8": (1, np.uint8),
    "16UC1": (1, np.uint16),
    "mono16": (1, np.uint16),
    "32FC1": (1, np.float32),
}
#: Target kinds (module docstring).
KINDS = ("depth", "rgb", "bgr", "mono")
#: m per unit of a 16-bit depth image in ROS (REP 118: millimetres) and a RealSense D400's
#: default depth unit (librealsense ``RS2_OPTION_DEPTH_UNITS`` 0.001).
MILLIMETRE = 0.001


@dataclass(frozen=True)
class FrameTarget:
    """What a frame becomes (module docstring).

    Attributes:
        shape: (rows, columns) the block expects. kind: ``depth``, ``rgb``, ``bgr`` or ``mono``.
        camera: Named in a refusal. dtype: Of a colour or grey target (default uint8; depth is
            always float32 metres).
    """

    shape: tuple[int, int]
    kind: str = "depth"
    camera: str = "camera"
    dtype: str = "uint8"

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"FrameTarget: kind '{self.kind}', expected one of {KINDS}")

    @property
    def out_shape(self) -> tuple[int, ...]:
        """The converted frame's shape: (rows, columns), or (rows, columns, 3) for colour."""
        return (*self.shape, 3) if self.kind in ("rgb", "bgr") else tuple(self.shape)


def target_for(block) -> FrameTarget:
    """The target of a spec's image block: a :class:`~sim2real.deploy.spec.camera.
    DepthImageBlock` is ``depth``; an :class:`~sim2real.deploy.spec.camera.RgbImageBlock` is
    ``rgb`` whatever its ``channel_order`` (the runtime's camera stage reads frames in R, G, B
    order and its preprocessing gives the graph its own order)."""
    kind = "rgb" if getattr(block, "kind", "depth") == "rgb" else "depth"
    return FrameTarget(tuple(block.shape), kind, block.camera)


def to_target(
    image, encoding: str, target: FrameTarget, where: str, depth_unit: float = MILLIMETRE
) -> np.ndarray:
    """``image`` (as the driver delivered it, ``encoding``) as the target's frame.

    Args:
        image: The frame's array. encoding: One of :data:`ENCODINGS`.
        target: What the block reads. where: The source, named in a refusal (``--camera-source
            head=ros2:/depth``). depth_unit: m per unit of a 16-bit depth frame (a RealSense's
            depth scale; ROS: 0.001).

    Returns:
        depth: float32 (rows, columns) m, 0 invalid (0 units, NaN, inf or negative);
        rgb/bgr: (rows, columns, 3) of ``target.dtype`` in that order; mono: (rows, columns).

    Raises:
        CameraError: a frame that is not numbers, an unknown encoding, an encoding the target
            cannot be made of, or another shape than the target's (one line naming ``where``,
            the camera and what was expected).
    """
    head = f"{where}: camera '{target.camera}'"
    if encoding not in ENCODINGS:
        raise CameraError(
            f"{head}: encoding '{encoding}' is not read; expected one of {sorted(ENCODINGS)}"
        )
    a = np.asarray(image)
    if a.dtype.kind not in "uif" or a.dtype.kind == "b":
        raise CameraError(f"{head}: a frame of dtype {a.dtype}; expected numbers ({encoding})")
    channels, _ = ENCODINGS[encoding]
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    got = a.shape[2] if a.ndim == 3 else 1 if a.ndim == 2 else None
    if got != channels:
        raise CameraError(
            f"{head}: a frame of shape {a.shape} for encoding '{encoding}'; expected "
            f"(rows, columns{', 3' * (channels == 3)})"
        )
    if a.shape[:2] != tuple(target.shape):
        raise CameraError(
            f"{head}: a frame of {a.shape[0]} x {a.shape[1]} pixels; the policy's image block "
            f"expects {target.shape[0]} x {target.shape[1]} (rows x columns): set the camera to "
            "that resolution"
        )
    if target.kind == "depth":
        if encoding in ("16UC1", "mono16"):
            return (a.astype(np.float32) * np.float32(depth_unit)).astype(np.float32)
        if encoding == "32FC1":
            d = a.astype(np.float32)
            return np.where(np.isfinite(d) & (d > 0), d, np.float32(0.0)).astype(np.float32)
        raise CameraError(
            f"{head}: a '{encoding}' picture for a depth block; expected depth (16UC1 or mono16 "
            "depth units, 32FC1 metres)"
        )
    if encoding not in ("rgb8", "bgr8", "mono8"):
        raise CameraError(
            f"{head}: '{encoding}' depth for a {target.kind} block; expected rgb8, bgr8 or mono8"
        )
    if target.kind == "mono":
        if encoding != "mono8":
            raise CameraError(f"{head}: a colour '{encoding}' frame for a one-channel block")
        return a.astype(target.dtype)
    if encoding == "mono8":
        raise CameraError(
            f"{head}: a grey (mono8) frame for a {target.kind} block; expected rgb8 or bgr8"
        )
    if encoding[:3] != target.kind:
        a = a[:, :, ::-1]
    return np.ascontiguousarray(a, dtype=target.dtype)


def decode_compressed(data, fmt: str, where: str) -> tuple[np.ndarray, str]:
    """A ``sensor_msgs/CompressedImage``'s bytes as ``(image, encoding)`` by OpenCV's decoder:
    a JPEG or PNG colour picture as ``bgr8``, a grey one as ``mono8``, a 16-bit PNG (depth) as
    ``16UC1``. ``fmt`` is the message's ``format`` (``jpeg``, ``png``, or image_transport's
    ``rgb8; jpeg compressed bgr8``); ``compressedDepth`` (its own header before the PNG) is
    refused.

    Raises:
        CameraError: OpenCV is missing, the format is compressedDepth, or the bytes do not
            decode (one line naming ``where``)."""
    if "compresseddepth" in fmt.lower().replace(" ", ""):
        raise CameraError(
            f"{where}: CompressedImage format '{fmt}' (compressedDepth) is not read; publish "
            "the raw sensor_msgs/Image (16UC1 or 32FC1)"
        )
    cv2 = require_cv2(where)
    buf = np.frombuffer(bytes(data), dtype=np.uint8)
    image = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if buf.size else None
    if image is None:
        raise CameraError(
            f"{where}: a CompressedImage ({fmt or 'no format'}, {buf.size} bytes) that OpenCV "
            "cannot decode; expected JPEG or PNG"
        )
    if image.dtype == np.uint16 and image.ndim == 2:
        return image, "16UC1"
    if image.ndim == 2:
        return image, "mono8"
    if image.shape[2] == 4:
        image = image[:, :, :3]  # a PNG's alpha
    return image, "bgr8"


def require_cv2(where: str):
    """``cv2`` (OpenCV), or CameraError naming the extra that installs it."""
    try:
        import cv2
    except ImportError:
        raise CameraError(
            f"{where}: OpenCV does not import; install the extra 'camera' (pip install "
            "'sim2real-deploy[camera]': opencv-python-headless)"
        ) from None
    return cv2
