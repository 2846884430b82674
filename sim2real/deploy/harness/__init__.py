"""The top floor of ``deploy``: hardware-in-the-loop harnesses, each an emulator of a real
interface started beside ``deploy-run`` with its own command line.

- :mod:`sim2real.deploy.harness.servo_hil`: the serial-bus servos (Feetech, Dynamixel) on a pseudo-terminal;
- :mod:`sim2real.deploy.harness.unitree_hil`: a Unitree robot's low-level DDS topics;
- :mod:`sim2real.deploy.harness.ros2_hil`: a robot behind ROS 2 topics;
- :mod:`sim2real.deploy.harness.common`: what they share (command line, emulator process, deploy-run).

A harness may import every room below it (the command line's parser, the runtime, the emulators);
nothing imports a harness.
"""
