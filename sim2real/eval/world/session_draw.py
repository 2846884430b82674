"""One soak session's randomization, drawn from its seed: each part from its own named stream
(:func:`session_rng`), bundled in :class:`SessionRandomization` by :func:`sample_session`:

- dynamics (:mod:`sim2real.eval.world.dynamics`);
- sensors (:mod:`sim2real.eval.world.sensors`): encoder noise, latency and dropout; a floating-base robot's
  IMU and foot force noise;
- a floating-base robot's floor friction (:mod:`sim2real.eval.world.floor`) and, with terrain ranges, its
  ground's tiles (:mod:`sim2real.eval.world.terrain`);
- slow drift (:mod:`sim2real.eval.world.drift`);
- a fault schedule (:mod:`sim2real.eval.world.fault_schedule`): dropout bursts, stale frames, non-finite
  actions, latency spikes, pushes and a cable pulling on the end effector, as
  :class:`sim2real.deploy.backends.sim.faults.Fault` for
  :class:`sim2real.deploy.backends.sim.faults.FaultInjector`, each sized to be survivable in the session's
  plant.

The ranges it draws from are :class:`sim2real.eval.world.session_ranges.SessionRanges`.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from sim2real.eval.world.drift import Drift, sample_drift
from sim2real.eval.world.dynamics import Dynamics, randomized_model, sample_dynamics
from sim2real.eval.world.fault_schedule import (
    FaultRanges,
    fault_from_dict,
    fault_to_dict,
    sample_fault_schedule,
)
from sim2real.eval.world.sensors import ImuDraw, SensorDraw, sample_imu, sample_sensors
from sim2real.eval.world.session_ranges import SessionRanges
from sim2real.eval.world.terrain import TerrainDraw, sample_terrain
from sim2real.robots import Robot

#: Named random streams of a session: ``numpy.random.default_rng([seed, STREAMS[name]])``.
STREAMS = {
    "dynamics": 0,
    "sensors": 1,
    "drift": 2,
    "faults": 3,
    "sensor_noise": 4,  # the backend's encoder noise and dropout draws
    "goals": 5,
    "imu": 6,  # floating-base robots: IMU and foot-force noise scales (ImuRanges)
    "floor": 7,  # floating-base robots: the floor's sliding friction (floor_friction)
    "base_mass": 8,  # floating-base robots: mass added to the base (added_base_mass)
    "encoder_bias": 9,  # each joint's encoder offset (SensorRanges.encoder_bias)
    "com_offset": 10,  # a body's centre-of-mass shift (ComOffsetRanges)
    "terrain": 11,  # floating-base robots: the ground's tile kind and level (TerrainRanges)
    "terrain_tiles": 12,  # the random parts of its tiles (roughness, obstacles)
    "curriculum_walk": 13,  # a curriculum walk's respawns (sim2real.eval.soak.curriculum_walk)
    "camera": 14,  # a camera policy's faults and depth noise (sim2real.eval.soak.camera)
}


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
class SessionRandomization:
    """Everything drawn for one soak session from its seed: replayable and reportable.

    Attributes:
        seed: The session seed.
        dynamics: Link lengths, masses, friction, damping, actuator strength.
        sensors: Encoder noise sigma, latency, dropout.
        drift: Friction rise over the session.
        faults: The fault schedule (``sim2real.deploy.backends.sim.faults.Fault``, sorted by start; empty
            without faults).
        imu: A floating-base robot's IMU and foot-force noise (:func:`sample_imu`; None for an
            arm).
        floor_friction: A floating-base robot's floor sliding friction (drawn from
            :attr:`SessionRanges.floor_friction`; None for an arm).
        added_base_mass: kg added to a floating-base robot's base (drawn from
            :attr:`SessionRanges.added_base_mass`; None where the ranges add none).
        encoder_bias: Each joint's encoder offset, rad (drawn from
            :attr:`SensorRanges.encoder_bias`; None where the ranges have none).
        com_offset: ``(body, (x, y, z) m)``, a body's centre-of-mass shift (drawn from
            :attr:`SessionRanges.com_offset`; None where the ranges have none).
        terrain: A floating-base robot's ground tiles (drawn from
            :attr:`SessionRanges.terrain`; None: the flat plane).
    """

    seed: int
    dynamics: Dynamics
    sensors: SensorDraw
    drift: Drift
    faults: tuple
    imu: ImuDraw | None = None
    floor_friction: float | None = None
    added_base_mass: float | None = None
    encoder_bias: tuple[float, ...] | None = None
    com_offset: tuple[str, tuple[float, float, float]] | None = None
    terrain: TerrainDraw | None = None

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
        if self.added_base_mass is not None:
            out["added_base_mass"] = self.added_base_mass
        if self.encoder_bias is not None:
            out["encoder_bias"] = list(self.encoder_bias)
        if self.com_offset is not None:
            out["com_offset"] = {"body": self.com_offset[0], "offset_m": list(self.com_offset[1])}
        if self.terrain is not None:
            out["terrain"] = self.terrain.to_dict()
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
            float(data["added_base_mass"]) if data.get("added_base_mass") is not None else None,
            (
                tuple(map(float, data["encoder_bias"]))
                if data.get("encoder_bias") is not None
                else None
            ),
            (
                (str(data["com_offset"]["body"]), tuple(map(float, data["com_offset"]["offset_m"])))
                if data.get("com_offset") is not None
                else None
            ),
            TerrainDraw.from_dict(data["terrain"]) if data.get("terrain") is not None else None,
        )


def sample_faults(
    robot: Robot,
    seed: int,
    duration: float,
    sensors: SensorDraw,
    ranges: FaultRanges,
    plant: mujoco.MjModel | None = None,
) -> list:
    """The fault schedule of session ``seed`` (its ``faults`` stream) over ``[0, duration)`` s:
    :func:`sim2real.eval.world.fault_schedule.sample_fault_schedule` sized against the session's encoder
    latency (``sensors``) and plant model ``plant`` (default the nominal one). What
    :func:`sample_session` draws, and a training episode with its own sensors and plant.

    Raises:
        ValueError: an unknown stream or a negative seed (:func:`session_rng`).
    """
    rng = session_rng(seed, "faults")
    return sample_fault_schedule(robot, rng, duration, sensors, ranges, plant)


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
        ranges: The ranges; default :class:`SessionRanges` (the robot kind's own:
            :func:`sim2real.eval.world.session_ranges.session_ranges`).
        faults: False: an empty fault schedule.

    Raises:
        ValueError: a floating-base robot with ranges without ``imu`` or ``floor_friction``.
    """
    ranges = SessionRanges() if ranges is None else ranges
    sensors = sample_sensors(session_rng(seed, "sensors"), ranges.sensors)
    dynamics = sample_dynamics(robot, session_rng(seed, "dynamics"), ranges.dynamics)
    schedule = []
    if faults:
        # faults are sized against this session's plant (its masses and link lengths)
        plant = randomized_model(robot, robot.config.control.mode, dynamics)
        schedule = sample_faults(robot, seed, duration, sensors, ranges.faults, plant)
    imu = floor = added = terrain = None
    if robot.floating_base:  # an IMU and a floor
        if ranges.imu is None or ranges.floor_friction is None:
            raise ValueError(
                f"sample_session: robot {robot.name} has a floating base: expected ranges with "
                f"imu and floor_friction (sim2real.eval.world.session_ranges.session_ranges), got imu = "
                f"{ranges.imu}, floor_friction = {ranges.floor_friction}"
            )
        imu = sample_imu(robot, session_rng(seed, "imu"), ranges.imu)
        floor = float(session_rng(seed, "floor").uniform(*ranges.floor_friction))
        if ranges.added_base_mass is not None:
            added = float(session_rng(seed, "base_mass").uniform(*ranges.added_base_mass))
        if ranges.terrain is not None:
            terrain = sample_terrain(session_rng(seed, "terrain"), ranges.terrain)
    bias = com = None
    if ranges.sensors.encoder_bias is not None:
        rng = session_rng(seed, "encoder_bias")
        bias = tuple(float(b) for b in rng.uniform(*ranges.sensors.encoder_bias, robot.n_joints))
    if ranges.com_offset is not None:
        body = ranges.com_offset.body_of(robot)
        com = (body, ranges.com_offset.sample(session_rng(seed, "com_offset")))
    return SessionRandomization(
        seed=int(seed),
        dynamics=dynamics,
        sensors=sensors,
        drift=sample_drift(robot, session_rng(seed, "drift"), ranges.drift),
        faults=tuple(schedule),
        imu=imu,
        floor_friction=floor,
        added_base_mass=added,
        encoder_bias=bias,
        com_offset=com,
        terrain=terrain,
    )
