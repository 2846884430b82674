"""PolicySpec: the observation and action contract of a policy.

One spec describes what a policy sees and what its outputs mean. Training builds observations with
it, export stores it as JSON in the ONNX file, and the runtime refuses a policy whose spec does not
match the robot. It removes the commonest sim-to-real bug: observations fed in another order, scale
or unit than in training, or action post-processing forgotten.

Observation: the concatenation of ordered blocks; each block computes a raw quantity in SI units and
normalizes it as ``clip((raw - offset) / scale, -clip, clip)``. The scales are physical maxima
(joint limit, maximum velocity, reach, maximum winding temperature), never statistics of observed
data. The block kinds, with their sizes, units and scales, are the registry
:mod:`sim2real.deploy.spec.kinds`.

Convention: ``scale`` is a *divisor* and ``offset`` is subtracted first, per entry, in the raw
quantity's SI unit. A training library that multiplies instead (legged_gym's ``obs_scales``,
Isaac Lab's term ``scale``), ``obs = (raw - default) * s``, is ``offset = default``, ``scale =
1 / s``: legged_gym's ``dof_vel`` 0.05 is ``scale`` 20, ``ang_vel`` 0.25 is 4, ``lin_vel`` 2.0 is
0.5, ``dof_pos`` 1.0 about ``default_angles`` is ``scale`` 1 with ``offset`` the default pose. In
JSON ``scale`` and ``offset`` may be one number or one per entry (``sim2real.deploy.spec.schema``; the
JSON Schema is ``docs/policy_spec.schema.json``).

Action: ``a`` in ``[-clip, clip]^n`` maps to the target of the control mode,
``target = offset + scale * a`` (``reference = "absolute"``) or ``target = q + scale * a``
(position mode, ``reference = "current"``); :mod:`sim2real.deploy.spec.defaults` gives a robot's scales.
Arrays are shaped (envs, ...); ``observation`` and ``action_to_target`` write into ``out`` when
it is given (no allocation in the control loop). A block and the action mapping are
:mod:`sim2real.deploy.spec.contract_parts`' records.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.spec.block_checks import observation_problems
from sim2real.deploy.spec.camera import DepthImageBlock, RgbImageBlock
from sim2real.deploy.spec.contract_parts import (  # noqa: F401 - importable from here too
    DEFAULT_CLIP,
    SMOOTHING,
    UNCLIPPED,
    ActionSpec,
    ObservationBlock,
)
from sim2real.deploy.spec.drive import DriveSpec
from sim2real.deploy.spec.history import ObservationHistory, stacked_dim
from sim2real.deploy.spec.kinds import KINDS, kind_names
from sim2real.robots import CONTROL_MODES, Robot
from sim2real.robots.errors import Sim2RealError

if TYPE_CHECKING:
    from sim2real.deploy.spec.observation_plan import ObservationPlan

FORMAT_VERSION = 1
#: A floating-base robot's default observation (legged_gym's, with the gait clock of
#: unitree_rl_gym and without the base linear velocity, which needs the estimator to converge).
LEGGED_DEFAULT_BLOCKS = (
    "base_angular_velocity",
    "projected_gravity",
    "velocity_command",
    "gait_phase",
    "joint_position",
    "joint_velocity",
    "last_action",
)
#: Divisors of the legged blocks: 1 / legged_gym's ``obs_scales`` (LeggedRobotCfg.normalization:
#: lin_vel 2.0, ang_vel 0.25, dof_vel 0.05; commands scaled like the velocities they command).
LEGGED_SCALES = {
    "base_linear_velocity": (0.5, 0.5, 0.5),
    "base_angular_velocity": (4.0, 4.0, 4.0),
    "velocity_command": (0.5, 0.5, 4.0),
    "joint_velocity": 20.0,
}
#: Position actions about the home pose, rad per unit action (legged_gym
#: LeggedRobotCfg.control.action_scale).
LEGGED_ACTION_SCALE = 0.25
#: A legged policy's action clip (legged_gym LeggedRobotCfg.normalization.clip_actions): its
#: targets reach past the joints' ranges, where the guard clamps them (counted).
LEGGED_ACTION_CLIP = 100.0
#: The gait clock's period, s (unitree_rl_gym legged_gym/envs/go2: the phase period 0.8 s).
GAIT_PERIOD = 0.8


class SpecError(Sim2RealError, ValueError):
    """A PolicySpec is invalid or does not match a robot; the message names the field."""


@dataclass(frozen=True)
class PolicySpec:
    """The contract of a policy: robot, joint order, observation layout, action mapping, rates.

    Attributes:
        robot: Robot name. joint_names: Joint order of observations and actions.
        robot_hash: ``Robot.description_hash`` of the description trained on.
        observation_blocks: Ordered observation blocks (JSON key ``observation``).
        action: The action mapping.
        control_rate: Hz, the rate the policy was trained at.
        baked: What the ONNX graph already contains (``observation_normalizer``: an empirical
            normalizer of a training library; ``action_clip``).
        parity: Parity figures of the export (max abs error, samples), filled by export.
        format_version: Version of this JSON format; other versions are refused.
        constant_inputs: Graph inputs besides the observation and recurrent state, fed this
            constant every tick (name -> value; JSON key ``constant_inputs``, left out when empty).
        drive: The PD gains and default pose the policy was trained with
            (:class:`sim2real.deploy.spec.drive.DriveSpec`, ``joint_names`` order; None: not recorded;
            JSON key ``drive``, left out when None).
        history: The frame history the graph reads (:class:`sim2real.deploy.spec.history.
            ObservationHistory`: ticks, order, layout, fill); None: one frame, the present.
        images: The graph's image inputs besides the observation vector
            (:class:`sim2real.deploy.spec.camera.DepthImageBlock`: camera, shape, crop, resize,
            clip, normalisation, frames and skip; :class:`~sim2real.deploy.spec.camera.
            RgbImageBlock`, ``"kind": "rgb"``: channel order, layout, mean and std besides; JSON
            key ``images``, left out when empty).

    ``robot_hash`` may be empty (a spec written by hand for a policy trained elsewhere): the
    description hash is then not checked.
    """

    robot: str
    joint_names: tuple[str, ...]
    robot_hash: str
    observation_blocks: tuple[ObservationBlock, ...]
    action: ActionSpec
    control_rate: float
    baked: dict[str, bool] = field(default_factory=dict)
    parity: dict[str, Any] = field(default_factory=dict)
    format_version: int = FORMAT_VERSION
    constant_inputs: dict[str, float] = field(default_factory=dict)
    drive: DriveSpec | None = None
    history: ObservationHistory | None = None
    images: tuple[DepthImageBlock | RgbImageBlock, ...] = ()

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_robot(
        cls,
        robot: Robot,
        blocks: tuple[str, ...] | None = None,
        mode: str | None = None,
        reference: str = "absolute",
        position_range: str = "soft",
    ) -> PolicySpec:
        """Standard spec for ``robot`` with physical scales taken from the robot description.

        Joints whose range exceeds 2 pi (multi-turn) are wrapping joints: ``joint_position``
        skips them and ``joint_position_sincos`` covers them. A velocity action is scaled by the
        soft velocity limit (the fastest command the smoother issues, so a full action is never
        clamped), a torque action by the effort limit, an absolute position action by half the
        soft range about its centre (``position_range="soft"``: a full action is the soft limit,
        so no action in ``[-1, 1]`` is clamped by the guard) or by half the hard range
        (``position_range="hard"``: an adversary's, past the soft limits). Legged robots' absolute
        position actions are legged_gym's (``LEGGED_ACTION_SCALE`` about the default pose).

        Default blocks: ``joint_position``, ``joint_position_sincos`` (only when the robot has
        wrapping joints), ``joint_velocity``, ``ee_position``, ``goal_position``, ``goal_in_ee``.

        Built by :func:`sim2real.deploy.spec.defaults.spec_for_robot`.

        Raises:
            SpecError: unknown block kind, control mode or position range.
        """
        from sim2real.deploy.spec.defaults import spec_for_robot

        return spec_for_robot(cls, robot, blocks, mode, reference, position_range)

    # ------------------------------------------------------------------ properties
    @property
    def obs_dim(self) -> int:
        """Entries of the graph's input: :attr:`frame_dim` times the history's ticks."""
        return stacked_dim(self.history, tuple(b.size for b in self.observation_blocks))

    @property
    def frame_dim(self) -> int:
        """Entries of one tick's frame: the blocks' sizes summed (= ``obs_dim`` without history)."""
        return sum(b.size for b in self.observation_blocks)

    @property
    def act_dim(self) -> int:
        return self.action.size

    def block_slices(self) -> dict[str, slice]:
        """Where each block sits in a frame (the observation without history), by kind (a kind
        that occurs in two blocks, as a velocity command split in two: the last)."""
        out, start = {}, 0
        for b in self.observation_blocks:
            out[b.name] = slice(start, start + b.size)
            start += b.size
        return out

    # ------------------------------------------------------------------ validation
    def validate(self) -> None:
        """Check internal consistency.

        Raises:
            SpecError: naming the field.
        """
        if self.format_version != FORMAT_VERSION:
            raise SpecError(
                f"format_version: {self.format_version} is not supported; expected {FORMAT_VERSION}"
            )
        n = len(self.joint_names)
        problems = observation_problems(self.observation_blocks, n, self.action.driven)
        if problems:
            raise SpecError(problems[0])
        a = self.action
        if a.mode not in CONTROL_MODES:
            raise SpecError(f"action.mode: '{a.mode}' is unknown; expected one of {CONTROL_MODES}")
        if a.size != n or len(a.scale) != n or len(a.offset) != n:
            raise SpecError(f"action: size, scale and offset need one entry per joint ({n})")
        if a.reference not in ("absolute", "current") or (
            a.reference == "current" and a.mode != "position"
        ):
            raise SpecError(f"action.reference: '{a.reference}' is not valid for mode '{a.mode}'")
        if a.smoothing not in SMOOTHING or (a.smoothing == "none" and a.mode != "position"):
            raise SpecError(
                f"action.smoothing: '{a.smoothing}' is not valid for mode '{a.mode}'; expected "
                "'none' (position mode: PD targets as the policy emits them) or 'jerk_limited'"
            )
        if a.joints and (
            len(set(a.joints)) != len(a.joints) or not all(0 <= j < n for j in a.joints)
        ):
            raise SpecError(
                f"action.joints: {list(a.joints)} must be distinct joint indices in 0..{n - 1}"
            )
        if not self.control_rate > 0:
            raise SpecError(f"control_rate: must be positive, got {self.control_rate}")
        problems = self.drive.problems(n) if self.drive is not None else []
        if not problems and self.drive is not None and any(self.drive.velocity(n)):
            speed = [j for j, v in enumerate(self.drive.velocity(n)) if v]
            if a.mode != "position" or a.reference != "absolute" or any(a.offset[j] for j in speed):
                problems.append(
                    f"action: a velocity drive's target is scale x action (rad/s, about 0): "
                    f"mode 'position', reference 'absolute' and offset 0 at joints {speed}, got "
                    f"mode '{a.mode}', reference '{a.reference}', offsets "
                    f"{[a.offset[j] for j in speed]}"
                )
        if self.history is not None:
            problems += self.history.problems(len(self.observation_blocks))
        for i, image in enumerate(self.images):
            problems += image.problems(f"images[{i}]")
        if len({b.input for b in self.images}) < len(self.images):
            problems.append(
                f"images: two blocks name one graph input: {[b.input for b in self.images]}"
            )
        if problems:
            raise SpecError(problems[0])
        for name, value in self.constant_inputs.items():
            if not np.isfinite(value):
                raise SpecError(f"constant_inputs['{name}']: must be finite, got {value}")

    def on_robot(self, robot: Robot) -> PolicySpec:
        """This spec over every joint of ``robot`` (:func:`sim2real.deploy.spec.subset.widen`): itself
        when it names the robot's joints; a policy over some of them, widened so that the
        others are held at home.

        Raises:
            SpecError: a joint the robot does not have.
        """
        from sim2real.deploy.spec.subset import widen

        return widen(self, robot)

    def check_robot(self, robot: Robot, check_hash: bool = True) -> None:
        """Refuse a robot this policy was not made for.

        Raises:
            SpecError: naming the mismatch (robot name, joint names/order, control rate, action
                size, description hash).
        """
        if self.robot != robot.name:
            raise SpecError(f"robot: policy is for '{self.robot}', the robot is '{robot.name}'")
        if tuple(self.joint_names) != robot.joint_names:
            raise SpecError(
                f"joint_names: policy expects {list(self.joint_names)}, "
                f"the robot has {list(robot.joint_names)}"
                + (
                    " (a policy over some of the robot's joints runs through its spec's "
                    "on_robot(robot), which holds the others)"
                    if set(self.joint_names) < set(robot.joint_names)
                    else ""
                )
            )
        for i, b in enumerate(self.observation_blocks):
            kind = KINDS.get(b.name)
            if kind is not None and kind.needs_base and not robot.floating_base:
                provided = kind_names(needs_base=False)
                raise SpecError(
                    f"observation[{i}] ('{b.name}'): block '{b.name}' cannot be provided: the "
                    f"robot '{robot.name}' is a fixed-base arm (no IMU, no feet); blocks it "
                    f"provides: {', '.join(provided)}"
                )
            if kind is not None and kind.per_foot and b.size != robot.n_feet:
                raise SpecError(
                    f"observation[{i}] ('{b.name}'): size {b.size}, the robot '{robot.name}' "
                    f"has {robot.n_feet} feet"
                )
        rate = 1.0 / robot.control_period
        if abs(self.control_rate - rate) > 1e-6:
            raise SpecError(
                f"control_rate: policy runs at {self.control_rate} Hz, the robot at {rate} Hz"
            )
        if check_hash and self.robot_hash and self.robot_hash != robot.description_hash:
            raise SpecError(
                f"robot_hash: policy was made for description {self.robot_hash[:12]}..., the robot "
                f"is {robot.description_hash[:12]}... (robot.toml or MJCF changed since training)"
            )

    # ------------------------------------------------------------------ the two mappings
    def observation(
        self, state: RobotState, goal: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        """Normalized observation, float32 (envs, obs_dim).

        Args:
            state: Estimated state with end-effector pose filled (``Kinematics.update``).
            goal: (envs, 3) m, goal position in the base frame.
            out: Optional float32 (envs, obs_dim) array to write into.

        The spec's compiled plan (:class:`sim2real.deploy.spec.observation_plan.ObservationPlan`, built on
        the first call) assembles it; the numpy reference is
        :func:`sim2real.deploy.spec.reference.observation_reference` (the same numbers bit for bit).

        Raises:
            SpecError: a floating-base block and a state without a base.
        """
        return self.plan.observation(state, goal, out)

    @cached_property
    def plan(self) -> ObservationPlan:
        """The spec's observation plan (:class:`~sim2real.deploy.spec.observation_plan.ObservationPlan`),
        built on first use and the same object after: its layout, norm and kernel arguments
        (:meth:`~sim2real.deploy.spec.observation_plan.ObservationPlan.kernel_args`)."""
        from sim2real.deploy.spec.observation_plan import ObservationPlan

        return ObservationPlan(self)

    def action_to_target(
        self, action: np.ndarray, state: RobotState, out: np.ndarray | None = None
    ) -> np.ndarray:
        """Target in the units of the control mode, float64 (envs, n): ``offset + scale x
        clip(action)`` (``q + ...`` for reference 'current'); a velocity drive's column
        (``drive.kinds``, offset 0) is then its speed target, rad/s.

        Args:
            action: (envs, n) policy output; clipped to ``[-clip, clip]`` first.
            state: Estimated state (``q`` is the reference of 'current' position actions).
            out: Optional (envs, n) float64 array to write into.
        """
        a = self.action
        if out is None:
            out = np.empty(action.shape, dtype=np.float64)
        np.minimum(np.maximum(action, -a.clip, out=out), a.clip, out=out)
        out *= a.scale
        out += state.q if a.reference == "current" else a.offset
        return out

    # ------------------------------------------------------------------ JSON
    def to_json(self) -> str:
        """The spec as JSON, every field explicit (sorted keys; ``constant_inputs``,
        ``drive``, a block's ``components`` and the action's ``joints`` only when set, so a spec
        without them writes what earlier versions wrote)."""
        d = asdict(self)
        d["observation"] = d.pop("observation_blocks")
        for block in d["observation"]:
            if not block["period"]:  # gait_phase, motion_phase: others write what they wrote before
                del block["period"]
            if not block["components"]:
                del block["components"]
            if block["scan"] is None:  # height_scan only
                del block["scan"]
            for key in ("stand_below", "stand_phase"):  # a gait clock that stops only
                if not block[key]:
                    del block[key]
        if not d["action"]["joints"]:
            del d["action"]["joints"]
        if not d["action"]["smoothing"]:
            del d["action"]["smoothing"]
        if not d["constant_inputs"]:
            del d["constant_inputs"]
        if d["drive"] is None:
            del d["drive"]
        else:
            d["drive"] = {k: v for k, v in d["drive"].items() if v}
        if d["images"]:  # each block's own JSON (an RGB block's says its kind)
            d["images"] = [b.to_dict() for b in self.images]
        else:
            del d["images"]
        if d["history"] is None:
            del d["history"]
        elif not d["history"]["lengths"]:
            del d["history"]["lengths"]
        return json.dumps(d, sort_keys=True)

    @classmethod
    def from_json(cls, text: str, source: str = "spec") -> PolicySpec:
        """Parse and validate a spec (:func:`sim2real.deploy.spec.schema.parse_spec`: the format and
        the shorthands it expands: ``scale``/``offset`` as one number, ``size``, ``joints``,
        ``robot_hash`` left out, joints by name).

        Raises:
            SpecError: invalid JSON, unknown format version, missing, unknown or invalid field (the
                message starts with ``source`` and names the field).
        """
        from sim2real.deploy.spec.schema import parse_spec

        return parse_spec(text, source)
