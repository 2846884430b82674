"""Domain randomization: seeded samplers and appliers for the plant's dynamics.

Training (:mod:`policies.envs`) and the soak harness draw from the same samplers, so a policy is
trained and tested on the same family of "slightly broken worlds" (seed section 5). Every draw is a
plain dataclass that can be written to a report and replayed exactly.

Dynamics (``DynamicsRanges``; defaults from the seed's section 11 "Randomize the arm"):

===================  ==========  ===================================================================
quantity             default     applied to (``mujoco.MjSpec`` before compiling)
===================  ==========  ===================================================================
link length          +-10 %      every moving body's frame contents: child body and site positions,
                                 geom positions, ``fromto`` and sizes, centre of mass; inertia x s^2
mass                 +-20 %      body mass and inertia (same factor: the shape is unchanged)
joint friction       +-50 %      ``frictionloss`` (dry friction, N m)
joint damping        +-50 %      ``damping`` (viscous, N m s/rad)
actuator strength    +-10 %      servo gains kp, kd (position, velocity mode); motor gear (torque)
===================  ==========  ===================================================================

The runtime keeps the nominal Pinocchio model: randomization is the gap between what the
controller believes and the plant it drives.

The soak harness (:mod:`eval.soak`) draws more per session, each from its own named stream of the
session seed (:func:`session_rng`), bundled in :class:`SessionRandomization` by
:func:`sample_session`:

- sensors (:class:`SensorRanges`): encoder noise sigma (seed section 5: 0.002-0.010 on angle / pi),
  latency and dropout, applied with :func:`apply_sensors`; a floating-base robot's IMU and foot
  force noise (:class:`ImuRanges`, seed section 5), :func:`sample_imu` and :func:`apply_imu`;
- a floating-base robot's floor friction (``FLOOR_FRICTION``), applied to the compiled model by
  :func:`apply_floor_friction`;
- slow drift (:class:`DriftRanges`): dry friction rising with wear over the session, applied to the
  session's compiled model in place with :func:`apply_drift`;
- a fault schedule (:mod:`eval.world.fault_schedule`): dropout bursts, stale frames, non-finite
  actions, latency spikes, pushes and a cable pulling on the end effector, as
  :class:`deploy.backends.sim.faults.Fault` for :class:`deploy.backends.sim.faults.FaultInjector`,
  each sized to be survivable in the session's plant.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import mujoco
import numpy as np

from eval.world.fault_schedule import (
    FaultRanges,
    check_range,
    fault_from_dict,
    fault_to_dict,
    sample_fault_schedule,
)
from robots import Robot


@dataclass(frozen=True)
class DynamicsRanges:
    """Relative half-ranges of the dynamics factors: a factor is drawn from ``U(1 - r, 1 + r)``.

    Attributes:
        link_length: Link length (seed section 11: +-10 %).
        mass: Link mass (seed section 11: +-20 %).
        friction: Joint dry friction (seed section 11: +-50 %).
        damping: Joint viscous damping.
        actuator_strength: Servo gains or motor gear.
    """

    link_length: float = 0.10
    mass: float = 0.20
    friction: float = 0.50
    damping: float = 0.50
    actuator_strength: float = 0.10

    def __post_init__(self):
        for name, value in asdict(self).items():
            if not 0.0 <= value < 1.0:
                raise ValueError(f"DynamicsRanges.{name}: expected a value in [0, 1), got {value}")

    @classmethod
    def none(cls) -> DynamicsRanges:
        """No randomization: the nominal robot."""
        return cls(0.0, 0.0, 0.0, 0.0, 0.0)


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

    @classmethod
    def nominal(cls, n_joints: int) -> Dynamics:
        ones = (1.0,) * n_joints
        return cls(ones, ones, ones, ones, ones)

    def to_dict(self) -> dict[str, list[float]]:
        return {k: list(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> Dynamics:
        return cls(**{k: tuple(float(x) for x in data[k]) for k in cls.__dataclass_fields__})


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
    strength = dict(zip(robot.joint_names, dynamics.actuator_strength, strict=True))
    for act in spec.actuators:  # every actuator of a joint (velocity mode: the PI loop's two)
        k = strength[act.target]
        if mode == "torque":
            gear = np.asarray(act.gear)
            gear[0] *= k
            act.gear = gear
        else:
            gain, bias = np.asarray(act.gainprm), np.asarray(act.biasprm)
            gain[0] *= k
            bias[1:3] *= k
            act.gainprm, act.biasprm = gain, bias


def randomized_model(robot: Robot, mode: str, dynamics: Dynamics) -> mujoco.MjModel:
    """Compiled plant model of ``robot`` in control ``mode`` with ``dynamics`` applied."""
    spec = robot.mjspec(mode)
    apply_dynamics(spec, robot, dynamics, mode)
    return spec.compile()


# ====================================================================== sensors, drift, faults
# Additions for the soak harness (:mod:`eval.soak`): per-session sensor settings, slow drift of
# the plant over a session, and a seeded fault schedule. Every quantity is drawn from its own
# stream of the session seed (:func:`session_rng`), so one kind of draw never shifts another.

#: Named random streams of a session: ``numpy.random.default_rng([seed, STREAMS[name]])``.
STREAMS = {
    "dynamics": 0,
    "sensors": 1,
    "drift": 2,
    "faults": 3,
    "sensor_noise": 4,  # the backend's encoder noise and dropout draws
    "goals": 5,
    "imu": 6,  # floating-base robots: IMU and foot-force noise scales (ImuRanges)
    "floor": 7,  # floating-base robots: the floor's sliding friction (FLOOR_FRICTION)
}

#: Sliding friction coefficient of the floor of a floating-base robot's session, uniform. Our
#: choice: 0.5-1.25, legged_gym's ``domain_rand.friction_range`` (LeggedRobotCfg / GO2RoughCfg in
#: unitree_rl_gym). There it is the robot's shapes' coefficient, which PhysX averages with the
#: terrain's 1.0 (an effective 0.75-1.125); here it is the contact's own (the floor has contact
#: priority, :func:`apply_floor_friction`): the low end is a more slippery floor than legged_gym's.
FLOOR_FRICTION = (0.5, 1.25)


def floor_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Indices of the plane geoms of ``model`` (the floor)."""
    return np.flatnonzero(model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)


