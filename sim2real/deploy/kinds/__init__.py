"""Robot kinds beyond the two of :mod:`sim2real.deploy.robot_kind` (an arm, a legged robot),
one module each, registered by :data:`sim2real.deploy.robot_kind.KIND_REGISTRY`'s ``builtin``."""
