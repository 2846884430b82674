"""Randomized dynamics: seeded samplers and appliers for the plant's masses, lengths, friction.

Training (:mod:`sim2real.policies.envs`) and the soak harness draw from the same samplers, so a policy is
trained and tested on the same family of "slightly broken worlds". Every draw is a
plain dataclass that can be written to a report and replayed exactly.

Dynamics (``DynamicsRanges``; defaults: the ranges the toolkit was specified with):

===================  ==========  ===================================================================
quantity             default     applied to (``mujoco.MjSpec`` before compiling)
===================  ==========  ===================================================================
link length          +-10 %      every moving body's frame contents: child body and site positions,
                                 geom positions, ``fromto`` and sizes, centre of mass; inertia x s^2
mass                 +-20 %      body mass and inertia (same factor: the shape is unchanged)
joint friction       +-50 %      ``frictionloss`` (dry friction, N m)
joint damping        +-50 %      ``damping`` (viscous, N m s/rad)
actuator strength    +-10 %      servo gains kp, kd (position, velocity mode); motor gear (torque)
kp, kd               none        servo gain kp, or kd, alone (position, velocity mode; legged_gym
                                 forks' ``stiffness_multi_range``, ``damping_multi_range``)
armature             none        ``armature`` (reflected rotor inertia, kg m^2)
===================  ==========  ===================================================================

The runtime keeps the nominal Pinocchio model: randomization is the gap between what the runtime
believes the robot is and what the plant is.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from sim2real.robots import Robot


@dataclass(frozen=True)
class DynamicsRanges:
    """Relative half-ranges of the dynamics factors: a factor is drawn from ``U(1 - r, 1 + r)``.

    Attributes:
        link_length: Link length (default +-10 %).
        mass: Link mass (default +-20 %).
        friction: Joint dry friction (default +-50 %).
        damping: Joint viscous damping.
        actuator_strength: Servo gains or motor gear.
        supply_voltage: The motors' supply voltage (a battery's charge), one draw per robot: a
            motor's torque-speed line (its stall torque and no-load speed) scales with it
            (:mod:`sim2real.robots.torque_speed`; motors without a no-load speed are unaffected). Default
            0: drawn only when set, so that sessions drawn before it are drawn the same.
        kp, kd: A servo's position gain, or its damping gain, alone (the position and velocity
            modes' actuators; a torque-mode plant has none: refused there by the plant). Default
            0, drawn only when set, as ``supply_voltage``.
        armature: Each joint's armature. Default 0, drawn only when set.
    """

    link_length: float = 0.10
    mass: float = 0.20
    friction: float = 0.50
    damping: float = 0.50
    actuator_strength: float = 0.10
    supply_voltage: float = 0.0
    kp: float = 0.0
    kd: float = 0.0
    armature: float = 0.0

    def __post_init__(self):
        for name, value in asdict(self).items():
            if not 0.0 <= value < 1.0:
                raise ValueError(f"DynamicsRanges.{name}: expected a value in [0, 1), got {value}")

    @classmethod
    def none(cls) -> DynamicsRanges:
        """No randomization: the nominal robot."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Dynamics:
    """One draw of dynamics factors, one per moving link / joint (tuples of length n_joints).

    A factor of 1.0 is the nominal value. ``Dynamics.nominal(n)`` is the unrandomized robot.
    """

    link_length: tuple[float, ...]
    mass: tuple[float, ...]
    friction: tuple[float, ...]
    damping: tuple[float, ...]
    actuator_strength: tuple[float, ...]
    supply_voltage: tuple[float, ...] = ()  # one value for every motor; () is nominal (1.0)
    kp: tuple[float, ...] = ()  # per joint; () is nominal (1.0), as kd and armature
    kd: tuple[float, ...] = ()
    armature: tuple[float, ...] = ()

    @classmethod
    def nominal(cls, n_joints: int) -> Dynamics:
        ones = (1.0,) * n_joints
        return cls(ones, ones, ones, ones, ones, ones)

    def factor(self, name: str, joint: int) -> float:
        """Joint ``joint``'s factor of ``kp``, ``kd`` or ``armature`` (1.0 when not drawn)."""
        values = getattr(self, name)
        return values[joint] if values else 1.0

    @property
    def supply(self) -> float:
        """The supply voltage over its nominal value (1.0 when not drawn)."""
        return self.supply_voltage[0] if self.supply_voltage else 1.0

    def to_dict(self) -> dict[str, list[float]]:
        """Lists by field; a nominal supply voltage is left out (as results and checkpoints
        written before it have it)."""
        out = {k: list(v) for k, v in asdict(self).items()}
        if self.supply == 1.0:
            out.pop("supply_voltage")
        for key in ("kp", "kd", "armature"):  # not drawn: left out, as before they were
            if all(v == 1.0 for v in out[key]):
                out.pop(key)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Dynamics:
        n = len(data["mass"])  # results written before supply_voltage have none: nominal
        ones = {"kp": [], "kd": [], "armature": []}  # not drawn: nominal
        return cls(
            **{
                k: tuple(float(x) for x in data.get(k, ones.get(k, [1.0] * n)))
                for k in cls.__dataclass_fields__
            }
        )