def apply_floor_friction(model: mujoco.MjModel, friction: float) -> None:
    """Set the sliding friction of ``model``'s floor (its plane geoms) to ``friction``, in place,
    and give the floor contact priority: MuJoCo then takes its friction for every contact with
    it (without priority a contact takes the larger of the two geoms' coefficients, and the feet's
    default 1 would hide a slippery floor).

    Raises:
        ValueError: the model has no plane geom.
    """
    floor = floor_geoms(model)
    if not len(floor):
        raise ValueError("apply_floor_friction: the model has no floor (plane geom)")
    model.geom_friction[floor, 0] = friction
    model.geom_priority[floor] = max(int(model.geom_priority.max()), 0) + 1


def session_rng(seed: int, stream: str) -> np.random.Generator:
    """The generator of one named stream (``STREAMS``) of session ``seed`` (an int >= 0).

    Raises:
        ValueError: an unknown stream name or a negative seed.
    """
    if stream not in STREAMS:
        raise ValueError(f"session_rng: stream '{stream}' is unknown; expected one of {STREAMS}")
    if int(seed) < 0:
        raise ValueError(f"session_rng: seed must be >= 0, got {seed}")
    return np.random.default_rng([int(seed), STREAMS[stream]])


@dataclass(frozen=True)
class SensorRanges:
    """Per-session encoder settings, drawn uniformly (integers inclusive).

    Attributes:
        noise_sigma: Encoder noise sigma, rad. Seed section 5: 0.002-0.010 on angle / pi, i.e.
            ``(0.002 pi, 0.010 pi)`` rad (as :class:`policies.envs.ReachConfig` trains with).
        latency_ticks: Encoder latency, control ticks (our choice: 0-2, i.e. 0-10 ms at 200 Hz).
        dropout: Probability that a reading is lost (per reading and joint; our choice).
    """

    noise_sigma: tuple[float, float] = (0.002 * np.pi, 0.010 * np.pi)
    latency_ticks: tuple[int, int] = (0, 2)
    dropout: tuple[float, float] = (0.0, 0.001)

    def __post_init__(self):
        check_range("SensorRanges", "noise_sigma", *self.noise_sigma)
        check_range("SensorRanges", "latency_ticks", *self.latency_ticks)
        check_range("SensorRanges", "dropout", *self.dropout)
        if self.dropout[1] > 1.0:
            raise ValueError(
                f"SensorRanges.dropout: expected probabilities <= 1, got {self.dropout}"
            )


