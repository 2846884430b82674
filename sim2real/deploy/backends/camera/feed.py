"""The newest frame of a hardware camera and its capture time, handed from the driver's thread to
the control loop (:class:`CameraFeed`): what every hardware source (OpenCV, RealSense, a ROS 2
image topic) fills and the runtime's camera stage (:mod:`sim2real.deploy.runtime.camera`) reads
through ``fill(frame)``, as it reads the simulated camera.

Clocks. A driver thread calls :meth:`CameraFeed.put` with the frame and its capture time on this
computer's monotonic clock (``time.monotonic``, Linux ``CLOCK_MONOTONIC``), the clock V4L2 stamps
its buffers on. A source whose stamps are on another clock (a RealSense's hardware clock, a
driver stamping on a clock of its own) passes them through :class:`ClockMap`, which moves
them onto the monotonic clock by the smallest receive-minus-stamp difference seen (the clocks'
offset cancels; the least delayed frame sets it, so an age is never under the true one by more
than that frame's transport delay). :meth:`CameraFeed.fill` writes the frame's stamp on the
frame's own clock: ``frame.time - age``, the age measured on the monotonic clock at the tick.

Only the newest frame is kept (a frame the loop did not take before the next arrived is dropped,
counted in ``overwritten``): the runtime wants the freshest view, not a queue of old ones. A tick
with no new frame since the last writes a NaN stamp (nothing delivered), so the runtime's stage
keeps its last frame's age growing and judges it stale past its limit, as it does a silent
simulated camera. A frame the target refuses (:func:`~sim2real.deploy.backends.camera.convert.
to_target`) is never delivered: before the first good frame it is the error :meth:`CameraFeed.
wait_first` raises (deploy-run refuses the camera before the robot moves); after it, a driver
that turns to another resolution or encoding mid-run is counted (``refused``, the last
``refusal``'s line in the report) and, delivering nothing the policy can read, goes stale: the
robot is safe-stopped, not left limp by an error.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from sim2real.deploy.backends.camera.convert import FrameTarget, to_target
from sim2real.deploy.spec.camera import CameraError


class ClockMap:
    """A device clock's stamps onto the monotonic clock (module docstring): ``offset`` s, the
    smallest ``receive - stamp`` seen (inf until the first stamp)."""

    def __init__(self):
        self.offset = np.inf

    def __call__(self, stamp: float, received: float) -> float:
        """The capture time of ``stamp`` (s, the device's clock) received at ``received`` (s,
        monotonic), on the monotonic clock."""
        self.offset = min(self.offset, received - stamp)
        return stamp + self.offset


class CameraFeed:
    """One camera's newest converted frame (module docstring).

    Args:
        target: What the policy's block reads (:class:`~sim2real.deploy.backends.camera.convert.
            FrameTarget`). where: The source as the user named it, in every refusal.
        depth_unit: m per unit of a 16-bit depth frame (a RealSense's depth scale; ROS 0.001).
        monotonic: The clock (default ``time.monotonic``; a test may pass its own).
        fields: The frame's image and stamp attributes (default those the runtime's camera
            stage reads for the target: ``depth_image`` and ``depth_stamp`` for depth,
            ``rgb_image`` and ``rgb_stamp`` for colour; :data:`sim2real.deploy.runtime.camera.
            FRAME_FIELDS`).

    Attributes:
        received: Frames put. taken: Frames the loop took. overwritten: Frames replaced before
            the loop took them. refused: Frames refused. refusal: The last refusal's line.
        last_age: s, the age of the last frame taken at its tick.
    """

    def __init__(self, target: FrameTarget, where: str, depth_unit: float = 0.001,
                 monotonic=time.monotonic, fields=None):  # fmt: skip
        self.target, self.where, self.depth_unit = target, where, depth_unit
        if fields is None:
            depth = target.kind == "depth"
            fields = ("depth_image", "depth_stamp") if depth else ("rgb_image", "rgb_stamp")
        self.fields = fields
        self.monotonic = monotonic
        self._lock = threading.Lock()
        self._new = threading.Condition(self._lock)
        self._image: np.ndarray | None = None
        self._captured = np.nan
        self._error: CameraError | None = None
        self._seq = self._taken_seq = 0
        self.received = self.taken = self.overwritten = self.refused = 0
        self.refusal: str | None = None
        self.last_age = np.nan

    def put(self, image, encoding: str, captured: float) -> None:
        """A driver's frame (``encoding``, :mod:`~sim2real.deploy.backends.camera.convert`)
        captured at ``captured`` s (monotonic): converted and kept as the newest; a refused
        frame is counted, never delivered (module docstring)."""
        try:
            frame, error = (
                to_target(image, encoding, self.target, self.where, self.depth_unit),
                None,
            )
        except CameraError as exc:
            frame, error = None, exc
        with self._new:
            if error is not None:
                self._refuse(error)
            else:
                if self._seq > self._taken_seq:
                    self.overwritten += 1
                self._image, self._captured = frame, float(captured)
                self._seq += 1
            self.received += 1
            self._new.notify_all()

    def _refuse(self, error: CameraError) -> None:
        self.refused += 1
        self.refusal = str(error)
        if self._image is None:  # before the first good frame: what wait_first raises
            self._error = self._error or error

    def fail(self, error: CameraError) -> None:
        """A frame the driver could not even decode (module docstring: refused as a frame the
        target refuses)."""
        with self._new:
            self._refuse(error)
            self._new.notify_all()

    def wait_first(self, timeout: float) -> np.ndarray:
        """Block until the first frame arrived (before the loop starts: a camera that delivers
        nothing, or a frame the block refuses, is refused before the robot moves); its frame.

        Raises:
            CameraError: a refused frame, a driver's failure, or no frame within ``timeout`` s.
        """
        end = self.monotonic() + timeout
        with self._new:
            while self._image is None and self._error is None:
                left = end - self.monotonic()
                if left <= 0:
                    raise CameraError(
                        f"{self.where}: no frame from camera '{self.target.camera}' within "
                        f"{timeout:g} s; check the device, file or topic"
                    )
                self._new.wait(min(left, 0.1))
            if self._error is not None:
                raise self._error
            return self._image

    def fill(self, frame) -> None:
        """The newest frame into ``frame.depth_image`` (1, rows, columns) and its capture time
        on the frame's clock into ``frame.depth_stamp`` (1,) (made on the first call, of the
        target's dtype: float32 metres for depth; NaN: no new frame since the last call;
        module docstring). Other ``fields``: the same under their names."""
        name, stamp_name = self.fields
        if getattr(frame, name, None) is None:
            dtype = np.float32 if self.target.kind == "depth" else self.target.dtype
            setattr(frame, name, np.zeros((1, *self.target.out_shape), dtype))
            setattr(frame, stamp_name, np.full(1, np.nan))
        images, stamps = getattr(frame, name), getattr(frame, stamp_name)
        with self._lock:
            if self._seq == self._taken_seq:
                stamps[0] = np.nan
                return
            self._taken_seq = self._seq
            images[0] = self._image
            age = self.monotonic() - self._captured
        self.taken += 1
        self.last_age = age
        stamps[0] = float(np.asarray(frame.time).flat[0]) - age

    def summary(self) -> dict:
        """The run report's lines: the source, frames received, taken, overwritten and refused
        (the last refusal), the last taken frame's age, s."""
        return {
            "source": self.where,
            "received": self.received,
            "taken": self.taken,
            "overwritten": self.overwritten,
            "refused": self.refused,
            "refusal": self.refusal,
            "last_age_s": None if np.isnan(self.last_age) else round(float(self.last_age), 6),
        }
