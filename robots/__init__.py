"""Robot descriptions (MJCF plus robot.toml) and their loader.

>>> from robots import load_robot
>>> arm = load_robot("arm3")
>>> arm.joint_names
('shoulder', 'elbow', 'wrist')

The names below load on first use: the lowest floor's light modules (:mod:`robots.errors`,
:mod:`robots.files`) import without MuJoCo or Pinocchio.
"""

from __future__ import annotations

from robots.lazy import lazy_names

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


__getattr__ = lazy_names(__name__, _SOURCES, globals())
