"""Slow drift of the plant over a session (:class:`DriftRanges`): dry friction rising with wear,
applied to the session's compiled model in place with :func:`apply_drift`.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from sim2real.eval.world.checks import check_range
from sim2real.robots import Robot


@dataclass(frozen=True)
class DriftRanges:
    """Slow drift of the plant over a session.

    Attributes:
        friction_rate: Rise of each joint's dry friction (``frictionloss``) per hour, as a
            fraction of its value at the session start: wear. Our choice: 1-6 % per hour, i.e.
            +8 to +48 % over an 8-hour session.
    """

    friction_rate: tuple[float, float] = (0.01, 0.06)

    def __post_init__(self):
        check_range("DriftRanges", "friction_rate", *self.friction_rate)


@dataclass(frozen=True)
class Drift:
    """One session's drift: ``friction_rate`` per joint, 1/h (see :class:`DriftRanges`)."""

    friction_rate: tuple[float, ...]

    def to_dict(self) -> dict:
        return {"friction_rate": list(self.friction_rate)}

    @classmethod
    def from_dict(cls, data: dict) -> Drift:
        return cls(tuple(float(x) for x in data["friction_rate"]))

    def friction(self, initial: np.ndarray, t: float) -> np.ndarray:
        """Dry friction (N m, (n,)) at session time ``t`` (s) from its ``initial`` value:
        ``initial * (1 + friction_rate * t / 3600)``."""
        return np.asarray(initial, dtype=np.float64) * (
            1.0 + np.asarray(self.friction_rate) * t / 3600.0
        )


def sample_drift(
    robot: Robot, rng: np.random.Generator, ranges: DriftRanges | None = None
) -> Drift:
    """Draw one :class:`Drift` for ``robot`` from ``rng`` (uniform, independent per joint)."""
    ranges = DriftRanges() if ranges is None else ranges
    return Drift(tuple(float(x) for x in rng.uniform(*ranges.friction_rate, robot.n_joints)))


def joint_dofs(model: mujoco.MjModel, robot: Robot) -> np.ndarray:
    """Indices (n,) of the robot's joints, in its joint order, in ``model``'s DoF arrays.

    Raises:
        ValueError: a joint of the robot is missing from the model.
    """
    dofs = []
    for name in robot.joint_names:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise ValueError(f"joint_dofs: joint '{name}' is not in the MuJoCo model")
        dofs.append(int(model.jnt_dofadr[jid]))
    return np.array(dofs)


def apply_drift(
    model: mujoco.MjModel, robot: Robot, initial_friction: np.ndarray, drift: Drift, t: float
) -> np.ndarray:
    """Set ``model.dof_frictionloss`` (in place, on the compiled model a session steps) to the
    drifted friction at session time ``t`` (s); returns the new values (N m, (n,)).

    ``initial_friction`` is the joints' friction at the session start (after
    :func:`apply_dynamics`), in the robot's joint order.
    """
    value = drift.friction(initial_friction, t)
    model.dof_frictionloss[joint_dofs(model, robot)] = value
    return value
