"""The elevation map on a robot: a ROS 2 subscriber that fills the frame's height scan
(:class:`HeightMapSubscriber`, a :class:`sim2real.deploy.runtime.height_map.HeightMap` source).

Two messages, converted by functions that need no ROS (tested on their own):

- ``std_msgs/Float32MultiArray`` (:func:`scan_from_array`): the scan itself, the sensor's height
  above the terrain at each point of the policy's pattern in the block's order, m (a node next to
  the elevation mapping samples its map there); ``layout.dim`` sizes multiply to the points.
- ``grid_map_msgs/GridMap`` where the package imports (:func:`scan_from_grid_map`): a layer
  (default ``elevation``) sampled at the pattern's points about the sensor's pose in the map's
  frame (x, y, z m, yaw rad; the caller's ``pose``: TF on a robot), the nearest cell as
  ``GridMap::atPosition`` reads it. grid_map's storage: each layer a column-major matrix
  (``data[col * rows + row]``), row along -x and column along -y from the map's corner at
  ``pose + (length_x / 2, length_y / 2)``, a circular buffer starting at
  (``outer_start_index``, ``inner_start_index``). A cell that is NaN (unknown) or off the map
  reads +inf, as a ray that meets nothing (the block's clip bounds it).

A map's stamp is its header's, moved onto this computer's clock by the smallest
receive-minus-stamp difference seen (the clocks' offset cancels); a map without a stamp is
stamped when it arrived. A node that stops publishing, or repeats an old map, goes stale.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

from sim2real.deploy.spec.height_scan import HeightScanPattern


def scan_from_array(data, sizes: list[int], pattern: HeightScanPattern) -> np.ndarray:
    """(P,) m the scan of a ``Float32MultiArray`` (``data``, its ``layout.dim`` ``sizes``).

    Raises:
        ValueError: sizes or data that do not hold the pattern's points.
    """
    scan = np.asarray(data, dtype=np.float64)
    if sizes and math.prod(sizes) != pattern.count or scan.shape != (pattern.count,):
        raise ValueError(
            f"height map: Float32MultiArray layout {sizes} with {scan.size} values; expected "
            f"{pattern.count} (the policy's scan: {len(pattern.x)} x {len(pattern.y)})"
        )
    return scan


def scan_from_grid_map(msg, pattern: HeightScanPattern, pose, layer: str = "elevation"):
    """(P,) m ``z_sensor - z_cell`` of ``msg`` (a ``grid_map_msgs/GridMap``) at the pattern's
    points about ``pose`` (x, y, z m, yaw rad: the sensor in the map's frame; ``base`` and
    ``world`` alignment read as ``yaw``: a map has no tilt).

    Raises:
        ValueError: no such layer, or a layer whose size is not the map's.
    """
    if layer not in list(msg.layers):
        raise ValueError(f"height map: GridMap has no layer '{layer}' (layers {list(msg.layers)})")
    info, array = msg.info, msg.data[list(msg.layers).index(layer)]
    res = float(info.resolution)
    rows, cols = round(info.length_x / res), round(info.length_y / res)
    values = np.asarray(array.data, dtype=np.float64)
    if values.size != rows * cols:
        raise ValueError(
            f"height map: GridMap layer '{layer}' has {values.size} cells, the map {rows} x {cols}"
        )
    x, y, z, yaw = (float(v) for v in pose)
    c, s = (1.0, 0.0) if pattern.alignment == "world" else (math.cos(yaw), math.sin(yaw))
    p = pattern.points()
    px, py = x + c * p[:, 0] - s * p[:, 1], y + s * p[:, 0] + c * p[:, 1]
    centre = info.pose.position
    row = np.floor((centre.x + info.length_x / 2.0 - px) / res).astype(np.int64)
    col = np.floor((centre.y + info.length_y / 2.0 - py) / res).astype(np.int64)
    inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    r = (row + int(msg.outer_start_index)) % rows
    k = (col + int(msg.inner_start_index)) % cols
    cell = np.where(inside, values[(k * rows + r) % values.size], np.nan)
    return np.where(np.isfinite(cell), z - cell, np.inf)


class HeightMapSubscriber:
    """Subscribes to an elevation map topic and writes the newest map into the frame (module
    docstring): ``fill(frame)`` (one env: ``frame.height_scan`` (1, P) m,
    ``frame.height_scan_stamp`` (1,) s on the frame's clock; NaN until a map arrives).

    Args:
        pattern: The policy's block's pattern. topic: The map's topic.
        message: ``array`` (``std_msgs/Float32MultiArray``) or ``grid_map``.
        pose: ``grid_map`` only: ``() -> (x, y, z, yaw)`` the sensor in the map's frame.
        node: A :class:`~sim2real.deploy.ros2.context.NodeThread` to subscribe on (default one
            of its own, spun on its thread).

    Raises:
        Ros2UnavailableError: rclpy or the message's package is missing.
    """

    def __init__(self, pattern, topic="height_map", message="array", pose=None, node=None):
        from sim2real.deploy.ros2.context import NodeThread, Ros2UnavailableError

        self.pattern, self.message, self.pose = pattern, message, pose
        if message == "grid_map":
            try:
                from grid_map_msgs.msg import GridMap as kind
            except ImportError:
                raise Ros2UnavailableError(
                    "height map: grid_map_msgs does not import; publish a "
                    "std_msgs/Float32MultiArray of the scan (message 'array') instead"
                ) from None
        elif message == "array":
            from std_msgs.msg import Float32MultiArray as kind
        else:
            raise ValueError(f"height map: message '{message}', expected 'array' or 'grid_map'")
        self._own = node is None
        self.node = node or NodeThread("deploy_height_map")
        self._lock = threading.Lock()
        self._scan = np.full(pattern.count, np.nan)
        self._sampled = np.nan  # s, this computer's monotonic clock
        self._offset = np.inf
        self._seq = self._taken = 0
        self.received = 0
        self.node.node.create_subscription(kind, topic, self._on_map, 10)
        if self._own:
            self.node.start()

    def _on_map(self, msg) -> None:
        now = time.monotonic()
        if self.message == "grid_map":
            scan = scan_from_grid_map(msg, self.pattern, self.pose())
            header = msg.info.header.stamp
        else:
            scan = scan_from_array(msg.data, [d.size for d in msg.layout.dim], self.pattern)
            header = None
        sampled = now
        if header is not None and (header.sec or header.nanosec):
            stamp = header.sec + header.nanosec * 1e-9
            self._offset = min(self._offset, now - stamp)
            sampled = stamp + self._offset
        with self._lock:
            self._scan[:] = scan
            self._sampled = sampled
            self._seq += 1
            self.received += 1

    def fill(self, frame) -> None:
        """The newest map into ``frame`` (made on the first call), stamped on its clock."""
        if frame.height_scan is None:
            frame.height_scan = np.full((1, self.pattern.count), np.nan)
            frame.height_scan_stamp = np.full(1, np.nan)
        with self._lock:
            if self._seq == self._taken:
                frame.height_scan_stamp[0] = np.nan  # nothing new arrived
                return
            self._taken = self._seq
            frame.height_scan[0] = self._scan
            age = time.monotonic() - self._sampled
        frame.height_scan_stamp[0] = frame.time[0] - age

    def close(self) -> None:
        """Leave ROS 2 (a node of its own only)."""
        if self._own:
            self.node.close()
