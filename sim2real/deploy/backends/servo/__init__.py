"""Serial-bus servos: their control tables, unit conversions and wire protocols.

Pure Python, no vendor SDK imported here; shared by the wire-protocol emulator
(:mod:`sim2real.deploy.backends.emulator`) and the servo-bus backends that drive real servos through the
vendors' SDKs.

- :mod:`sim2real.deploy.backends.servo.control_tables`: register maps of the Feetech STS3215 and the
  Dynamixel XM430-W350 / XL430-W250, their encodings and the tick / SI conversions.
- :mod:`sim2real.deploy.backends.servo.feetech_protocol`: the Feetech SCS/STS packet codec (checksum).
- :mod:`sim2real.deploy.backends.servo.dynamixel_protocol`: the Dynamixel Protocol 2.0 packet codec
  (CRC-16, byte stuffing).
"""