#: The dynamics ranges of a floating-base (legged) robot's soak session (``soak-test`` uses them
#: for one): an arm's, but link lengths +-2 % (our choice: four legs of independently drawn
#: lengths +-10 % on a flat floor make a stance the home pose cannot reach: go2 then never leaves
#: RAMP_IN, its HOME_TOLERANCE being 0.05 rad; the legs of one robot are made alike).
LEGGED_DYNAMICS = DynamicsRanges(link_length=0.02)
#: The encoder ranges of a floating-base (legged) robot's soak session (``soak-test`` uses them for
#: one). Noise: 1-10 encoder counts of the GO-M8010-6 (robots/go2/robot.toml: one count 3.03e-5
#: rad; our choice: an arm's 0.006-0.03 rad keeps the estimated joint speeds above the runtime's
#: REST_SPEED, so RAMP_IN never ends); latency: none (our choice: at 50 Hz one tick is 20 ms, and
#: the shipped go2 trot generator falls at 40 ms of joint latency); dropout as an arm's.
LEGGED_SENSORS = SensorRanges(noise_sigma=(3e-5, 3e-4), latency_ticks=(0, 0))


@dataclass(frozen=True)
class SensorDraw:
    """One session's encoder settings: noise sigma (rad), latency (control ticks), dropout."""

    noise_sigma: float
    latency_ticks: int
    dropout_probability: float

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> SensorDraw:
        return cls(
            float(data["noise_sigma"]),
            int(data["latency_ticks"]),
            float(data["dropout_probability"]),
        )


def sample_sensors(rng: np.random.Generator, ranges: SensorRanges | None = None) -> SensorDraw:
    """Draw one :class:`SensorDraw` from ``rng``."""
    ranges = SensorRanges() if ranges is None else ranges
    lo, hi = ranges.latency_ticks
    return SensorDraw(
        noise_sigma=float(rng.uniform(*ranges.noise_sigma)),
        latency_ticks=int(rng.integers(lo, hi + 1)),
        dropout_probability=float(rng.uniform(*ranges.dropout)),
    )


def apply_sensors(backend, env: int, draw: SensorDraw) -> None:
    """Set env ``env`` of a :class:`~deploy.backends.sim.plant.SimBackend` to ``draw``.

    Raises:
        ValueError: the latency exceeds the backend's ``max_latency_ticks``.
    """
    if draw.latency_ticks > backend.max_latency_ticks:
        raise ValueError(
            f"sensor latency {draw.latency_ticks} ticks exceeds the backend's max_latency_ticks "
            f"= {backend.max_latency_ticks}"
        )
    backend.noise_sigma[env] = draw.noise_sigma
    backend.latency_ticks[env] = draw.latency_ticks
    backend.dropout_probability[env] = draw.dropout_probability


@dataclass(frozen=True)
class ImuRanges:
    """Per-session IMU and foot-force noise of a floating-base robot, drawn uniformly (integers
    inclusive), as :class:`SensorRanges` does for the encoders.

    Attributes:
        gyro_noise_sigma: Gyroscope white noise, rad/s. Seed section 5: IMU angular rate
            0.01-0.03 normalized; normalized over 4 rad/s (legged_gym's angular velocity scale
            0.25): ``(0.04, 0.12)`` rad/s.
        accel_noise_sigma: Accelerometer white noise, m/s^2. Seed section 5: linear acceleration
            0.03-0.08 normalized, over standard gravity: ``(0.29, 0.78)`` m/s^2.
        bias_scale: Factor on the robot's ``[sensors.imu]`` turn-on bias and bias random walk
            (our choice: 0.5-2, a unit better or worse than the nominal one).
        latency_ticks: IMU latency, control ticks (our choice: 0-1).
        force_noise_fraction: Foot force noise over the standing load of one foot (m g / feet).
            Seed section 5: force sensors 0.05-0.10 normalized.
    """

    gyro_noise_sigma: tuple[float, float] = (0.01 * 4.0, 0.03 * 4.0)
    accel_noise_sigma: tuple[float, float] = (0.03 * 9.80665, 0.08 * 9.80665)
    bias_scale: tuple[float, float] = (0.5, 2.0)
    latency_ticks: tuple[int, int] = (0, 1)
    force_noise_fraction: tuple[float, float] = (0.05, 0.10)

    def __post_init__(self):
        for name in ("gyro_noise_sigma", "accel_noise_sigma", "bias_scale", "latency_ticks"):
            check_range("ImuRanges", name, *getattr(self, name))
        check_range("ImuRanges", "force_noise_fraction", *self.force_noise_fraction)


@dataclass(frozen=True)
class ImuDraw:
    """One session's IMU and foot-force noise: sigmas (rad/s, m/s^2, N), the bias factor and
    the IMU latency (control ticks)."""

    gyro_noise_sigma: float
    accel_noise_sigma: float
    bias_scale: float
    latency_ticks: int
    force_noise_sigma: float

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> ImuDraw:
        return cls(
            float(data["gyro_noise_sigma"]),
            float(data["accel_noise_sigma"]),
            float(data["bias_scale"]),
            int(data["latency_ticks"]),
            float(data["force_noise_sigma"]),
        )


