"""Cameras on hardware: a V4L2/UVC device, a video file or stream through OpenCV
(:mod:`~.opencv_source`), an Intel RealSense or its recording through pyrealsense2
(:mod:`~.realsense_source`); a ROS 2 image topic is :mod:`sim2real.deploy.ros2.camera`. Each keeps
its newest frame and its capture time in a :class:`~.feed.CameraFeed`, whose ``fill(frame)`` the
runtime's camera stage (:mod:`sim2real.deploy.runtime.camera`) reads as it reads the simulated
camera; :mod:`~.convert` makes a driver's frame what the policy's block reads;
:mod:`~.options` reads ``deploy-run --camera-source NAME=KIND:WHERE``.
"""
