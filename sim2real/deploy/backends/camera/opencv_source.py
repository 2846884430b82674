"""A camera through OpenCV's ``cv2.VideoCapture`` (:class:`OpenCvCamera`): a V4L2/UVC device
(``/dev/videoN`` or its index), a video file or a stream URL, its frames converted to the policy's
block and handed to the runtime (:class:`~sim2real.deploy.backends.camera.feed.CameraFeed`).

Latency. V4L2 queues frames: OpenCV's V4L2 backend requests 4 buffers
(``DEFAULT_V4L_BUFFERS``, ``modules/videoio/src/cap_v4l.cpp``) and ``read()`` dequeues the oldest
filled one, so a reader that lags the camera reads frames up to 4 frame periods old. Two things
keep the age to one frame's transfer: ``CAP_PROP_BUFFERSIZE`` 1 (the V4L2 backend requests that
many buffers; others may ignore it), and a grab thread of our own that dequeues every frame as it
arrives (``grab()`` blocks until the next) and keeps only the newest; the control loop never
reads the device.

Timestamps. On V4L2, ``CAP_PROP_POS_MSEC`` after a ``grab()`` is the dequeued buffer's kernel
timestamp (``cap_v4l.cpp``, ``getProperty``: ``1000 * timestamp.tv_sec + tv_usec / 1000``), taken
by the driver when the frame's capture began (uvcvideo: the first packet) on ``CLOCK_MONOTONIC``
(``V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC``), the clock of Python's ``time.monotonic``: the age is then
measured from the sensor's own stamp, the USB transfer and the decoding included. A stamp more
than 1 s from the monotonic clock (a driver stamping on another clock, an IP camera's stream
time) goes through :class:`~sim2real.deploy.backends.camera.feed.ClockMap`. A device that stops
delivering falls silent: the runtime's stage judges it stale and stops the robot. A video file is
played as a camera at its own rate: frame ``k`` is delivered at the start plus its presentation
time (``CAP_PROP_POS_MSEC`` of the FFmpeg backend after a ``grab()``) and stamped with it, so its
ages are the file's timestamps; at the file's end the camera falls silent (the runtime then
judges it stale), or starts again with ``loop``.

Frames: 8-bit colour as ``bgr8`` (OpenCV's order), 8-bit grey as ``mono8``, 16-bit one-channel
as ``16UC1`` (depth units, read with ``CAP_PROP_CONVERT_RGB`` off for a depth block: a UVC depth
camera's ``Z16``/``Y16``, a 16-bit FFV1 recording; ``--camera-source NAME=opencv:...`` scales it
by ``depth_unit``, default 1 mm).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from sim2real.deploy.backends.camera.convert import FrameTarget, require_cv2
from sim2real.deploy.backends.camera.feed import CameraFeed, ClockMap
from sim2real.deploy.spec.camera import CameraError

#: s between a V4L2 stamp and the monotonic clock past which it is not read as that clock.
MONOTONIC_SLACK = 1.0
#: Buffers asked of a V4L2 device (module docstring).
BUFFERS = 1


def encoding_of(image: np.ndarray) -> str:
    """The encoding of a frame OpenCV decoded: ``bgr8``, ``mono8``, ``16UC1`` or, for anything
    else, a name :func:`~sim2real.deploy.backends.camera.convert.to_target` refuses naming it."""
    if image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] in (3, 4):
        return "bgr8"  # 4: BGRx/BGRA as FFmpeg gives it unconverted; the fourth channel is dropped
    if image.dtype == np.uint8 and image.ndim == 2:
        return "mono8"
    if image.dtype == np.uint16 and image.ndim == 2:
        return "16UC1"
    return f"{image.dtype}{list(image.shape)}"


def device_capture_time(stamp: float, received: float, clock_map: ClockMap) -> tuple[float, str]:
    """A device frame's capture time, s monotonic, and how it was read: its V4L2 stamp ``stamp``
    (s) as it is (``monotonic``) when it lies within ``MONOTONIC_SLACK`` of ``received`` (s,
    monotonic), else through ``clock_map`` (``mapped``; module docstring)."""
    if stamp > 0 and -MONOTONIC_SLACK < received - stamp < MONOTONIC_SLACK:
        return stamp, "monotonic"  # V4L2: CLOCK_MONOTONIC, the clock of time.monotonic
    return clock_map(stamp, received), "mapped"


def is_device(source) -> bool:
    """An int (``/dev/videoN``'s N), a digit string or a ``/dev/video*`` path."""
    return isinstance(source, int) or str(source).isdigit() or str(source).startswith("/dev/")


class OpenCvCamera:
    """A ``cv2.VideoCapture`` camera on a grab thread of its own (module docstring).

    Args:
        source: A device index, ``/dev/videoN``, a video file or a URL.
        target: What the policy's block reads. where: The option as given, in refusals.
        rate: Frames per second asked of a device (default: its own). depth_unit: m per unit of
            a 16-bit frame. loop: A file starts again at its end.

    Attributes:
        feed: The :class:`~sim2real.deploy.backends.camera.feed.CameraFeed` (``fill(frame)``).
        device: True for a V4L2 device. ended: A file played to its end (or a device lost).
        stamp_clock: ``monotonic`` (V4L2 stamps read as they are), ``mapped`` (through a
            :class:`~sim2real.deploy.backends.camera.feed.ClockMap`) or ``file``.

    Raises:
        CameraError: OpenCV missing, or the source does not open.
    """

    def __init__(self, source, target: FrameTarget, where: str, rate: float | None = None,
                 depth_unit: float = 0.001, loop: bool = False):  # fmt: skip
        cv2 = self._cv2 = require_cv2(where)
        self.device = is_device(source)
        self.where, self.loop = where, loop
        self.feed = CameraFeed(target, where, depth_unit)
        raw = target.kind == "depth"  # 16-bit frames as they are, not converted to 8-bit BGR
        if self.device:
            src = int(source) if str(source).isdigit() else str(source)
            self.cap = cv2.VideoCapture(src, cv2.CAP_V4L2)
        else:
            params = [cv2.CAP_PROP_CONVERT_RGB, 0] if raw else []
            self.cap = cv2.VideoCapture(str(source), cv2.CAP_ANY, params)
        if not self.cap.isOpened():
            raise CameraError(f"{where}: OpenCV cannot open '{source}'")
        if self.device:
            rows, cols = target.shape
            self.cap.set(cv2.CAP_PROP_BUFFERSIZE, BUFFERS)
            self.cap.set(cv2.CAP_PROP_FRAME_WIDTH, cols)
            self.cap.set(cv2.CAP_PROP_FRAME_HEIGHT, rows)
            if rate:
                self.cap.set(cv2.CAP_PROP_FPS, float(rate))
            if raw:
                self.cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        self.stamp_clock = "file" if not self.device else "monotonic"
        self.ended = False
        self._map = ClockMap()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="opencv-camera", daemon=True)
        self._thread.start()

    def _captured(self, received: float, start: float) -> float:
        """The grabbed frame's capture time, s monotonic (module docstring)."""
        stamp = self.cap.get(self._cv2.CAP_PROP_POS_MSEC) / 1000.0
        if not self.device:
            return start + stamp
        captured, clock = device_capture_time(stamp, received, self._map)
        if clock == "mapped":
            self.stamp_clock = clock
        return captured

    def _run(self) -> None:
        start = time.monotonic()
        while not self._stop.is_set():
            if not self.cap.grab():
                if self.loop and not self.device and self.cap.set(self._cv2.CAP_PROP_POS_FRAMES, 0):
                    start = time.monotonic()
                    continue
                self.ended = True  # silent from now on: the runtime's stage judges it stale
                return
            received = time.monotonic()
            captured = self._captured(received, start)
            if not self.device:  # a file plays at its own rate
                self._stop.wait(max(0.0, captured - time.monotonic()))
            ok, image = self.cap.retrieve()
            if ok and image is not None:
                if image.ndim == 3 and image.shape[2] == 4:
                    image = image[:, :, :3]
                self.feed.put(image, encoding_of(image), captured)

    def fill(self, frame) -> None:
        """The newest frame into ``frame`` (:meth:`CameraFeed.fill
        <sim2real.deploy.backends.camera.feed.CameraFeed.fill>`)."""
        self.feed.fill(frame)

    def summary(self) -> dict:
        """The run report's lines: the feed's counts, the stamps' clock."""
        return {**self.feed.summary(), "stamp_clock": self.stamp_clock, "ended": self.ended}

    def close(self) -> None:
        """Stop the grab thread and release the device (idempotent)."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        if not self._thread.is_alive():  # a grab blocked on a dead device: left to the exit
            self.cap.release()
