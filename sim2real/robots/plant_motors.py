"""The robot's motors as the plant simulates them, when they differ from its description: a
"plant motors" file, the truth an emulated robot runs on and an identification must find.

The robot folder describes the motors the policy, the guard and the soak's judgement assume. A
plant motors file changes only what the simulated plant does (the MuJoCo and pybullet plants, the
emulators behind them), never the robot's contract (its description hash stays)::

    source = "a worn SO-101: friction x3, armature x2, a 20 % weaker line, 8 ms delay"
    [motors.sts3215]            # MotorConfig fields replacing the motor's own
    command_delay = 0.008       # s
    max_velocity = 3.77         # rad/s: the torque-speed line's no-load speed
    [joints."*"]                # shell pattern of joint names
    friction_scale = 3.0        # factors on the MJCF's dry friction (dof_frictionloss),
    armature_scale = 2.0        # reflected rotor inertia (dof_armature)
    damping_scale = 1.0         # and viscous damping (dof_damping)
    [joints.gripper]
    friction = 0.05             # or values: N m, kg m^2 (armature), N m s/rad (damping)

Joint tables apply in file order: a value replaces the joint's, a factor multiplies what an
earlier table left.
"""

from __future__ import annotations

import dataclasses
import fnmatch
from pathlib import Path

import mujoco
import numpy as np
from pydantic import Field, ValidationError

from sim2real.robots.robot import Robot, RobotSpecError
from sim2real.robots.schema import MotorConfig, NonNegative, _Strict

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib


#: The joint properties a file sets, and MuJoCo's model fields they are.
JOINT_FIELDS = {
    "friction": "dof_frictionloss",
    "armature": "dof_armature",
    "damping": "dof_damping",
}


class JointFactors(_Strict):
    """A joint table: values replacing the MJCF's (None: kept) and factors on them (1.0)."""

    friction: NonNegative | None = None  # N m, dry (Coulomb) friction
    armature: NonNegative | None = None  # kg m^2, reflected rotor inertia
    damping: NonNegative | None = None  # N m s/rad, viscous damping
    friction_scale: NonNegative = 1.0
    armature_scale: NonNegative = 1.0
    damping_scale: NonNegative = 1.0


class PlantMotorsFile(_Strict):
    """The whole plant motors file (module docstring)."""

    source: str = Field(min_length=10)
    motors: dict[str, dict] = Field(default_factory=dict)
    joints: dict[str, JointFactors] = Field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class PlantMotors:
    """A plant motors file applied to a robot.

    Attributes:
        path: The file.
        robot: The robot with its motors replaced (its description and hash unchanged).
        values: (n, 3) friction (N m), armature (kg m^2) and damping (N m s/rad) per joint,
            NaN where the file keeps the model's.
        factors: (n, 3) factors on them.
    """

    path: Path
    robot: Robot
    values: np.ndarray
    factors: np.ndarray

    def apply(self, model: mujoco.MjModel) -> mujoco.MjModel:
        """Set ``model``'s (a plant model of the robot) joint friction, armature and damping to
        the file's values and factors, in place; returns it."""
        for i, name in enumerate(self.robot.joint_names):
            dof = model.jnt_dofadr[model.joint(name).id]
            for k, field in enumerate(JOINT_FIELDS.values()):
                column = getattr(model, field)
                if np.isfinite(self.values[i, k]):
                    column[dof] = self.values[i, k]
                column[dof] *= self.factors[i, k]
        return model


def load_plant_motors(path: str | Path, robot: Robot) -> PlantMotors:
    """Read a plant motors file for ``robot``.

    Raises:
        RobotSpecError: an unreadable file or invalid TOML; a field that is missing, unknown or
            out of range; a motor the robot does not use; a joint pattern that matches no joint
            (each named with the file and the field).
    """
    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
        doc = PlantMotorsFile.model_validate(raw)
    except OSError as exc:
        raise RobotSpecError(f"{path}: cannot read: {exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise RobotSpecError(f"{path}: not valid TOML: {exc}") from None
    except ValidationError as exc:
        err = exc.errors()[0]
        field = ".".join(str(p) for p in err["loc"])
        raise RobotSpecError(f"{path}: field '{field}': {err['msg']}") from None
    used = robot.config.motors
    replaced = {}
    for name, overrides in doc.motors.items():
        if name not in used:
            raise RobotSpecError(
                f"{path}: field 'motors.{name}': the robot {robot.name} uses no motor '{name}' "
                f"(it uses {sorted(used)})"
            )
        try:
            replaced[name] = MotorConfig.model_validate({**used[name].model_dump(), **overrides})
        except ValidationError as exc:
            err = exc.errors()[0]
            field = ".".join(str(p) for p in err["loc"])
            raise RobotSpecError(f"{path}: field 'motors.{name}.{field}': {err['msg']}") from None
    motors = tuple(
        replaced.get(joint.motor, motor)
        for joint, motor in zip(robot.config.joints, robot.motors, strict=True)
    )
    values, factors = np.full((robot.n_joints, 3), np.nan), np.ones((robot.n_joints, 3))
    for pattern, f in doc.joints.items():
        hit = [i for i, n in enumerate(robot.joint_names) if fnmatch.fnmatchcase(n, pattern)]
        if not hit:
            raise RobotSpecError(
                f"{path}: field 'joints.{pattern}': matches no joint of {robot.name} "
                f"({', '.join(robot.joint_names)})"
            )
        for k, name in enumerate(JOINT_FIELDS):
            if getattr(f, name) is not None:
                values[hit, k] = getattr(f, name)
                factors[hit, k] = 1.0
            factors[hit, k] *= getattr(f, f"{name}_scale")
    return PlantMotors(path, dataclasses.replace(robot, motors=motors), values, factors)
