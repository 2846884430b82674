"""A camera on a ROS 2 topic (:class:`ImageSubscriber`): ``sensor_msgs/Image`` or
``sensor_msgs/CompressedImage`` frames converted to the policy's block and handed to the runtime
(:class:`~sim2real.deploy.backends.camera.feed.CameraFeed`), each frame's age from its header.

Messages (converted by functions that need no ROS, tested on their own):

- ``sensor_msgs/Image`` (:func:`image_from_msg`): ``encoding`` rgb8, bgr8, mono8, 16UC1 or mono16
  (depth in mm, REP 118), 32FC1 (depth in m, REP 118); rows of ``step`` bytes (a row may be
  padded), ``is_bigendian`` honoured. Another encoding (rgba8, a Bayer pattern, yuv422) is refused
  in one line naming it.
- ``sensor_msgs/CompressedImage`` (:func:`~sim2real.deploy.backends.camera.convert.
  decode_compressed`, OpenCV): JPEG or PNG. image_transport publishes a camera's compressed
  stream on its image topic plus ``/compressed``: a topic ending so is read as CompressedImage.

Age. A frame's capture time is its ``header.stamp`` read against the node's clock
(``node.get_clock()``: the system clock, or ``/clock`` with ``use_sim_time``) when it arrives:
``age = now - stamp``, carried onto the monotonic clock the feed measures ages on. The publisher's
clock must be the node's (one computer, or clocks kept together by chrony or PTP, as every ROS
robot's are). A zero stamp (a driver that stamps nothing) is stamped when it arrived.
"""

from __future__ import annotations

import time

import numpy as np

from sim2real.deploy.backends.camera.convert import ENCODINGS, FrameTarget, decode_compressed
from sim2real.deploy.backends.camera.feed import CameraFeed
from sim2real.deploy.spec.camera import CameraError

#: m per unit of a 16-bit depth image (REP 118: millimetres).
ROS_DEPTH_UNIT = 0.001


def image_from_msg(encoding: str, height: int, width: int, step: int, bigendian: bool, data,
                   where: str) -> np.ndarray:  # fmt: skip
    """A ``sensor_msgs/Image``'s fields as its array (rows, columns[, 3]) of the encoding's type.

    Raises:
        CameraError: an encoding not read, or data shorter than ``height`` rows of ``step``
            bytes, or a ``step`` shorter than a row (one line naming ``where``)."""
    if encoding not in ENCODINGS:
        raise CameraError(
            f"{where}: sensor_msgs/Image encoding '{encoding}' is not read; expected one of "
            f"{sorted(ENCODINGS)}"
        )
    channels, dtype = ENCODINGS[encoding]
    dt = np.dtype(dtype).newbyteorder(">" if bigendian else "<")
    row = width * channels * dt.itemsize
    buf = np.frombuffer(bytes(data), dtype=np.uint8)
    if step < row or buf.size < height * step:
        raise CameraError(
            f"{where}: sensor_msgs/Image {width}x{height} {encoding} with step {step} and "
            f"{buf.size} bytes; expected step >= {row} and {height} x step bytes"
        )
    rows = buf[: height * step].reshape(height, step)[:, :row]
    a = np.ascontiguousarray(rows).view(dt).astype(dtype)
    return a.reshape(height, width, channels) if channels == 3 else a.reshape(height, width)


def is_compressed(topic: str) -> bool:
    """image_transport's compressed topic (module docstring)."""
    return topic.rstrip("/").endswith("/compressed")


class ImageSubscriber:
    """Subscribes to a camera topic and keeps its newest frame for the runtime (module docstring).

    Args:
        topic: The image topic (``.../compressed``: CompressedImage). target: What the policy's
            block reads. where: The option as given, in refusals.
        node: A :class:`~sim2real.deploy.ros2.context.NodeThread` to subscribe on (default one of
            its own, spun on its thread).

    Attributes:
        feed: The :class:`~sim2real.deploy.backends.camera.feed.CameraFeed` (``fill(frame)``).

    Raises:
        Ros2UnavailableError: rclpy or sensor_msgs missing.
    """

    def __init__(self, topic: str, target: FrameTarget, where: str, node=None):
        from sim2real.deploy.ros2.context import NodeThread, require_ros2

        require_ros2()
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import CompressedImage, Image

        self.topic, self.where = topic, where
        self.compressed = is_compressed(topic)
        self.feed = CameraFeed(target, where, ROS_DEPTH_UNIT)
        self._own = node is None
        self.node = node or NodeThread("deploy_camera")
        kind = CompressedImage if self.compressed else Image
        # a camera driver publishes best effort (image_transport's sensor data profile); a
        # best-effort subscriber also hears a reliable publisher
        self.node.node.create_subscription(kind, topic, self._on_image, qos_profile_sensor_data)
        if self._own:
            self.node.start()

    def _on_image(self, msg) -> None:
        received = time.monotonic()
        now = self.node.node.get_clock().now().nanoseconds * 1e-9
        s = msg.header.stamp
        age = now - (s.sec + s.nanosec * 1e-9) if (s.sec or s.nanosec) else 0.0
        try:
            if self.compressed:
                image, encoding = decode_compressed(msg.data, msg.format, self.where)
            else:
                image = image_from_msg(msg.encoding, msg.height, msg.width, msg.step,
                                       bool(msg.is_bigendian), msg.data, self.where)  # fmt: skip
                encoding = msg.encoding
        except CameraError as exc:
            self.feed.fail(exc)
            return
        self.feed.put(image, encoding, received - age)

    def fill(self, frame) -> None:
        """The newest frame into ``frame`` (:meth:`CameraFeed.fill
        <sim2real.deploy.backends.camera.feed.CameraFeed.fill>`)."""
        self.feed.fill(frame)

    def summary(self) -> dict:
        """The run report's lines: the feed's counts and the topic."""
        return {**self.feed.summary(), "topic": self.topic, "compressed": self.compressed}

    def close(self) -> None:
        """Leave ROS 2 (a node of its own only)."""
        if self._own:
            self.node.close()