def sample_dynamics(
    robot: Robot, rng: np.random.Generator, ranges: DynamicsRanges | None = None
) -> Dynamics:
    """Draw one :class:`Dynamics` for ``robot`` from ``rng`` (uniform, independent per joint)."""
    ranges = DynamicsRanges() if ranges is None else ranges
    n = robot.n_joints

    def draw(r: float) -> tuple[float, ...]:
        return tuple(float(x) for x in rng.uniform(1.0 - r, 1.0 + r, n))

    return Dynamics(
        link_length=draw(ranges.link_length),
        mass=draw(ranges.mass),
        friction=draw(ranges.friction),
        damping=draw(ranges.damping),
        actuator_strength=draw(ranges.actuator_strength),
        # one battery for every motor; no draw when not randomized (earlier sessions' streams)
        supply_voltage=(float(rng.uniform(1.0 - r, 1.0 + r)),) * n
        if (r := ranges.supply_voltage) > 0.0
        else (1.0,) * n,
        # drawn after the others, only when set: earlier sessions' streams stay as they were
        kp=draw(ranges.kp) if ranges.kp > 0.0 else (),
        kd=draw(ranges.kd) if ranges.kd > 0.0 else (),
        armature=draw(ranges.armature) if ranges.armature > 0.0 else (),
    )


def apply_dynamics(spec: mujoco.MjSpec, robot: Robot, dynamics: Dynamics, mode: str) -> None:
    """Edit ``spec`` (from ``robot.mjspec(mode)``) in place to the randomized dynamics.

    The moving body of joint ``i`` is scaled by ``dynamics.link_length[i]`` about its own frame
    (so its child bodies, sites and geoms move out with it and the link's centre of mass and
    inertia stay those of the same shape), and its mass and inertia by ``dynamics.mass[i]``.

    Raises:
        ValueError: a joint of the robot is missing from the spec.
    """
    for i, name in enumerate(robot.joint_names):
        joint = spec.joint(name)
        if joint is None:
            raise ValueError(f"apply_dynamics: joint '{name}' is not in the MuJoCo spec")
        body = joint.parent
        s, m = dynamics.link_length[i], dynamics.mass[i]
        for child in body.bodies:
            child.pos = np.asarray(child.pos) * s
        for site in body.sites:
            site.pos = np.asarray(site.pos) * s
        for geom in body.geoms:
            geom.pos = np.asarray(geom.pos) * s
            geom.size = np.asarray(geom.size) * s
            fromto = np.asarray(geom.fromto)
            if np.isfinite(fromto).all():
                geom.fromto = fromto * s
        body.ipos = np.asarray(body.ipos) * s
        body.mass = body.mass * m
        body.inertia = np.asarray(body.inertia) * (m * s * s)
        joint.frictionloss = joint.frictionloss * dynamics.friction[i]
        joint.damping = joint.damping * dynamics.damping[i]
        joint.armature = joint.armature * dynamics.factor("armature", i)
    index = {name: i for i, name in enumerate(robot.joint_names)}
    if mode == "torque" and (dynamics.kp or dynamics.kd):
        raise ValueError("apply_dynamics: kp and kd factors need servo gains; torque mode has none")
    for act in spec.actuators:  # every actuator of a joint (velocity mode: the PI loop's two)
        i = index[act.target]
        k = dynamics.actuator_strength[i]
        if mode == "torque":
            gear = np.asarray(act.gear)
            gear[0] *= k
            act.gear = gear
        else:
            kp, kd = k * dynamics.factor("kp", i), k * dynamics.factor("kd", i)
            gain, bias = np.asarray(act.gainprm), np.asarray(act.biasprm)
            gain[0] *= kp
            bias[1] *= kp
            bias[2] *= kd
            act.gainprm, act.biasprm = gain, bias


