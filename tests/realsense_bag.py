"""A RealSense recording written without a camera: a ``.bag`` (ROS 1 bag, librealsense's file
version 3) of one depth stream, written by the ``rosbags`` package in the layout librealsense's
own recorder writes and its reader (``src/media/ros/ros_reader.cpp``) plays back: the topics of
``ros_file_format.h`` (``ros_topic``), the message types of ``ros_writer.cpp`` (the device and
sensor descriptions as ``diagnostic_msgs/KeyValue``, the stream's ``realsense_msgs/StreamInfo``
and ``sensor_msgs/CameraInfo``, the ``Depth Units`` option as ``std_msgs/Float32``, each frame a
``sensor_msgs/Image`` ``mono16`` (librealsense's name for ``z16``) with its metadata). The static
description is stamped 1 ns (the bag reader refuses a zero time)."""

from __future__ import annotations

import numpy as np

#: realsense_msgs/StreamInfo as librealsense defines it (its md5sum 311d7e24eac31bb87271d041bf70ff7d,
#: third-party/realsense-file/rosbag/msgs/realsense_msgs/StreamInfo.h).
STREAM_INFO = """# This message defines meta information for a stream
# The stream type is expressed in the topic name

uint32 fps        # The nominal streaming rate, defined in Hz
string encoding   # Stream's data format
bool is_recommended # Is this stream recommended by RealSense SDK
"""
DEPTH = "/device_0/sensor_0/Depth_0"


def write_depth_bag(path, frames, fps: float, depth_unit: float, first_ms: float = 1000.0):
    """``frames`` ((rows, columns) uint16 depth units) into a bag at ``path``, frame ``k``
    stamped ``first_ms + k * 1000 / fps`` ms (``system_time`` domain); the sensor's depth unit
    ``depth_unit`` m. Returns the stamps, ms."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg(STREAM_INFO, "realsense_msgs/msg/StreamInfo"))
    t = ts.types
    rows, cols = frames[0].shape
    kv = "diagnostic_msgs/msg/KeyValue"

    def stamp(ns: int):
        return t["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)

    def header(seq: int, ns: int):
        return t["std_msgs/msg/Header"](seq=seq, stamp=stamp(ns), frame_id="")

    stamps = [first_ms + k * 1000.0 / fps for k in range(len(frames))]
    with Writer(path) as w:
        conns: dict = {}

        def put(topic, kind, msg, when):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, kind, typestore=ts)
            w.write(conns[topic], when, ts.serialize_ros1(msg, kind))

        put("/file_version", "std_msgs/msg/UInt32", t["std_msgs/msg/UInt32"](data=3), 1)
        for key, value in (("Name", "Intel RealSense D435"), ("Serial Number", "000000000001"),
                           ("Product Id", "FFFF")):  # fmt: skip  # no D400 id: no filters
            put("/device_0/info", kv, t[kv](key=key, value=value), 1)
        put("/device_0/sensor_0/info", kv, t[kv](key="Name", value="Stereo Module"), 1)
        info = t["realsense_msgs/msg/StreamInfo"](fps=int(fps), encoding="mono16",
                                                  is_recommended=True)  # fmt: skip
        put(f"{DEPTH}/info", "realsense_msgs/msg/StreamInfo", info, 1)
        roi = t["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        camera = t["sensor_msgs/msg/CameraInfo"](
            header=header(0, 0), height=rows, width=cols, distortion_model="Brown Conrady",
            D=np.zeros(5), K=np.array([10.0, 0, cols / 2, 0, 10.0, rows / 2, 0, 0, 1]),
            R=np.eye(3).ravel(), P=np.zeros(12), binning_x=0, binning_y=0, roi=roi,
        )  # fmt: skip
        put(f"{DEPTH}/info/camera_info", "sensor_msgs/msg/CameraInfo", camera, 1)
        option = "/device_0/sensor_0/option/Depth Units"
        put(
            f"{option}/value", "std_msgs/msg/Float32", t["std_msgs/msg/Float32"](data=depth_unit), 1
        )
        put(f"{option}/description", "std_msgs/msg/String",
            t["std_msgs/msg/String"](data="Number of meters represented by a single depth unit"), 1)  # fmt: skip
        for k, (image, ms) in enumerate(zip(frames, stamps, strict=True)):
            when = 10**9 + round(k * 1e9 / fps)
            data = np.ascontiguousarray(image, dtype="<u2").view(np.uint8).ravel()
            msg = t["sensor_msgs/msg/Image"](
                header=header(k, round(ms * 1e6)), height=rows, width=cols, encoding="mono16",
                is_bigendian=0, step=cols * 2, data=data,
            )  # fmt: skip
            put(f"{DEPTH}/image/data", "sensor_msgs/msg/Image", msg, when)
            for key, value in (("timestamp_domain", "System Time"), ("system_time", str(int(ms)))):
                put(f"{DEPTH}/image/metadata", kv, t[kv](key=key, value=value), when)
    return stamps
