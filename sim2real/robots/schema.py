"""Schema of ``robot.toml``: the robot spec, validated on load.

Every quantity is SI with angles in radians, temperatures in degrees Celsius. Each motor table must
name the datasheet its constants come from (``source``). See ``sim2real/robots/arm3/robot.toml`` for a fully
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
    # rad, hard (mechanical) limits; None for a continuous joint (a wheel), which says so
    position_limit: tuple[Finite, Finite] | None = None
    # a continuous joint (MJCF hinge without range, URDF type="continuous"): no position limit;
    # the guard checks its speed and torque only, and its angle never counts as a violation;
    # None (unset, as false) stays out of the description hash: no existing robot's changes
    continuous: bool | None = None
    velocity_limit: Positive  # rad/s
    acceleration_limit: Positive  # rad/s^2
    jerk_limit: Positive  # rad/s^3
    effort_limit: Positive  # N m at the joint
    soft_limit_fraction: Annotated[float, Field(gt=0.0, lt=1.0)] = 0.9
    # rad/s, the fastest command the smoother issues; default soft_limit_fraction x
    # velocity_limit (a servo tracks its command). A legged robot's PD targets get their
    # own (robot-import --target-limits pd): the joint's speed is bounded by its drive, not by
    # how fast its target moves
    command_velocity_limit: Positive | None = None
    motor: str  # key into [motors]
    # N m/rad, plant position servo stiffness: positive, or 0 for a velocity drive
    kp: NonNegative
    kd: NonNegative  # N m s/rad, plant position servo damping
    # what the joint's command is in position mode: "position" (a PD target, tau = kp (target -
    # q) - kd dq) or "velocity" (a wheel: a speed target, tau = kd (v_target - dq), kp 0);
    # None (unset, as "position") stays out of the description hash
    drive: Literal["position", "velocity"] | None = None

    @model_validator(mode="after")
    def _ordered_limits(self) -> JointConfig:
        if bool(self.continuous) == (self.position_limit is not None):
            raise ValueError(
                "expected either position_limit = [lower, upper] or continuous = true "
                f"(got position_limit {self.position_limit}, continuous {self.continuous})"
            )
        if self.drive == "velocity":
            if self.kp != 0.0 or not self.kd > 0.0:
                raise ValueError(
                    f"drive = 'velocity' needs kp = 0 and kd > 0 (tau = kd (v_target - dq)), "
                    f"got kp {self.kp}, kd {self.kd}"
                )
        elif not self.kp > 0.0:
            raise ValueError(f"kp must be positive for a position drive, got {self.kp}")
        if self.continuous:
            return self
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


class PositionTargetConfig(_Strict):
    """Whether a drive clamps its position target to the joint's range, and where that is said
    (``[motors.NAME.position_target]``).

    ``clamped = true``: the drive's firmware limits the target to the joint's range (a smart
    servo's angle-limit registers), as the plant's position actuator then does
    (``Robot.mjspec``). ``clamped = false``: the drive runs its PD law on any target (a Unitree
    motor's ``tau = kp (q_des - q) + kd (dq_des - dq) + tau_ff``); the joint's range is a
    mechanical stop (a contact in the physics), not a bound on the target, and the torque-speed
    envelope bounds the torque. ``source``: the document that says so.
    """

    clamped: bool
    source: Annotated[str, Field(min_length=10)]


class MotorConfig(_Strict):
    """A motor plus gearhead, with its datasheet constants (motor side unless stated).

    One TOML file a model in ``sim2real/robots/motors/`` (the catalog), or a ``[motors.NAME]`` table in
    robot.toml (which takes precedence). The optional fields (``None`` when absent, left out of a
    robot's description hash): ``max_velocity`` (rad/s at the output, the no-load speed at the
    rated voltage: the importer's velocity limit, and the plant's torque-speed line,
    :mod:`sim2real.robots.torque_speed`), ``encoder_resolution`` (counts per output revolution),
    ``protection`` (a smart servo's own protection registers) and ``position_target`` (whether
    the drive clamps a position target to the joint's range, :class:`PositionTargetConfig`).
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
    #: s, the drive's command delay (its bus and control loop): the simulated plant holds each
    #: command back by it (sim2real.deploy.backends.sim.actuators); not part of the description hash
    command_delay: Annotated[float, Field(ge=0.0, le=1.0)] | None = None
    encoder_resolution: Annotated[int, Field(gt=0)] | None = None  # counts per output revolution
    protection: ServoProtection | None = None
    #: whether the drive clamps a position target to the joint's range (PositionTargetConfig);
    #: None: it does not (a bus motor's PD law runs on any target, the range is its joint's
    #: stop); a clamp only where the file says ``clamped = true``. The plant's drive, not the
    #: policy's contract: not part of the description hash
    position_target: PositionTargetConfig | None = None

    @model_validator(mode="after")
    def _ordered_temperatures(self) -> MotorConfig:
        if not self.derating_start_temperature < self.max_winding_temperature:
            raise ValueError(
                "derating_start_temperature must be below max_winding_temperature, got "
                f"{self.derating_start_temperature} >= {self.max_winding_temperature}"
            )
        if self.protection and not self.max_winding_temperature < self.protection.temperature_limit:
            # the runtime's thermal safe stop must come before the servo cuts its own torque
            raise ValueError(
                "max_winding_temperature must be below protection.temperature_limit (the servo's "
                f"own cut-off), got {self.max_winding_temperature} >= "
                f"{self.protection.temperature_limit}"
            )
        return self


class SensorConfig(_Strict):
    """Encoders and temperature reporting, as the drive delivers them."""

    encoder_resolution: Annotated[int, Field(gt=0)]  # counts per revolution
    encoder_noise_sigma: NonNegative  # rad
    encoder_rate: Positive  # Hz
    encoder_latency_ticks: Annotated[int, Field(ge=0)] = 0  # control ticks
    encoder_dropout: Probability = 0.0  # probability per reading and joint
    # The joint velocity the drive reports with each encoder reading (Unitree's motor_state.dq,
    # Dynamixel's present velocity): the true velocity plus white noise of this sigma; None: the
    # drives report none. Out of the description hash (an estimator input, not a policy's).
    velocity_noise_sigma: NonNegative | None = None  # rad/s
    temperature_resolution: Positive = 1.0  # degC
    temperature_rate: Positive = 10.0  # Hz
    ambient_temperature: Finite = 25.0  # degC
    imu: ImuConfig | None = None  # floating-base robots: [sensors.imu]
    contact: ContactConfig | None = None  # floating-base robots: [sensors.contact]


class ImuConfig(_Strict):
    """A MEMS IMU at the base's IMU site: gyroscope and accelerometer, each axis with white noise
    and a bias that starts at a random turn-on value and then walks (the IMU noise model of
    Kalibr, ETH Zurich, "IMU Noise Model" wiki page; discrete time: ``b_k+1 = b_k + walk
    sqrt(dt) N(0, 1)``, ``y_k = true_k + b_k + sigma N(0, 1)``).

    Units: ``*_noise_sigma`` per sample (rad/s, m/s^2); ``*_bias_sigma`` the turn-on bias's
    standard deviation (rad/s, m/s^2); ``*_bias_walk`` the bias random walk (rad/s/sqrt(s),
    m/s^2/sqrt(s)). ``rate`` (Hz) at most the control rate; ``latency_ticks`` control ticks.
    """

    gyro_noise_sigma: NonNegative  # rad/s
    gyro_bias_sigma: NonNegative = 0.0  # rad/s
    gyro_bias_walk: NonNegative = 0.0  # rad/s/sqrt(s)
    accel_noise_sigma: NonNegative  # m/s^2
    accel_bias_sigma: NonNegative = 0.0  # m/s^2
    accel_bias_walk: NonNegative = 0.0  # m/s^2/sqrt(s)
    rate: Positive  # Hz
    latency_ticks: Annotated[int, Field(ge=0)] = 0  # control ticks
    dropout: Probability = 0.0  # probability per reading
    # The IMU's own attitude estimate (an AHRS module's quaternion, as Unitree's LowState sends):
    # roll and pitch errors (rad) each a first-order Gauss-Markov process of stationary standard
    # deviation orientation_sigma and correlation time orientation_tau (s); None: the IMU sends
    # no attitude. Out of the description hash (an estimator input, not a policy's).
    orientation_sigma: NonNegative | None = None  # rad
    orientation_tau: Positive = 1.0  # s
    # Its heading (yaw about gravity), which a 6-axis AHRS (no magnetometer: Unitree's, per
    # unitreerobotics/unitree_legged_sdk#38) integrates from its gyroscope: the yaw error grows by a
    # residual yaw-rate bias the filter could not calibrate away (drawn at turn-on, standard
    # deviation heading_rate_sigma rad/s, then held) and an angle random walk (heading_walk
    # rad/sqrt(s)); it starts at 0. None: the attitude's heading is the true one. Needs
    # orientation_sigma. Out of the description hash.
    heading_rate_sigma: NonNegative | None = None  # rad/s
    heading_walk: NonNegative = 0.0  # rad/sqrt(s)

    @model_validator(mode="after")
    def _heading_needs_attitude(self) -> ImuConfig:
        if self.heading_rate_sigma is not None and self.orientation_sigma is None:
            raise ValueError(
                "heading_rate_sigma needs orientation_sigma (a heading is part of the IMU's "
                "own attitude, which orientation_sigma turns on)"
            )
        return self


class ContactConfig(_Strict):
    """Foot contact: the normal force of MuJoCo's contacts in each foot's site (a ``touch``
    sensor), with Gaussian noise, thresholded. ``threshold`` and ``force_noise_sigma`` in N,
    ``rate`` in Hz (at most the control rate), ``latency_ticks`` in control ticks."""

    threshold: Positive  # N
    force_noise_sigma: NonNegative = 0.0  # N
    rate: Positive  # Hz
    latency_ticks: Annotated[int, Field(ge=0)] = 0  # control ticks


class BaseConfig(_Strict):
    """A floating-base robot (legged): its base and where its sensors sit.

    ``body``: the MJCF body with the free joint (MuJoCo ``<freejoint>``; Pinocchio reads it as
    its free-flyer root joint). ``imu_site``: the site of the MJCF ``gyro`` and
    ``accelerometer`` sensors. ``feet``: one site a foot, at the centre of its contact sphere,
    each with an MJCF ``touch`` sensor (foot contact). ``standing_height``: base height (m)
    above the floor when standing at ``control.home``.
    """

    body: str
    imu_site: str
    feet: Annotated[list[str], Field(min_length=1)]
    standing_height: Positive  # m


class SafetyConfig(_Strict):
    """What the safety guard checks beyond the joint limits.

    ``end_effector_site`` and the workspace box are required for a fixed-base arm; a
    floating-base robot (``[base]``) may leave them out (no workspace check for legs).
    """

    end_effector_site: str | None = None
    workspace_min: Vec3 | None = None  # m, base frame
    workspace_max: Vec3 | None = None  # m, base frame
    collision_pairs: list[tuple[str, str]] = []
    # s without a fresh encoder reading before a safe stop; the runtime uses the longer of it and
    # 8 control periods (Robot.stale_limit, sim2real/robots/robot.py MIN_STALE_TICKS)
    stale_limit: Positive = 0.05
    # Floating-base robots: a fall is the base tilted past fall_tilt (rad) or lower than
    # fall_height (m) above its lowest foot (0: no height check); left out, the defaults of
    # sim2real/deploy/estimation/fall.py (FALL_TILT, FALL_HEIGHT). None keeps them out of the description
    # hash.
    fall_tilt: Positive | None = None
    fall_height: NonNegative | None = None
    # m kept between listed collision geometries, and from the workspace box's faces, by the
    # guard's motion envelope (sim2real/deploy/safety/envelope.py); left out, its DEFAULT_MARGIN (None keeps
    # it
    # out of the description hash)
    clearance_margin: NonNegative | None = None
    # How far each link's length may differ from the MJCF's, as a share of it (0.10: +-10 %);
    # left out, 0: the description is exact. The motion envelope keeps the end effector inside
    # the workspace box for every chain within it (sim2real/deploy/safety/envelope.py). A guard setting,
    # not part of what a policy depends on: left out of the description hash.
    link_length_tolerance: NonNegative | None = None

    @model_validator(mode="after")
    def _ordered_box(self) -> SafetyConfig:
        if (self.workspace_min is None) != (self.workspace_max is None):
            raise ValueError("workspace_min and workspace_max go together")
        if self.workspace_min is not None and not all(
            a < b for a, b in zip(self.workspace_min, self.workspace_max, strict=True)
        ):
            raise ValueError("workspace_min must be below workspace_max on every axis")
        return self


class ControlConfig(_Strict):
    mode: ControlMode
    control_rate: Positive  # Hz
    physics_timestep: Positive  # s
    home: list[Finite]  # rad, one per joint


class TaskConfig(_Strict):
    """Where goals are sampled.

    ``planar_annulus``: radius and angle in the XY plane; ``box``: uniform in
    [box_min, box_max], or, with ``joint_fraction``, the end effector at joint poses drawn
    uniformly within that fraction of each joint's range about home (clipped into the soft
    limits), kept when inside the box: every goal is one the arm reaches (a box corner may not
    be: 4 % of so101's uniform box goals lie over 3 cm from any pose within the soft limits).

    ``scene``: an MJCF in the robot's folder that a camera watching the task renders: the robot's
    MJCF included first, a mocap body ``goal`` the goal moves and the cameras outside the robot
    (``sim2real.deploy.backends.sim.task_scene``); drawn, never simulated, and, as the rest of
    ``[task]``, left out of the description hash.
    """

    region: Literal["planar_annulus", "box"]
    scene: str | None = None  # file name in the robot's folder
    joint_fraction: Annotated[float, Field(gt=0.0, le=1.0)] | None = None
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
        if self.joint_fraction is not None and self.region != "box":
            raise ValueError(f"joint_fraction applies to region 'box', not '{self.region}'")
        return self


class SoakConfig(_Strict):
    """Disturbances of the soak sized to this robot (``[soak]``; left out of the description
    hash, as ``[task]``). Unset fields keep :class:`sim2real.eval.world.fault_schedule.FaultRanges`'
    defaults.

    ``push_force``: range (N) of the pushes on the end effector (on the base of a floating-base
    robot). The default 5-25 N suits arm3 (its drives hold 14.9 N at the tip for an instant,
    ``sim2real.eval.world.fault_schedule.cable_budget``); a desktop servo arm holds a fraction of that.
    ``robot-import --floating-base`` writes a legged robot's from its mass
    (``sim2real.robots.importer.legged_toml.PUSH_VELOCITY``).
    """

    push_force: tuple[NonNegative, NonNegative] | None = None  # N

    @model_validator(mode="after")
    def _ordered(self) -> SoakConfig:
        if self.push_force is not None and self.push_force[0] > self.push_force[1]:
            raise ValueError(f"push_force: expected [low, high] N, got {list(self.push_force)}")
        return self


class UnitreeConfig(_Strict):
    """How a Unitree robot's low-level DDS interface maps to this description (``[unitree]``;
    ``deploy-run --backend unitree``; left out of the description hash, as ``[task]``: wiring,
    not dynamics).

    ``family``: the message family the robot speaks (``unitree_go``: Go2, Go1, B2, H1;
    ``unitree_hg``: G1, H1-2). ``motor_index``: the motor slot of each joint, in joint order
    (the Go2's motors run FR, FL, RR, RL, hip-thigh-calf; its description's joints FL, FR, RL,
    RR). ``foot_index``: the ``foot_force`` slot of each ``[base] feet`` entry (``unitree_go``).
    ``motor_mode``: the ``mode`` byte of an enabled motor (0x01 on the Go2 and the
    ``unitree_hg`` robots; 0x0A on the H1's servo motors). ``damping_kd``: N m s/rad, the
    damping command's gain (kp 0), per joint or one for all. ``ramp_time``: s, the bring-up's
    ramp from the measured to the home pose; ``ramp_kp`` (N m/rad), ``ramp_kd`` (N m s/rad): its
    gains, per joint or one for all (default: the joints' kp/kd; a policy's gains may be too
    soft to stand a robot up), blended into the joints' at the end of the ramp.
    ``foot_force_scale``: N per ``foot_force`` count.
    ``driver_errors``: read the drivers' error codes (``unitree_go``: ``motor_state.reserve[0]``;
    ``unitree_hg``: ``motor_state.motorstate``) as faults.
    """

    family: Literal["unitree_go", "unitree_hg"]
    motor_index: list[Annotated[int, Field(ge=0)]]
    foot_index: list[Annotated[int, Field(ge=0)]] = []
    motor_mode: Annotated[int, Field(ge=0, le=255)] = 1
    damping_kd: NonNegative | list[NonNegative]
    ramp_time: Positive = 2.0  # s
    ramp_kp: Positive | list[Positive] | None = None  # N m/rad
    ramp_kd: NonNegative | list[NonNegative] | None = None  # N m s/rad
    foot_force_scale: Positive = 1.0  # N per count
    driver_errors: bool = True

    @model_validator(mode="after")
    def _distinct(self) -> UnitreeConfig:
        slots = 20 if self.family == "unitree_go" else 35
        for name in ("motor_index", "foot_index"):
            index = getattr(self, name)
            if len(set(index)) != len(index) or any(i >= slots for i in index):
                raise ValueError(
                    f"{name}: expected distinct slots below {slots} ({self.family}), got {index}"
                )
        return self


class RobotConfig(_Strict):
    """The whole ``robot.toml``."""

    name: str
    mjcf: str  # path relative to robot.toml
    #: the robot's kind (sim2real.deploy.robot_kind: "arm", "legged", "wheel_legged" or a registered
    #: one); None: "legged" with a [base] table ("wheel_legged" with velocity-driven joints too),
    #: else "arm"
    kind: str | None = None
    control: ControlConfig
    joints: Annotated[list[JointConfig], Field(min_length=1)]
    motors: dict[str, MotorConfig]
    sensors: SensorConfig
    safety: SafetyConfig
    task: TaskConfig | None = None  # required for a fixed-base arm
    base: BaseConfig | None = None  # a floating-base robot (legged)
    soak: SoakConfig | None = None  # the soak's disturbances sized to this robot
    unitree: UnitreeConfig | None = None  # deploy-run --backend unitree: motor slots, family

    @model_validator(mode="after")
    def _cross_references(self) -> RobotConfig:
        if self.base is None:
            for name in ("end_effector_site", "workspace_min"):
                if getattr(self.safety, name) is None:
                    raise ValueError(
                        f"safety.{name} is required for a fixed-base arm (no [base] table)"
                    )
            if self.task is None:
                raise ValueError("[task] is required for a fixed-base arm (no [base] table)")
        else:
            missing = [k for k in ("imu", "contact") if getattr(self.sensors, k) is None]
            if missing:
                raise ValueError(
                    f"a floating-base robot ([base]) needs "
                    f"{' and '.join(f'[sensors.{k}]' for k in missing)}"
                )
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
        u = self.unitree
        if u is not None:
            if len(u.motor_index) != len(self.joints):
                raise ValueError(
                    f"unitree.motor_index has {len(u.motor_index)} slots, expected one per joint "
                    f"({len(self.joints)})"
                )
            for name in ("damping_kd", "ramp_kp", "ramp_kd"):
                value = getattr(u, name)
                if isinstance(value, list) and len(value) != len(self.joints):
                    raise ValueError(
                        f"unitree.{name} has {len(value)} values, expected one or one per joint "
                        f"({len(self.joints)})"
                    )
            feet = len(self.base.feet) if self.base is not None else 0
            if len(u.foot_index) not in (0, feet):
                raise ValueError(
                    f"unitree.foot_index has {len(u.foot_index)} slots, expected one per "
                    f"[base] feet entry ({feet})"
                )
        return self
