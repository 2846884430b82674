"""The operator: input sources (the Unitree remote, ROS 2 ``sensor_msgs/Joy``, an evdev gamepad
and its recorded stream, the terminal keyboard) behind one seam, a mapping file, the state machine
around the runtime (PASSIVE, STAND, POLICY, DAMP) with its authority table, and the rig's hook
that runs it (docs/operator.md).
"""
