"""Robot descriptions (MJCF plus robot.toml) and their loader.

>>> from robots import load_robot
>>> arm = load_robot("arm3")
>>> arm.joint_names
('shoulder', 'elbow', 'wrist')

The names below load on first use: the lowest floor's light modules (:mod:`robots.errors`,
:mod:`robots.files`) import without MuJoCo or Pinocchio.
"""

from __future__ import annotations

import importlib

#: public name -> module of this package that defines it
_SOURCES = {
    "CONTROL_MODES": "robots.schema",
    "MotorConfig": "robots.schema",
    "RobotConfig": "robots.schema",
    "Robot": "robots.robot",
    "RobotSpecError": "robots.robot",
    "load_robot": "robots.loading",
    "resolve_robot_toml": "robots.loading",
}

__all__ = sorted(_SOURCES)


def __getattr__(name: str):
    """Import a public name's module on first use."""
    if name not in _SOURCES:
        raise AttributeError(f"module 'robots' has no attribute {name!r}")
    value = getattr(importlib.import_module(_SOURCES[name]), name)
    globals()[name] = value
    return value
