"""An Intel RealSense camera through librealsense's Python wrapper, ``pyrealsense2``
(:class:`RealSenseCamera`): a device by its serial number, or a recorded ``.bag`` played back as
one (``rs.config.enable_device_from_file``), its depth in metres (or its colour) handed to the
runtime (:class:`~sim2real.deploy.backends.camera.feed.CameraFeed`).

Depth. A depth frame is ``z16``: uint16 units of the device's depth scale
(``depth_sensor.get_depth_scale()``, m per unit: 0.001 on a D400 by default,
``RS2_OPTION_DEPTH_UNITS``); a depth in metres is units x scale and 0 is librealsense's invalid
pixel (no stereo match, out of range), which stays 0 (the block reads it as ``far``). The stream
is asked at the block's resolution and rate; a device that cannot give it is refused in one line.

Timestamps. ``frame.get_timestamp()`` is ms in ``frame.get_frame_timestamp_domain()``:
``global_time`` (the device's clock moved onto the host's system clock by librealsense, the D400
default) and ``system_time`` (the host's clock when the frame arrived) are ms since the epoch on
``time.time``'s clock, so the age is ``time.time() - stamp``; ``hardware_clock`` (the device's own
counter) goes through :class:`~sim2real.deploy.backends.camera.feed.ClockMap`. A bag plays in real
time (``playback.set_real_time(True)``), as the camera recorded it, on the recording's clock
started when its first frame arrived: its frames keep their recorded spacing, as a video file's
do (:mod:`~sim2real.deploy.backends.camera.opencv_source`).

A grab thread waits on ``pipeline.wait_for_frames`` and keeps only the newest frame (librealsense's
own frame queue holds one frame per stream by default: a slow reader gets the newest).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from sim2real.deploy.backends.camera.convert import FrameTarget
from sim2real.deploy.backends.camera.feed import CameraFeed, ClockMap
from sim2real.deploy.spec.camera import CameraError

#: ms a wait for a frameset lasts before the thread looks at its stop flag (our choice).
WAIT_MS = 200


def require_rs(where: str):
    """``pyrealsense2``, or CameraError naming the extra that installs it (and libusb)."""
    try:
        import pyrealsense2 as rs
    except ImportError as exc:
        raise CameraError(
            f"{where}: pyrealsense2 does not import ({exc}); install the extra 'realsense' "
            "(pip install 'sim2real-deploy[realsense]'; Linux needs libusb-1.0)"
        ) from None
    return rs


def depth_metres(units: np.ndarray, scale: float) -> np.ndarray:
    """(rows, columns) uint16 z16 units -> float32 m (units x ``scale``; 0 stays 0, invalid)."""
    return (np.asarray(units, dtype=np.float32) * np.float32(scale)).astype(np.float32)


def is_bag(source: str) -> bool:
    """A recorded file (``.bag``) rather than a serial number."""
    return str(source).lower().endswith(".bag")


class RealSenseCamera:
    """A RealSense device or recording on a grab thread of its own (module docstring).

    Args:
        source: A serial number, '' (the first device) or a ``.bag`` file.
        target: What the policy's block reads (``depth``: the depth stream; ``rgb``/``bgr``:
            the colour stream). where: The option as given, in refusals.
        rate: Frames per second asked of a device (default the block's). loop: A bag starts
            again at its end.

    Attributes:
        feed: The :class:`~sim2real.deploy.backends.camera.feed.CameraFeed`. depth_scale: m per
            depth unit. domain: The stamps' timestamp domain (its name).

    Raises:
        CameraError: pyrealsense2 missing, no device (or no such serial), a missing bag, a
            stream the device or recording cannot give at the block's shape.
    """

    def __init__(self, source: str, target: FrameTarget, where: str, rate: float | None = None,
                 loop: bool = False):  # fmt: skip
        rs = self._rs = require_rs(where)
        self.where, self.target = where, target
        rows, cols = target.shape
        config = rs.config()
        bag = is_bag(source)
        if bag:
            if not Path(source).is_file():
                raise CameraError(f"{where}: no such recording '{source}'")
            config.enable_device_from_file(str(source), repeat_playback=loop)
        else:  # pipeline.start waits 15 s for a device that is not there: ask first
            serials = [d.get_info(rs.camera_info.serial_number)
                       for d in rs.context().query_devices()]  # fmt: skip
            if not serials or (source and source not in serials):
                raise CameraError(
                    f"{where}: no RealSense device{f' with serial {source}' * bool(source)} is "
                    f"connected (connected: {serials or 'none'})"
                )
            if source:
                config.enable_device(str(source))
        depth = target.kind == "depth"
        stream = rs.stream.depth if depth else rs.stream.color
        fmt = rs.format.z16 if depth else getattr(rs.format, f"{target.kind}8", rs.format.rgb8)
        if bag:
            config.enable_stream(stream)  # the recording's own profile; its shape checked per frame
        else:
            config.enable_stream(stream, cols, rows, fmt, int(round(rate or 30)))
        self.pipe = rs.pipeline()
        try:
            profile = self.pipe.start(config)
        except RuntimeError as exc:
            what = "recording" if bag else "device"
            raise CameraError(
                f"{where}: librealsense cannot start the {what}'s "
                f"{'depth' if depth else 'colour'} stream at {cols}x{rows} ({exc})"
            ) from None
        dev = profile.get_device()
        self.depth_scale = float(dev.first_depth_sensor().get_depth_scale()) if depth else 1.0
        if bag:
            dev.as_playback().set_real_time(True)
        self.encoding = "16UC1" if depth else f"{target.kind}8"
        self.feed = CameraFeed(target, where, self.depth_scale)
        self.domain = None
        self._map = ClockMap()
        self._start: float | None = None
        self._bag = bag
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="realsense", daemon=True)
        self._thread.start()

    def captured(self, stamp_ms: float, domain, received: float) -> float:
        """A frame's capture time, s monotonic, from its stamp (ms) in ``domain`` received at
        ``received`` s monotonic (module docstring)."""
        td = self._rs.timestamp_domain
        if self._bag:  # the recording's clock, started when its first frame arrived
            if self._start is None:
                self._start = received - stamp_ms / 1000.0
            return self._start + stamp_ms / 1000.0
        if domain in (td.global_time, td.system_time):
            return received - (time.time() - stamp_ms / 1000.0)
        return self._map(stamp_ms / 1000.0, received)

    def _run(self) -> None:
        depth = self.target.kind == "depth"
        while not self._stop.is_set():
            try:
                frames = self.pipe.wait_for_frames(WAIT_MS)
            except RuntimeError:  # none within WAIT_MS (a bag at its end: silent, then stale)
                continue
            received = time.monotonic()
            f = frames.get_depth_frame() if depth else frames.get_color_frame()
            if not f:
                continue
            domain = f.get_frame_timestamp_domain()
            self.domain = str(domain).rsplit(".", 1)[-1]
            image = np.asanyarray(f.get_data()).copy()
            self.feed.put(image, self.encoding, self.captured(f.get_timestamp(), domain, received))

    def fill(self, frame) -> None:
        """The newest frame into ``frame`` (:meth:`CameraFeed.fill
        <sim2real.deploy.backends.camera.feed.CameraFeed.fill>`)."""
        self.feed.fill(frame)

    def summary(self) -> dict:
        """The run report's lines: the feed's counts, the depth scale, the stamps' domain."""
        return {**self.feed.summary(), "depth_scale_m": self.depth_scale, "domain": self.domain}

    def close(self) -> None:
        """Stop the thread and the pipeline (idempotent)."""
        if not self._stop.is_set():
            self._stop.set()
            self._thread.join(timeout=2.0)
            self.pipe.stop()
