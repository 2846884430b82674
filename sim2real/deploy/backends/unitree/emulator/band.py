"""The gantry a humanoid hangs from before it stands on its own: unitree_mujoco's elastic band.

unitree_mujoco (``simulate_python/unitree_sdk2py_bridge.py``, ``ElasticBand``; applied in
``unitree_mujoco.py`` before every ``mj_step`` while enabled) pulls the robot's ``torso_link``
(``base_link``, the floating base, for a quadruped) towards a point 3 m above the origin with a spring of rest
length ``length`` and a damper along the band:

    d = point - p,  f = (STIFFNESS (|d| - length) - DAMPING (v . d / |d|)) d / |d|

``p`` and ``v`` are the free joint's position and linear velocity (``qpos[:3]``, ``qvel[:3]``),
the force at the body's centre of mass (``xfrc_applied``). Its viewer's keys lengthen it by
0.1 m (``8``) and release it (``9``); here ``--band LENGTH@RELEASE`` sets the length (the
length at which the G1 stands with the band carrying most of its weight: docs/unitree.md) and
releases it ``RELEASE`` s after the first LowCmd, as the operator presses ``9`` (no release
time: it holds for good).
"""

from __future__ import annotations

import numpy as np

#: unitree_mujoco ``ElasticBand``: N/m, N s/m, and the point it hangs from, m (world).
STIFFNESS = 200.0
DAMPING = 100.0
POINT = np.array([0.0, 0.0, 3.0])
BAND_HELP = (
    "LENGTH[@RELEASE]: hang the robot's torso_link (its floating base without one) from "
    "unitree_mujoco's elastic band (200 N/m, 100 N s/m, from 3 m above the origin) of rest "
    "length LENGTH m (0.8: the G1's feet on the floor, the band carrying most of its weight), "
    "released RELEASE s after the first LowCmd (none: never)"
)


def parse_band(text: str) -> tuple[float, float | None]:
    """``(length m, release s or None)`` of ``LENGTH[@RELEASE]``.

    Raises:
        ValueError: not two numbers, a negative length or release time (naming the text).
    """
    length, _, release = text.partition("@")
    try:
        values = float(length), (float(release) if release else None)
    except ValueError:
        raise ValueError(f"--band {text!r}: expected LENGTH[@RELEASE], m and s") from None
    if not (values[0] >= 0.0 and (values[1] is None or values[1] >= 0.0)):
        raise ValueError(f"--band {text!r}: expected a length and a release time >= 0")
    return values


class ElasticBand:
    """unitree_mujoco's elastic band on one body of a simulated plant (module docstring).

    Args:
        plant: The :class:`~sim2real.deploy.backends.sim.plant.SimBackend` (one env).
        length: The band's rest length, m. release: s after the first LowCmd at which it lets
            go (None: never).
        body: The body it holds: ``torso_link`` when the model has one, else the floating base
            (unitree_mujoco's ``base_link`` of its quadrupeds).

    Attributes:
        released: Whether it has let go. force: (3,) N, the last force applied (world frame).
    """

    def __init__(self, plant, length: float, release: float | None, body: str | None = None):
        self.plant, self.length, self.release = plant, float(length), release
        names = {plant.models[0].body(i).name for i in range(plant.models[0].nbody)}
        self.body = body or ("torso_link" if "torso_link" in names else plant.robot.base_body)
        if self.body not in names:
            raise ValueError(f"--band: the model has no body '{self.body}' to hang")
        self.released = False
        self.force = np.zeros(3)
        self._base = np.zeros((1, 13))

    def apply(self, elapsed: float | None) -> None:
        """Set this physics step's band force; ``elapsed``: s since the first LowCmd (None:
        none yet). At the release time the force goes to zero for good."""
        if self.released:
            return
        if self.release is not None and elapsed is not None and elapsed >= self.release:
            self.released = True
            self.force[:] = 0.0
        else:
            base = self.plant.true_base_state(out=self._base)[0]
            d = POINT - base[:3]
            distance = float(np.linalg.norm(d))
            direction = d / distance
            v = float(base[7:10] @ direction)
            self.force[:] = (STIFFNESS * (distance - self.length) - DAMPING * v) * direction
        self.plant.set_external_force(0, self.force, self.body)
