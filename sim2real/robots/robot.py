"""The Robot: one description (MJCF + robot.toml) from which MuJoCo and Pinocchio are both built.

Holds :class:`Robot` and :class:`RobotSpecError`; :mod:`sim2real.robots.loading` reads and validates a
description into a Robot (:func:`sim2real.robots.loading.load_robot`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin

from sim2real.robots.errors import Sim2RealError
from sim2real.robots.schema import CONTROL_MODES, MotorConfig, RobotConfig


class RobotSpecError(Sim2RealError, ValueError):
    """A robot description is invalid.

    The message names the file, the field and what was expected.
    """


#: Control periods the stale limit spans at least (:attr:`Robot.stale_limit`): a reading's time in
#: flight (1) + the largest sensor latency the soak draws and the simulated backends emulate
#: (2 ticks: ``sim2real.eval.world.sensors.SensorRanges.latency_ticks``) + a run of 4 readings of
#: one joint lost in a row to the session's own random dropout, which at the soak's highest
#: probability (0.001 per reading and joint, ``SensorRanges.dropout``) a 30-joint robot at 50 Hz
#: meets about 30 * 50 * 3600 * 1e-12 = 5e-6 times an hour (3 in a row: 5e-3; 2 in a row: 5 an
#: hour), all strictly below the limit: (1 + 2 + 4) < 8.
MIN_STALE_TICKS = 8

#: What :func:`lock_free_flyer` appends to a site's frame name while Pinocchio reduces the model.
_SITE_TAG = "\x00site"


def lock_free_flyer(model: pin.Model, geom: pin.GeometryModel | None = None):
    """``pin.buildReducedModel`` of ``model`` with its free flyer (joint 1) locked at the origin,
    upright: the reduced model, or ``(model, geometry)`` with ``geom``.

    Pinocchio's reduction looks frames up by name alone, which raises "Several frames match the
    filter" when a site's frame (an MJCF site is an ``OP_FRAME``) shares its name with the body
    it sits on and that body carries a fixed child body (the importer names foot sites after
    their link; holosoma's G1 hangs ``*_foot_contact_point`` under each ankle link). Such site
    frames are renamed for the reduction and named back after it: a lookup by name and type
    finds the body's ``BODY`` frame and the site's ``OP_FRAME`` as in ``model``.
    """
    work = pin.Model(model)
    names = [f.name for f in work.frames]
    for i, name in enumerate(names):
        if work.frames[i].type == pin.FrameType.OP_FRAME and names.count(name) > 1:
            work.frames[i].name = f"{name}{_SITE_TAG}{i}"
    q = pin.neutral(work)
    if geom is None:
        reduced = out = pin.buildReducedModel(work, [1], q)
    else:
        out = pin.buildReducedModel(work, geom, [1], q)
        reduced = out[0]
    for i in range(reduced.nframes):
        if _SITE_TAG in reduced.frames[i].name:
            reduced.frames[i].name = reduced.frames[i].name.split(_SITE_TAG)[0]
    return out


@dataclass(frozen=True, eq=False)
class Robot:
    """A validated robot: spec, MuJoCo model and Pinocchio model built from the same MJCF.

    Arrays are read-only, shaped ``(n_joints,)``, in the joint order of ``joint_names``.

    Attributes:
        name: Robot name from robot.toml.
        directory: Folder holding robot.toml and the MJCF.
        mjcf_path: Path of the MJCF file MuJoCo and Pinocchio read: the robot folder's, or a
            copy with its ``package://`` meshdir resolved (see
            ``sim2real.robots.packages.resolved_mjcf``).
        config: The validated robot.toml (``sim2real.robots.schema.RobotConfig``).
        joint_names: Joint names in kinematic (and action/observation) order.
        position_lower, position_upper: Hard joint limits, rad.
        soft_lower, soft_upper: Soft limits (``soft_limit_fraction`` of the range about its
            centre), rad. Crossing one is a warning, not a violation.
        velocity_limit: Hard velocity limit, rad/s: the joint itself must stay within it.
        soft_velocity_limit: ``soft_limit_fraction`` of ``velocity_limit``, rad/s. The margin
            is for the drive's servo, which tracks a velocity command with overshoot (figures:
            docs/measurements.md).
        command_velocity_limit: rad/s, the fastest command the smoother issues: robot.toml's
            ``command_velocity_limit`` of the joint, else ``soft_velocity_limit``, lowered on a
            fixed base to the speed at which the joint's motor still holds it against gravity
            (:func:`sim2real.robots.chain_bounds.holding_command_limit`). A legged
            robot's PD position targets have their own (``robot-import --target-limits pd``,
            :func:`sim2real.robots.importer.legged.pd_target_limits`): its drive, not its target's
            speed, bounds how fast the joint moves.
        acceleration_limit: rad/s^2. jerk_limit: rad/s^3.
        effort_limit: N m at the joint.
        motors: The motor of each joint, per joint.
        home: Home pose, rad.
        control_period: 1 / control_rate, s. physics_timestep: s.
        decimation: Physics steps per control tick (an integer; checked).
        mj_model: MuJoCo model without actuators (kinematics and dynamics reference).
        pin_model: Pinocchio model; velocity and effort limits set from robot.toml, gravity from
            the MJCF ``<option gravity>``.
        ee_frame_id: Pinocchio frame id of the end-effector site.
        ee_site_id: MuJoCo site id of the end-effector site.
        description_hash: sha256 (hex) of the robot.toml fields except ``[task]``, ``[soak]``
            and ``[unitree]`` (canonical JSON) and the MJCF bytes; a policy records it.
        floating_base: True for a robot whose base moves freely (``[base]`` in robot.toml):
            MuJoCo's ``<freejoint>`` (qpos ``[x y z, qw qx qy qz, joints]``, qvel ``[v world,
            omega body, dq]``) and Pinocchio's free-flyer root joint (q ``[x y z, qx qy qz qw,
            joints]``, v ``[v body, omega body, dq]``). False for a fixed-base arm (the fields
            below are then empty or -1).
        base_body: MuJoCo body (and Pinocchio frame) of the base; None for an arm.
        base_frame_id: Pinocchio frame id of ``base_body``.
        imu_site: Site of the gyroscope and accelerometer; imu_site_id (MuJoCo),
            imu_frame_id (Pinocchio).
        foot_sites: One site a foot (centre of its contact sphere); foot_site_ids (MuJoCo),
            foot_frame_ids (Pinocchio), in the order of ``[base] feet``.
    """

    name: str
    directory: Path
    mjcf_path: Path
    config: RobotConfig
    joint_names: tuple[str, ...]
    position_lower: np.ndarray
    position_upper: np.ndarray
    soft_lower: np.ndarray
    soft_upper: np.ndarray
    velocity_limit: np.ndarray
    soft_velocity_limit: np.ndarray
    command_velocity_limit: np.ndarray
    acceleration_limit: np.ndarray
    jerk_limit: np.ndarray
    effort_limit: np.ndarray
    motors: tuple[MotorConfig, ...]
    home: np.ndarray
    control_period: float
    physics_timestep: float
    decimation: int
    mj_model: mujoco.MjModel = field(repr=False)
    pin_model: pin.Model = field(repr=False)
    ee_frame_id: int
    ee_site_id: int
    description_hash: str
    floating_base: bool = False
    base_body: str | None = None
    base_frame_id: int = -1
    imu_site: str | None = None
    imu_site_id: int = -1
    imu_frame_id: int = -1
    foot_sites: tuple[str, ...] = ()
    foot_site_ids: tuple[int, ...] = ()
    foot_frame_ids: tuple[int, ...] = ()

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_feet(self) -> int:
        """Number of feet (0 for a fixed-base arm)."""
        return len(self.foot_sites)

    @property
    def stale_limit(self) -> float:
        """s without a fresh reading (an encoder's, the IMU's, an elevation map's) before the
        runtime safe-stops (``stale_sensor``): robot.toml's ``safety.stale_limit`` or
        :data:`MIN_STALE_TICKS` control periods, the longer. A fixed time alone spans fewer
        ticks the longer the period: at 50 Hz, 0.05 s is 2.5 periods, and one tick of latency
        with two readings lost to random dropout passes it (0.06 s). So the limit spans at least
        the latency and the dropout runs a sensor in order shows (0.16 s at 50 Hz, 0.08 s at
        100 Hz, robot.toml's 0.05 s at 200 Hz and above); a sensor silent longer than that still
        stops the robot."""
        return max(float(self.config.safety.stale_limit), MIN_STALE_TICKS * self.control_period)

    @property
    def qpos_offset(self) -> int:
        """Index of the first joint angle in MuJoCo's ``qpos`` (7 with a free joint, else 0)."""
        return 7 if self.floating_base else 0

    @property
    def qvel_offset(self) -> int:
        """Index of the first joint velocity in MuJoCo's ``qvel`` (6 with a free joint, else 0)."""
        return 6 if self.floating_base else 0

    def pin_configuration(
        self,
        q: np.ndarray,
        base_position: np.ndarray | None = None,
        base_quaternion: np.ndarray | None = None,
    ) -> np.ndarray:
        """Pinocchio configuration from joint angles ``q`` (rad, (n,)) and, for a floating base,
        its position (m, world, (3,), default 0) and orientation (unit quaternion ``[w, x, y,
        z]`` as MuJoCo orders it, default identity); Pinocchio orders it ``[x, y, z, w]``."""
        q = np.asarray(q, dtype=np.float64)
        if not self.floating_base:
            return q
        pos = np.zeros(3) if base_position is None else np.asarray(base_position, np.float64)
        wxyz = np.array([1.0, 0, 0, 0]) if base_quaternion is None else base_quaternion
        wxyz = np.asarray(wxyz, dtype=np.float64)
        return np.concatenate([pos, wxyz[1:], wxyz[:1], q])

    @cached_property
    def fixed_base_model(self) -> pin.Model:
        """Pinocchio model of the joints alone, ``nq = n_joints``: ``pin_model`` for a fixed-base
        arm; for a floating base, ``pin_model`` with its free-flyer locked at the origin, upright
        (``pin.buildReducedModel``): the base frame is the world frame. The guard's kinematics,
        gravity torques (the legs in the air) and self-collisions run on it."""
        if not self.floating_base:
            return self.pin_model
        return lock_free_flyer(self.pin_model)

    def fixed_base_geometry(self, geom: pin.GeometryModel) -> pin.GeometryModel:
        """A geometry model built on ``pin_model``, attached to :attr:`fixed_base_model` instead
        (the same object for a fixed-base arm)."""
        if not self.floating_base:
            return geom
        return lock_free_flyer(self.pin_model, geom)[1]

    def foot_positions(
        self,
        q: np.ndarray,
        base_position: np.ndarray | None = None,
        base_quaternion: np.ndarray | None = None,
    ) -> np.ndarray:
        """Foot site positions (m, world frame), shape (n_feet, 3), for joint angles ``q`` (rad)
        and the base pose (see :meth:`pin_configuration`; default: base frame)."""
        data = self.pin_model.createData()
        pin.framesForwardKinematics(
            self.pin_model, data, self.pin_configuration(q, base_position, base_quaternion)
        )
        return np.array([data.oMf[f].translation for f in self.foot_frame_ids]).reshape(-1, 3)

    @property
    def control_mode(self) -> str:
        """Default control mode from robot.toml: 'position', 'velocity' or 'torque'."""
        return self.config.control.mode

    @property
    def velocity_driven(self) -> np.ndarray:
        """(n_joints,) bool: joints whose position-mode command is a speed target, rad/s
        (robot.toml ``drive = "velocity"``: a wheel, ``tau = kd (v_target - dq)``); the others
        take PD position targets."""
        return np.array([j.drive == "velocity" for j in self.config.joints], dtype=bool)

    def mjspec(self, mode: str | None = None) -> mujoco.MjSpec:
        """A fresh ``mujoco.MjSpec`` of the robot with its drives for ``mode``.

        Position mode: a PD servo per joint (``kp``, ``kd``), its target clamped to the joint's
        range where the real drive clamps it (:attr:`clamps_position_target`; a Unitree motor runs
        its PD law on any target: the range is the joint's stop, a contact). Velocity mode: a
        drive's PI velocity loop, ``tau = kd (v_cmd - dq) + kp (s - q)`` with the setpoint ``s`` the
        integral of the command (bounded to the joint range), as two actuators per joint that take
        the same command: ``<joint>_velocity`` (MuJoCo ``intvelocity`` with ``kp``: the integral
        term) and ``<joint>_velocity_p`` (MuJoCo ``velocity`` with ``kd``: the proportional term).
        The proportional term on the command matters: a servo that damps ``dq`` instead of ``v_cmd -
        dq`` lags ``a kd / kp`` behind an accelerating command (1.5 rad/s at 20 rad/s^2 on arm3) and
        overshoots when it catches up. A velocity-driven joint (:attr:`velocity_driven`) in
        position mode: MuJoCo ``velocity`` with ``kd``, its command a speed within
        ``velocity_limit``. Torque mode: a direct motor. The total actuator torque on
        each joint is limited to ``effort_limit`` (MuJoCo ``actuatorfrcrange``). Edit the returned
        spec (for example to randomize link lengths) and ``compile()`` it;
        :meth:`actuators_per_joint` gives ``nu / n_joints``.

        Raises:
            RobotSpecError: unknown control mode.
        """
        mode = self.control_mode if mode is None else mode
        if mode not in CONTROL_MODES:
            raise RobotSpecError(
                f"{self.directory / 'robot.toml'}: control mode '{mode}' is unknown; "
                f"expected one of {CONTROL_MODES}"
            )
        spec = mujoco.MjSpec.from_file(str(self.mjcf_path))
        spec.option.timestep = self.physics_timestep
        spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET

        def add(
            name: str, joint: str, lo: float, hi: float, limited: bool = True
        ) -> mujoco.MjsActuator:
            act = spec.add_actuator()
            act.name, act.target, act.trntype = name, joint, mujoco.mjtTrn.mjTRN_JOINT
            if limited:
                act.ctrlrange = [lo, hi]
                act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            else:
                act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
            return act

        clamps = self.clamps_position_target

        for i, joint in enumerate(self.config.joints):
            mj_joint = spec.joint(joint.name)
            mj_joint.actfrcrange = [-self.effort_limit[i], self.effort_limit[i]]
            mj_joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
            lo, hi = self.position_lower[i], self.position_upper[i]
            if mode == "position" and joint.drive == "velocity":  # tau = kd (ctrl - dq)
                vmax = self.velocity_limit[i]
                add(f"{joint.name}_position", joint.name, -vmax, vmax).set_to_velocity(kv=joint.kd)
            elif mode == "position":
                add(f"{joint.name}_position", joint.name, lo, hi, clamps[i]).set_to_position(
                    kp=joint.kp, kv=joint.kd
                )
            elif mode == "torque":
                effort = self.effort_limit[i]
                add(f"{joint.name}_torque", joint.name, -effort, effort).set_to_motor()
        if mode == "velocity":  # all integral terms first, then all proportional terms
            for i, joint in enumerate(self.config.joints):
                vmax = self.velocity_limit[i]
                act = add(f"{joint.name}_velocity", joint.name, -vmax, vmax)
                act.set_to_intvelocity(kp=joint.kp, kv=0.0)
                act.actrange = [self.position_lower[i], self.position_upper[i]]
                act.actlimited = mujoco.mjtLimited.mjLIMITED_TRUE
            for i, joint in enumerate(self.config.joints):
                vmax = self.velocity_limit[i]
                add(f"{joint.name}_velocity_p", joint.name, -vmax, vmax).set_to_velocity(
                    kv=joint.kd
                )
        return spec

    @property
    def clamps_position_target(self) -> tuple[bool, ...]:
        """Per joint: whether its drive clamps a position target to the joint's range (its
        motor's ``position_target.clamped``; False where the motor table says nothing: a clamp
        only where a motor file says so, as the catalog's servos and maxon drives do, while a
        Unitree motor runs its PD law on any target). The plant's position actuators follow it."""
        motors = self.config.motors
        return tuple(
            motors[j.motor].position_target is not None and motors[j.motor].position_target.clamped
            for j in self.config.joints
        )

    def actuators_per_joint(self, mode: str | None = None) -> int:
        """Actuators per joint of :meth:`mjspec` in ``mode`` (2 in velocity mode, else 1); each
        takes the joint's command, ordered ``[all joints' first, all joints' second]``."""
        mode = self.control_mode if mode is None else mode
        return 2 if mode == "velocity" else 1

    def plant_model(self, mode: str | None = None) -> mujoco.MjModel:
        """Compiled MuJoCo model with actuators for ``mode`` (see :meth:`mjspec`)."""
        return self.mjspec(mode).compile()

    def forward_kinematics(self, q: np.ndarray) -> np.ndarray:
        """End-effector position (m, base frame), shape (3,), for one configuration ``q`` (rad).

        Raises:
            RobotSpecError: the robot names no end-effector site (a floating-base robot).
        """
        if self.ee_frame_id < 0:
            raise RobotSpecError(
                f"{self.directory / 'robot.toml'}: field 'safety.end_effector_site' is not set"
            )
        data = self.pin_model.createData()
        pin.framesForwardKinematics(self.pin_model, data, self.pin_configuration(q))
        return data.oMf[self.ee_frame_id].translation.copy()

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """Joint torques (N m), shape (n_joints,), that hold configuration ``q`` against gravity
        (a floating base: held upright at the origin, the legs in the air)."""
        data = self.pin_model.createData()
        g = pin.computeGeneralizedGravity(self.pin_model, data, self.pin_configuration(q))
        return g[self.qvel_offset :].copy()
