"""Every range a soak session draws from (:class:`SessionRanges`), and each robot kind's defaults
(:func:`session_ranges`: the kind's face in :data:`SESSION_RANGES`, an arm's, a floating-base
robot's). Training draws from the same ranges
(:mod:`sim2real.policies.envs`, :mod:`sim2real.policies.locomotion`); a TOML file overrides any of them
(:func:`sim2real.eval.world.ranges_file.load_ranges`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sim2real.deploy.core.registry import Faces
from sim2real.deploy.kinds import robot_kind
from sim2real.deploy.tasks.commands import CommandRanges
from sim2real.eval.world.checks import check_range
from sim2real.eval.world.drift import DriftRanges
from sim2real.eval.world.dynamics import ComOffsetRanges, DynamicsRanges
from sim2real.eval.world.fault_schedule import FaultRanges, fault_ranges
from sim2real.eval.world.floor import FLOOR_FRICTION
from sim2real.eval.world.pushes import PushRanges
from sim2real.eval.world.sensors import ImuRanges, SensorRanges
from sim2real.eval.world.terrain import TerrainRanges
from sim2real.robots import Robot

#: The dynamics ranges of a floating-base (legged) robot's soak session (``soak-test`` uses them
#: for one): an arm's, but link lengths +-2 % (our choice: four legs of independently drawn
#: lengths +-10 % on a flat floor make a stance the home pose cannot reach: go2 then never leaves
#: RAMP_IN, its HOME_TOLERANCE being 0.05 rad; the legs of one robot are made alike).
LEGGED_DYNAMICS = DynamicsRanges(link_length=0.02)
#: The encoder ranges of a floating-base (legged) robot's soak session (``soak-test`` uses them for
#: one). Noise: 1-10 encoder counts of the GO-M8010-6 (sim2real/robots/go2/robot.toml: one count 3.03e-5
#: rad; our choice: an arm's 0.006-0.03 rad keeps the estimated joint speeds above the runtime's
#: REST_SPEED, so RAMP_IN never ends); latency: none (our choice: at 50 Hz one tick is 20 ms, and
#: the shipped go2 trot generator falls at 40 ms of joint latency); dropout as an arm's.
LEGGED_SENSORS = SensorRanges(noise_sigma=(3e-5, 3e-4), latency_ticks=(0, 0))


@dataclass(frozen=True)
class SessionRanges:
    """Every range a soak session draws from (defaults as documented on each class).

    Attributes:
        dynamics: Link lengths, masses, friction, damping, actuator strength.
        sensors: Encoder noise sigma (rad), latency (control ticks), dropout.
        drift: Friction rise over the session.
        faults: The fault schedule.
        imu: A floating-base robot's IMU and foot force noise; None: the robot has no IMU (an
            arm's, :func:`session_ranges`).
        floor_friction: A floating-base robot's floor sliding friction coefficient ``(low,
            high)``, uniform (default ``FLOOR_FRICTION``); None: no floor is drawn (an arm's).
        added_base_mass: A floating-base robot's mass added to its base body, ``(low, high)``
            kg, uniform (legged_gym's ``domain_rand.added_mass_range``); None: none (default).
        added_mass_body: The body ``added_base_mass`` goes on (a name of the robot's MJCF;
            empty: its base body, legged_gym's; Isaac Lab's G1 task adds it to ``torso_link``).
        pushes: A floating-base robot's pushes of its training domain
            (:class:`sim2real.eval.world.pushes.PushRanges`, legged_gym's ``push_robots``); None: none
            (default; the fault schedule's force pushes are apart).
        com_offset: A shift of a body's centre of mass per session
            (:class:`sim2real.eval.world.dynamics.ComOffsetRanges`; a ranges file's ``[dynamics]
            com_offset``); None: none (default).
        commands: A floating-base robot's velocity commands
            (:class:`sim2real.deploy.tasks.commands.CommandRanges`); None: the policy's training
            ranges where its contract records them (``soak-test``), else CommandRanges'
            defaults.
        terrain: A floating-base robot's ground: legged_gym's terrain tiles
            (:class:`sim2real.eval.world.terrain.TerrainRanges`, a ranges file's ``[terrain]``);
            None (default): the flat plane.

    Raises:
        ValueError: ``floor_friction`` is not a range ``0 <= low <= high`` (named).
    """

    dynamics: DynamicsRanges = DynamicsRanges()
    sensors: SensorRanges = SensorRanges()
    drift: DriftRanges = DriftRanges()
    faults: FaultRanges = FaultRanges()
    imu: ImuRanges | None = ImuRanges()
    floor_friction: tuple[float, float] | None = FLOOR_FRICTION
    added_base_mass: tuple[float, float] | None = None
    pushes: PushRanges | None = None
    commands: CommandRanges | None = None
    com_offset: ComOffsetRanges | None = None
    added_mass_body: str = ""
    terrain: TerrainRanges | None = None

    def __post_init__(self):
        if self.floor_friction is not None:
            check_range("SessionRanges", "floor_friction", *self.floor_friction)
        if self.added_base_mass is not None:
            check_range("SessionRanges", "added_base_mass", *self.added_base_mass, -math.inf)


def session_ranges(robot: Robot, mean_interval: float | None = None) -> SessionRanges:
    """The soak's ranges for ``robot`` (what ``soak-test`` runs, and training draws from): its
    kind's defaults (:data:`SESSION_RANGES`, the face registered under the kind's name) with the
    faults sized to it (:func:`sim2real.eval.world.fault_schedule.fault_ranges`,
    ``mean_interval`` s between faults when given).

    Raises:
        ValueError: the robot's kind registered no range defaults."""
    defaults = SESSION_RANGES.get(robot_kind(robot))
    return defaults(robot, fault_ranges(robot, mean_interval))


def arm_ranges(robot: Robot, faults: FaultRanges) -> SessionRanges:
    """An arm's defaults: the encoder noise scaled to the robot's own (:func:`sensor_ranges`),
    no IMU, no floor, ``faults``."""
    return SessionRanges(sensors=sensor_ranges(robot), faults=faults, imu=None, floor_friction=None)


def legged_ranges(robot: Robot, faults: FaultRanges) -> SessionRanges:
    """A floating-base robot's defaults: ``LEGGED_DYNAMICS``, ``LEGGED_SENSORS``, the default
    :class:`ImuRanges` and ``FLOOR_FRICTION``, ``faults``."""
    return SessionRanges(
        dynamics=LEGGED_DYNAMICS,
        sensors=LEGGED_SENSORS,
        faults=faults,
        imu=ImuRanges(),
        floor_friction=FLOOR_FRICTION,
    )


#: The soak's range defaults of each robot kind, by its name: ``(robot, faults) ->
#: SessionRanges`` (a wheel-legged robot's are a legged robot's).
SESSION_RANGES: Faces = Faces("soak's range defaults")
SESSION_RANGES.register("arm", arm_ranges)
SESSION_RANGES.register("legged", legged_ranges)


#: The nominal encoder noise the specified range is drawn about, rad: the specified 0.005 on
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
