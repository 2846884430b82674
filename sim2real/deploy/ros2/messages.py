"""The runtime's state as ROS 2 messages (REP 103 units and frames: SI, radians, x forward z up).

Each function fills a message it is given (the node keeps one of each and reuses it) from a
:class:`~sim2real.deploy.ros2.snapshot.TickSnapshot`, so nothing but the message's own arrays is built per
tick. Message types: ``sensor_msgs/JointState``, ``sensor_msgs/Imu``, ``nav_msgs/Odometry``,
``diagnostic_msgs/DiagnosticArray`` (one :class:`Status` per part, in the shape the
``diagnostic_aggregator`` groups: ``name`` ``'<node>: <part>'``, ``hardware_id`` the robot).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: ``diagnostic_msgs/DiagnosticStatus`` levels.
OK, WARN, ERROR, STALE = 0, 1, 2, 3


@dataclass
class Status:
    """One ``DiagnosticStatus``: ``level`` (``OK``, ``WARN``, ``ERROR``), ``name``,
    ``message`` (one line), ``values`` (key -> value, written as text)."""

    level: int
    name: str
    message: str
    values: dict = field(default_factory=dict)


def fill_joint_state(msg, snap, stamp, effort: bool) -> None:
    """``sensor_msgs/JointState``: the estimated positions (rad) and velocities (rad/s); with
    ``effort`` (torque mode) the commanded torques (N m), else no efforts. ``msg.name`` is set
    once by the caller (the robot's joint order)."""
    msg.header.stamp = stamp
    msg.position = snap.q
    msg.velocity = snap.dq
    if effort:
        msg.effort = snap.command


def fill_imu(msg, snap, stamp) -> None:
    """``sensor_msgs/Imu``: the base orientation estimate (yaw unobserved: it drifts), the
    gyroscope rate with its bias removed (rad/s) and the accelerometer's specific force
    (m/s^2), in the base frame. Covariances unknown: element 0 of each is -1 where the reading
    is missing (REP 145), else 0."""
    msg.header.stamp = stamp
    w, x, y, z = snap.orientation
    o = msg.orientation
    o.w, o.x, o.y, o.z = float(w), float(x), float(y), float(z)
    av = msg.angular_velocity
    av.x, av.y, av.z = (float(v) for v in snap.angular_velocity)
    acc = snap.acceleration
    la = msg.linear_acceleration
    if np.isfinite(acc).all():
        la.x, la.y, la.z = (float(v) for v in acc)
        msg.linear_acceleration_covariance[0] = 0.0
    else:
        msg.linear_acceleration_covariance[0] = -1.0


def fill_odometry(msg, snap, stamp) -> None:
    """``nav_msgs/Odometry``: the base's dead-reckoned pose in the odometry frame (its yaw
    drifts with the attitude filter's) and its velocity in the base frame (``child_frame_id``)."""
    msg.header.stamp = stamp
    pose = msg.pose.pose
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in snap.position)
    w, x, y, z = snap.orientation
    pose.orientation.w, pose.orientation.x = float(w), float(x)
    pose.orientation.y, pose.orientation.z = float(y), float(z)
    tw = msg.twist.twist
    tw.linear.x, tw.linear.y, tw.linear.z = (float(v) for v in snap.linear_velocity)
    tw.angular.x, tw.angular.y, tw.angular.z = (float(v) for v in snap.angular_velocity)


def diagnostic_array(msg_type, status_type, key_value_type, statuses, stamp, hardware_id: str):
    """A ``diagnostic_msgs/DiagnosticArray`` of ``statuses`` (:class:`Status`), stamped."""
    msg = msg_type()
    msg.header.stamp = stamp
    for s in statuses:
        st = status_type()
        st.level = bytes([s.level])
        st.name, st.message, st.hardware_id = s.name, s.message, hardware_id
        st.values = [key_value_type(key=str(k), value=_text(v)) for k, v in s.values.items()]
        msg.status.append(st)
    return msg


def _text(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)
