"""Robot descriptions (MJCF plus robot.toml) and their loader.

>>> from sim2real.robots import load_robot
>>> arm = load_robot("arm3")
>>> arm.joint_names
('shoulder', 'elbow', 'wrist')

The names below load on first use: the lowest floor's light modules (:mod:`sim2real.robots.errors`,
:mod:`sim2real.robots.files`) import without MuJoCo or Pinocchio.
"""

from __future__ import annotations

from sim2real.robots.lazy import lazy_names

#: public name -> module of this package that defines it
_SOURCES = {
    "CONTROL_MODES": "sim2real.robots.schema",
    "MotorConfig": "sim2real.robots.schema",
    "RobotConfig": "sim2real.robots.schema",
    "Robot": "sim2real.robots.robot",
    "RobotSpecError": "sim2real.robots.robot",
    "load_robot": "sim2real.robots.loading",
    "resolve_robot_toml": "sim2real.robots.loading",
}

__all__ = sorted(_SOURCES)


__getattr__ = lazy_names(__name__, _SOURCES, globals())