def sample_imu(robot: Robot, rng: np.random.Generator, ranges: ImuRanges | None = None) -> ImuDraw:
    """Draw one :class:`ImuDraw` for the floating-base ``robot`` from ``rng`` (the session's
    ``"imu"`` stream, :func:`session_rng`).

    Raises:
        ValueError: a fixed-base robot (no IMU).
    """
    if not robot.floating_base:
        raise ValueError(f"sample_imu: robot {robot.name} has no IMU (not a floating base)")
    ranges = ImuRanges() if ranges is None else ranges
    lo, hi = ranges.latency_ticks
    load = float(robot.mj_model.body_subtreemass[0]) * float(
        np.linalg.norm(robot.mj_model.opt.gravity)
    )
    return ImuDraw(
        gyro_noise_sigma=float(rng.uniform(*ranges.gyro_noise_sigma)),
        accel_noise_sigma=float(rng.uniform(*ranges.accel_noise_sigma)),
        bias_scale=float(rng.uniform(*ranges.bias_scale)),
        latency_ticks=int(rng.integers(lo, hi + 1)),
        force_noise_sigma=float(rng.uniform(*ranges.force_noise_fraction)) * load / robot.n_feet,
    )


def apply_imu(backend, env: int, draw: ImuDraw) -> None:
    """Set env ``env`` of a floating-base :class:`~deploy.backends.sim.plant.SimBackend` to ``draw``
    (its turn-on bias is redrawn at the next reset of the env).

    Raises:
        ValueError: a backend without IMU, or a latency above its ``max_latency_ticks``.
    """
    sensors = getattr(backend, "base_sensors", None)
    if sensors is None:
        raise ValueError("apply_imu: the backend's robot has no IMU (not a floating base)")
    if draw.latency_ticks > backend.max_latency_ticks:
        raise ValueError(
            f"IMU latency {draw.latency_ticks} ticks exceeds the backend's max_latency_ticks "
            f"= {backend.max_latency_ticks}"
        )
    imu = backend.robot.config.sensors.imu
    sensors.gyro_noise_sigma[env] = draw.gyro_noise_sigma
    sensors.accel_noise_sigma[env] = draw.accel_noise_sigma
    sensors.gyro_bias_sigma[env] = imu.gyro_bias_sigma * draw.bias_scale
    sensors.accel_bias_sigma[env] = imu.accel_bias_sigma * draw.bias_scale
    sensors.gyro_bias_walk[env] = imu.gyro_bias_walk * draw.bias_scale
    sensors.accel_bias_walk[env] = imu.accel_bias_walk * draw.bias_scale
    sensors.imu_latency_ticks[env] = draw.latency_ticks
    sensors.force_noise_sigma[env] = draw.force_noise_sigma


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


# Default magnitudes of the scheduled faults. Durations of the sensor faults are fractions of the
# "stale budget": the longest gap in fresh encoder data the runtime bridges by prediction,
# ``safety.stale_limit - (latency + 2) * control_period`` (DESIGN.md fault table: stale longer than
# the limit -> safe stop). Fractions below 1 are survivable, above 1 must make a safe stop.


@dataclass(frozen=True)
class SessionRanges:
    """Every range a soak session draws from (defaults as documented on each class)."""

    dynamics: DynamicsRanges = DynamicsRanges()
    sensors: SensorRanges = SensorRanges()
    drift: DriftRanges = DriftRanges()
    faults: FaultRanges = FaultRanges()


def session_ranges(robot: Robot, mean_interval: float | None = None) -> SessionRanges:
    """The soak's ranges for ``robot`` (what ``soak-test`` runs): the defaults with the faults
    sized to it (:func:`eval.world.fault_schedule.fault_ranges`, ``mean_interval`` s between faults
    when given), the encoder noise scaled to the robot's own (:func:`sensor_ranges`) and, for a
    floating-base robot, ``LEGGED_DYNAMICS`` and ``LEGGED_SENSORS``."""
    from eval.world.fault_schedule import fault_ranges

    faults = fault_ranges(robot, mean_interval)
    if robot.floating_base:
        return SessionRanges(dynamics=LEGGED_DYNAMICS, sensors=LEGGED_SENSORS, faults=faults)
    return SessionRanges(sensors=sensor_ranges(robot), faults=faults)


