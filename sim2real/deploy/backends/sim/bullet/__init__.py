"""The plant on pybullet, a second physics engine for sim-to-sim checks (see :mod:`.plant`)."""
