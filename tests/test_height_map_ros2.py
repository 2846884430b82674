"""The elevation map over ROS 2: a Float32MultiArray of the scan and a grid_map GridMap sampled at
the policy's points, converted to the frame's height scan; the subscriber against a publisher."""

from __future__ import annotations

import time
from types import SimpleNamespace as NS

import numpy as np
import pytest

from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.ros2.height_map import scan_from_array, scan_from_grid_map
from sim2real.deploy.spec.height_scan import HeightScanPattern
from tests.test_ros2 import ros_domain  # noqa: F401 - the fixture

PATTERN = HeightScanPattern()  # legged_gym's 17 x 11


def test_an_array_message_is_the_scan_and_a_wrong_size_is_refused():
    data = np.arange(187, dtype=np.float32) * 0.01
    np.testing.assert_allclose(scan_from_array(data, [17, 11], PATTERN), data, rtol=1e-7)
    with pytest.raises(ValueError, match=r"layout \[16, 11\] with 176 values; expected 187"):
        scan_from_array(data[:176], [16, 11], PATTERN)


def grid_map(elevation, start=(0, 0), length=4.0, res=0.1) -> NS:
    """A ``grid_map_msgs/GridMap`` as grid_map_ros writes one: ``elevation`` (rows along -x,
    columns along -y) stored column-major in a circular buffer starting at ``start``."""
    stored = np.roll(elevation, shift=start, axis=(0, 1))
    info = NS(resolution=res, length_x=length, length_y=length, pose=NS(position=NS(x=0.0, y=0.0)))
    data = NS(data=stored.flatten(order="F").astype(np.float32).tolist())
    return NS(info=info, layers=["elevation"], data=[data], outer_start_index=start[0],
              inner_start_index=start[1])  # fmt: skip


@pytest.mark.parametrize("start", [(0, 0), (7, 23)])
def test_a_grid_map_is_sampled_at_the_points_about_the_sensor(start):
    cells = 40
    centre_x = 2.0 - (np.arange(cells) + 0.5) * 0.1  # row i's x, m
    elevation = np.where(centre_x[:, None] >= 0.3, 0.1, 0.0) * np.ones((cells, cells))
    elevation[0, 0] = np.nan  # an unknown cell, off the scan
    pose = (0.05, 0.05, 0.33, 0.0)  # the sensor at cell centres' offsets, 0.33 m up
    scan = scan_from_grid_map(grid_map(elevation, start), PATTERN, pose)
    px = 0.05 + PATTERN.points()[:, 0]
    np.testing.assert_allclose(scan, 0.33 - np.where(px >= 0.3, 0.1, 0.0), atol=1e-6)
    far = scan_from_grid_map(grid_map(elevation, start), PATTERN, (1.9, 1.9, 0.33, 0.0))
    assert np.isinf(far).sum() > 0 and np.all(far[np.isfinite(far)] > 0)  # off the map: +inf


def test_the_subscriber_fills_the_frame_with_the_newest_map_and_stamps_it(ros_domain):  # noqa: F811
    from std_msgs.msg import Float32MultiArray, MultiArrayDimension

    from sim2real.deploy.ros2.context import NodeThread
    from sim2real.deploy.ros2.height_map import HeightMapSubscriber

    sub = HeightMapSubscriber(PATTERN, topic="height_map")
    frame = SensorFrame.empty(1, 12, 4)
    frame.time[0] = 10.0
    sub.fill(frame)
    assert np.isnan(frame.height_scan_stamp[0])  # nothing yet
    with NodeThread("map_node") as pub_node:
        pub = pub_node.node.create_publisher(Float32MultiArray, "height_map", 10)
        msg = Float32MultiArray()
        msg.layout.dim = [MultiArrayDimension(label="x", size=17, stride=187),
                          MultiArrayDimension(label="y", size=11, stride=11)]  # fmt: skip
        msg.data = [0.3] * 187
        end = time.monotonic() + 10.0
        while sub.received == 0 and time.monotonic() < end:
            pub.publish(msg)
            time.sleep(0.05)
    try:
        assert sub.received > 0
        sub.fill(frame)
        np.testing.assert_allclose(frame.height_scan[0], 0.3, rtol=1e-6)
        assert 9.0 < frame.height_scan_stamp[0] <= 10.0
        sub.fill(frame)
        assert np.isnan(frame.height_scan_stamp[0])  # no new map since
    finally:
        sub.close()