#: The nominal encoder noise the seed's range is drawn about, rad: seed section 5's 0.005 on
#: angle / pi, as arm3's and arm6's robot.toml round it (``encoder_noise_sigma = 0.0157``).
SEED_ENCODER_NOISE = 0.0157


def sensor_ranges(robot: Robot) -> SensorRanges:
    """An arm's encoder ranges: the seed's noise range (0.4-2x its nominal 0.005 pi rad) scaled
    to the robot's own nominal noise (``sensors.encoder_noise_sigma``): arm3 and arm6 get the
    seed's range exactly; an SO-101 (one count, 0.00153 rad) 0.4-2 counts instead of the 4-20
    counts the absolute range gave it, whose noise kept its estimated speeds above REST_SPEED
    (RAMP_IN never ended, stops never came to rest) and its estimate crossing hard limits the
    joints never reached."""
    ratio = robot.config.sensors.encoder_noise_sigma / SEED_ENCODER_NOISE
    low, high = SensorRanges().noise_sigma
    return SensorRanges(noise_sigma=(low * ratio, high * ratio))


@dataclass(frozen=True)
class SessionRandomization:
    """Everything drawn for one soak session from its seed: replayable and reportable.

    Attributes:
        seed: The session seed.
        dynamics: Link lengths, masses, friction, damping, actuator strength.
        sensors: Encoder noise sigma, latency, dropout.
        drift: Friction rise over the session.
        faults: The fault schedule (``deploy.backends.sim.faults.Fault``, sorted by start; empty
        without
            faults).
        imu: A floating-base robot's IMU and foot-force noise (:func:`sample_imu`; None for an
            arm).
        floor_friction: A floating-base robot's floor sliding friction (``FLOOR_FRICTION``;
            None for an arm).
    """

    seed: int
    dynamics: Dynamics
    sensors: SensorDraw
    drift: Drift
    faults: tuple
    imu: ImuDraw | None = None
    floor_friction: float | None = None

    def to_dict(self) -> dict:
        out = {
            "seed": self.seed,
            "dynamics": self.dynamics.to_dict(),
            "sensors": self.sensors.to_dict(),
            "drift": self.drift.to_dict(),
            "faults": [fault_to_dict(f) for f in self.faults],
        }
        if self.imu is not None:  # a floating-base robot's (an arm's document is unchanged)
            out["imu"] = self.imu.to_dict()
        if self.floor_friction is not None:
            out["floor_friction"] = self.floor_friction
        return out

    @classmethod
    def from_dict(cls, data: dict) -> SessionRandomization:
        return cls(
            int(data["seed"]),
            Dynamics.from_dict(data["dynamics"]),
            SensorDraw.from_dict(data["sensors"]),
            Drift.from_dict(data["drift"]),
            tuple(fault_from_dict(f) for f in data["faults"]),
            ImuDraw.from_dict(data["imu"]) if data.get("imu") is not None else None,
            float(data["floor_friction"]) if data.get("floor_friction") is not None else None,
        )


def sample_session(
    robot: Robot,
    seed: int,
    duration: float,
    ranges: SessionRanges | None = None,
    faults: bool = True,
) -> SessionRandomization:
    """Draw a session's randomization from its ``seed``: each part from its own stream
    (:func:`session_rng`), so that e.g. turning faults off leaves the dynamics unchanged. A
    floating-base robot also draws its IMU noise (``imu`` stream) and floor friction (``floor``).

    Args:
        robot: The robot.
        seed: Session seed (int >= 0).
        duration: Session length, s (the fault schedule ends before it).
        ranges: The ranges; default :class:`SessionRanges`.
        faults: False: an empty fault schedule.
    """
    ranges = SessionRanges() if ranges is None else ranges
    sensors = sample_sensors(session_rng(seed, "sensors"), ranges.sensors)
    dynamics = sample_dynamics(robot, session_rng(seed, "dynamics"), ranges.dynamics)
    schedule = []
    if faults:
        # faults are sized against this session's plant (its masses and link lengths)
        plant = randomized_model(robot, robot.config.control.mode, dynamics)
        rng = session_rng(seed, "faults")
        schedule = sample_fault_schedule(robot, rng, duration, sensors, ranges.faults, plant)
    imu = floor = None
    if robot.floating_base:
        imu = sample_imu(robot, session_rng(seed, "imu"))
        floor = float(session_rng(seed, "floor").uniform(*FLOOR_FRICTION))
    return SessionRandomization(
        seed=int(seed),
        dynamics=dynamics,
        sensors=sensors,
        drift=sample_drift(robot, session_rng(seed, "drift"), ranges.drift),
        faults=tuple(schedule),
        imu=imu,
        floor_friction=floor,
    )