def randomized_model(
    robot: Robot, mode: str, dynamics: Dynamics, ground: Callable | None = None
) -> mujoco.MjModel:
    """Compiled plant model of ``robot`` in control ``mode`` with ``dynamics`` applied, and
    ``ground(spec)`` (a terrain laid into the spec, :func:`sim2real.eval.world.terrain.apply_terrain`)
    when given."""
    spec = robot.mjspec(mode)
    apply_dynamics(spec, robot, dynamics, mode)
    if ground is not None:
        ground(spec)
    return spec.compile()


@dataclass(frozen=True)
class ComOffsetRanges:
    """A shift of one body's centre of mass, drawn once per session: a ranges file's
    ``[dynamics] com_offset = {body = "torso_link", x = [-0.05, 0.05], ...}`` (mjlab's
    ``base_com`` event, unitree_rl_mjlab ``mjlab/tasks/velocity/velocity_env_cfg.py``:
    ``body_ipos`` plus U(-0.05, 0.05) m per axis, the body set per robot, the G1's
    ``torso_link``). Floating- and fixed-base robots alike; :func:`shift_com` applies a draw.

    Attributes:
        body: The body (a name of the robot's MJCF); empty: the robot's base body.
        x, y, z: The offset's range ``(low, high)`` per axis, m, in the body's frame; None: 0.

    Raises:
        ValueError: an inverted or non-finite range (a body the robot lacks: :meth:`body_of`).
    """

    body: str = ""
    x: tuple[float, float] | None = None
    y: tuple[float, float] | None = None
    z: tuple[float, float] | None = None

    def __post_init__(self):
        for axis in ("x", "y", "z"):
            r = getattr(self, axis)
            if r is not None and not (np.isfinite(r).all() and r[0] <= r[1]):
                raise ValueError(f"ComOffsetRanges.{axis}: expected a range low <= high, got {r}")

    def body_of(self, robot: Robot) -> str:
        """The body the offset moves (``body``, else the robot's base body).

        Raises:
            ValueError: a body the robot's MJCF does not have (naming its bodies).
        """
        name = self.body or robot.base_body
        bodies = [robot.mj_model.body(i).name for i in range(1, robot.mj_model.nbody)]
        if name not in bodies:
            raise ValueError(
                f"ComOffsetRanges.body: '{name}' is no body of robot {robot.name} (its bodies: "
                f"{bodies})"
            )
        return name

    def sample(self, rng: np.random.Generator) -> tuple[float, float, float]:
        """One offset, m (x, y, z), uniform per axis."""
        return tuple(
            float(rng.uniform(*r)) if r is not None else 0.0 for r in (self.x, self.y, self.z)
        )


def shift_com(model: mujoco.MjModel, body: str, offset) -> None:
    """Move ``body``'s centre of mass by ``offset`` (3,) m in its frame (``body_ipos``) in the
    compiled ``model``, in place, and recompute the derived constants (``mj_setConst``)."""
    model.body_ipos[model.body(body).id] += np.asarray(offset, dtype=float)
    mujoco.mj_setConst(model, mujoco.MjData(model))


def add_base_mass(model: mujoco.MjModel, robot: Robot, kg: float, body_name: str = "") -> None:
    """Add ``kg`` to the mass of ``robot``'s base body (or of ``body_name``) in the compiled
    ``model``, in place, its inertia unchanged (legged_gym's ``randomize_base_mass``: a payload at
    the body's centre of mass), and recompute the model's derived constants (``mj_setConst``).

    Raises:
        ValueError: a fixed-base robot, or a body whose mass would not stay positive.
    """
    if not robot.floating_base:
        raise ValueError(f"add_base_mass: robot {robot.name} has no floating base")
    name = body_name or robot.base_body
    body = model.body(name).id
    if not model.body_mass[body] + kg > 0:
        raise ValueError(
            f"add_base_mass: {kg} kg leaves the body '{name}' of robot {robot.name} "
            f"without mass (it has {model.body_mass[body]:.3f} kg)"
        )
    model.body_mass[body] += kg
    mujoco.mj_setConst(model, mujoco.MjData(model))
