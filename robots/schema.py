"""Schema of ``robot.toml``: the robot spec, validated on load.

Every quantity is SI with angles in radians, temperatures in degrees Celsius. Each motor table must
name the datasheet its constants come from (``source``). See ``robots/arm3/robot.toml`` for a fully
commented example.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

Positive = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Probability = Annotated[float, Field(ge=0.0, lt=1.0)]
Vec3 = tuple[Finite, Finite, Finite]

ControlMode = Literal["position", "velocity", "torque"]
CONTROL_MODES: tuple[str, ...] = ("position", "velocity", "torque")


class _Strict(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class JointConfig(_Strict):
    """One joint: hard limits, motion limits, drive and plant servo gains."""

    name: str
    position_limit: tuple[Finite, Finite]  # rad, hard (mechanical) limits
    velocity_limit: Positive  # rad/s
    acceleration_limit: Positive  # rad/s^2
    jerk_limit: Positive  # rad/s^3
    effort_limit: Positive  # N m at the joint
    soft_limit_fraction: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.9
    motor: str  # key into [motors]
    kp: Positive  # N m/rad, plant position servo stiffness
    kd: NonNegative  # N m s/rad, plant position servo damping

    @model_validator(mode="after")
    def _ordered_limits(self) -> JointConfig:
        lo, hi = self.position_limit
        if not lo < hi:
            raise ValueError(
                f"position_limit must be [lower, upper] with lower < upper, got {lo}, {hi}"
            )
        return self


class ServoRegister(_Strict):
    """One register of a servo's control table: address, factory default and unit."""

    address: Annotated[int, Field(ge=0)]
    default: int
    unit: str = ""


class ServoProtection(_Strict):
    """A smart servo's own protection settings (it cuts or limits torque by itself).

    ``temperature_limit`` is the factory default of the servo's temperature limit register (degC);
    ``registers`` names every protection register with its address and default value.
    """

    source: Annotated[str, Field(min_length=10)]
    temperature_limit: Finite  # degC
    registers: dict[str, ServoRegister] = {}


class MotorConfig(_Strict):
    """A motor plus gearhead, with its datasheet constants (motor side unless stated).

    One TOML file a model in ``robots/motors/`` (the catalog), or a ``[motors.NAME]`` table in
    robot.toml (which takes precedence). The optional fields (``None`` when absent, left out of a
    robot's description hash) are for the importer: ``max_velocity`` (rad/s at the output, the
    no-load speed at the rated voltage), ``encoder_resolution`` (counts per output revolution)
    and ``protection`` (a smart servo's own protection registers).
    """

    source: Annotated[str, Field(min_length=10)]  # the datasheet the numbers come from
    gear_ratio: Positive
    gear_efficiency: Annotated[float, Field(gt=0.0, le=1.0)]
    torque_constant: Positive  # N m/A
    winding_resistance: Positive  # ohm at resistance_reference_temperature
    resistance_reference_temperature: Finite = 25.0  # degC
    copper_temperature_coefficient: Positive = 0.00393  # 1/K, annealed copper (IEC 60028)
    thermal_resistance_winding_housing: Positive  # K/W
    thermal_resistance_housing_ambient: Positive  # K/W
    thermal_time_constant_winding: Positive  # s
    thermal_time_constant_housing: Positive  # s
    max_winding_temperature: Finite  # degC
    derating_start_temperature: Finite  # degC, effort derated linearly from here to the maximum
    continuous_torque: Positive  # N m at the output
    peak_torque: Positive  # N m at the output
    rotor_inertia: Positive  # kg m^2
    max_velocity: Positive | None = None  # rad/s at the output (no-load speed)
    encoder_resolution: Annotated[int, Field(gt=0)] | None = None  # counts per output revolution
    protection: ServoProtection | None = None

    @model_validator(mode="after")
    def _ordered_temperatures(self) -> MotorConfig:
        if not self.derating_start_temperature < self.max_winding_temperature:
            raise ValueError(
                "derating_start_temperature must be below max_winding_temperature, got "
                f"{self.derating_start_temperature} >= {self.max_winding_temperature}"
            )
        return self


class SensorConfig(_Strict):
    """Encoders and temperature reporting, as the drive delivers them."""

    encoder_resolution: Annotated[int, Field(gt=0)]  # counts per revolution
    encoder_noise_sigma: NonNegative  # rad
    encoder_rate: Positive  # Hz
    encoder_latency_ticks: Annotated[int, Field(ge=0)] = 0  # control ticks
    encoder_dropout: Probability = 0.0  # probability per reading and joint
    temperature_resolution: Positive = 1.0  # degC
    temperature_rate: Positive = 10.0  # Hz
    ambient_temperature: Finite = 25.0  # degC


class SafetyConfig(_Strict):
    """What the safety guard checks beyond the joint limits."""

    end_effector_site: str
    workspace_min: Vec3  # m, base frame
    workspace_max: Vec3  # m, base frame
    collision_pairs: list[tuple[str, str]] = []
    stale_limit: Positive = 0.05  # s without a fresh encoder reading before a safe stop

    @model_validator(mode="after")
    def _ordered_box(self) -> SafetyConfig:
        if not all(a < b for a, b in zip(self.workspace_min, self.workspace_max, strict=True)):
            raise ValueError("workspace_min must be below workspace_max on every axis")
        return self


class ControlConfig(_Strict):
    mode: ControlMode
    control_rate: Positive  # Hz
    physics_timestep: Positive  # s
    home: list[Finite]  # rad, one per joint


class TaskConfig(_Strict):
    """Where goals are sampled.

    ``planar_annulus``: radius and angle in the XY plane (seed section 8); ``box``: uniform in
    [box_min, box_max].
    """

    region: Literal["planar_annulus", "box"]
    radius: tuple[NonNegative, NonNegative] | None = None  # m
    angle: tuple[Finite, Finite] | None = None  # rad
    box_min: Vec3 | None = None  # m
    box_max: Vec3 | None = None  # m
    success_radius: Positive  # m

    @model_validator(mode="after")
    def _region_fields(self) -> TaskConfig:
        need = ("radius", "angle") if self.region == "planar_annulus" else ("box_min", "box_max")
        missing = [f for f in need if getattr(self, f) is None]
        if missing:
            raise ValueError(f"region '{self.region}' needs {', '.join(missing)}")
        return self


class RobotConfig(_Strict):
    """The whole ``robot.toml``."""

    name: str
    mjcf: str  # path relative to robot.toml
    control: ControlConfig
    joints: Annotated[list[JointConfig], Field(min_length=1)]
    motors: dict[str, MotorConfig]
    sensors: SensorConfig
    safety: SafetyConfig
    task: TaskConfig

    @model_validator(mode="after")
    def _cross_references(self) -> RobotConfig:
        for i, joint in enumerate(self.joints):
            if joint.motor not in self.motors:
                raise ValueError(
                    f"joints[{i}].motor = '{joint.motor}' names no [motors.{joint.motor}] table "
                    f"(known: {sorted(self.motors)})"
                )
        if len(self.control.home) != len(self.joints):
            raise ValueError(
                f"control.home has {len(self.control.home)} values, expected one per joint "
                f"({len(self.joints)})"
            )
        names = [j.name for j in self.joints]
        if len(set(names)) != len(names):
            raise ValueError(f"joint names must be unique, got {names}")
        return self
