"""The standard PolicySpec of a robot: :meth:`sim2real.deploy.spec.policy_spec.PolicySpec.for_robot`'s
construction.

From the robot description alone: the default observation blocks (an arm's joint, end-effector and
goal blocks; a floating-base robot's ``LEGGED_DEFAULT_BLOCKS``), each with its physical scale and
offset (joint limits, velocity limits, reach, winding temperature limits, legged_gym's divisors),
and the action mapping of the control mode. The kinds' sizes are the registry's
(:mod:`sim2real.deploy.spec.kinds`); the legged tables (``LEGGED_SCALES``, ...) are
:mod:`sim2real.deploy.spec.policy_spec`'s.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sim2real.deploy.core.state import Kinematics
from sim2real.deploy.spec.kinds import KINDS, kind_names
from sim2real.deploy.spec.policy_spec import (
    GAIT_PERIOD,
    LEGGED_ACTION_CLIP,
    LEGGED_ACTION_SCALE,
    LEGGED_DEFAULT_BLOCKS,
    LEGGED_SCALES,
    ActionSpec,
    ObservationBlock,
    PolicySpec,
    SpecError,
)
from sim2real.robots import CONTROL_MODES, Robot

#: What a full absolute position action reaches: ``soft`` (the default) the soft joint limits,
#: ``hard`` the hard ones (an adversarial policy's, to exercise the guard's soft clamp).
POSITION_RANGES = ("soft", "hard")


def _inside_range(lower: np.ndarray, upper: np.ndarray) -> tuple[tuple, tuple]:
    """Per-joint ``(scale, offset)`` with ``offset -+ scale`` inside ``[lower, upper]`` in float64
    (half the range about its centre, the scale shrunk by an ulp where rounding would put a full
    action past a limit)."""
    scale, offset = (upper - lower) / 2, (upper + lower) / 2
    for j in range(len(scale)):
        while offset[j] - scale[j] < lower[j] or offset[j] + scale[j] > upper[j]:
            scale[j] = np.nextafter(scale[j], 0.0)
    return tuple(scale), tuple(offset)


def spec_for_robot(
    cls: type[PolicySpec],
    robot: Robot,
    blocks: tuple[str, ...] | None = None,
    mode: str | None = None,
    reference: str = "absolute",
    position_range: str = "soft",
) -> PolicySpec:
    """:meth:`PolicySpec.for_robot` (see there): the standard spec of ``robot``, an instance of
    ``cls``.

    Raises:
        SpecError: unknown block kind, control mode or position range.
    """
    mode = robot.control_mode if mode is None else mode
    if mode not in CONTROL_MODES:
        raise SpecError(f"action.mode: '{mode}' is unknown; expected one of {CONTROL_MODES}")
    if position_range not in POSITION_RANGES:
        raise SpecError(
            f"action: position range '{position_range}' is unknown; expected one of "
            f"{POSITION_RANGES}"
        )
    n = robot.n_joints
    lo, hi = robot.position_lower, robot.position_upper
    wrapping = tuple(i for i in range(n) if hi[i] - lo[i] > 2 * np.pi + 1e-9)
    legged = robot.floating_base
    if blocks is None and legged:
        blocks = LEGGED_DEFAULT_BLOCKS
    elif blocks is None:
        blocks = (
            ("joint_position",)
            + (("joint_position_sincos",) if wrapping else ())
            + ("joint_velocity", "ee_position", "goal_position", "goal_in_ee")
        )
    reach = Kinematics(robot).reach() if robot.ee_frame_id >= 0 else 1.0
    out = [_block(kind, robot, legged, wrapping, reach) for kind in blocks]
    action = _action(robot, mode, legged, reference, position_range)
    spec = cls(
        robot=robot.name,
        joint_names=robot.joint_names,
        robot_hash=robot.description_hash,
        observation_blocks=tuple(
            replace(b, scale=tuple(map(float, b.scale)), offset=tuple(map(float, b.offset)))
            for b in out
        ),
        action=action,
        control_rate=1.0 / robot.control_period,
    )
    spec.validate()
    return spec


def _block(kind: str, robot: Robot, legged: bool, wrapping: tuple, reach: float):
    """The standard observation block ``kind`` of ``robot`` (its scales and offsets).

    Raises:
        SpecError: an unknown block kind.
    """
    n = robot.n_joints
    lo, hi = robot.position_lower, robot.position_upper
    if kind == "joint_position" and legged:  # about the default pose, unscaled
        idx = tuple(range(n))
        home = tuple(float(h) for h in robot.home)
        return ObservationBlock(kind, n, (1.0,) * n, home, joints=idx)
    elif kind == "joint_position":
        idx = tuple(i for i in range(n) if i not in wrapping)
        scale = tuple((hi[i] - lo[i]) / 2 for i in idx)
        offset = tuple((hi[i] + lo[i]) / 2 for i in idx)
        return ObservationBlock(kind, len(idx), scale, offset, joints=idx)
    elif kind == "joint_velocity":
        idx = tuple(range(n))
        if legged:
            scale = (LEGGED_SCALES["joint_velocity"],) * n
        else:
            scale = tuple(float(v) for v in robot.velocity_limit)
        return ObservationBlock(kind, n, scale, (0.0,) * n, joints=idx)
    elif kind in KINDS and KINDS[kind].needs_base:
        size = robot.n_feet if KINDS[kind].per_foot else KINDS[kind].size
        scale = LEGGED_SCALES.get(kind, (1.0,) * size)
        period = GAIT_PERIOD if kind == "gait_phase" else 0.0  # motion_phase: no default T
        return ObservationBlock(kind, size, tuple(scale), (0.0,) * size, period=period)
    elif kind == "joint_position_sincos":
        k = len(wrapping)
        return ObservationBlock(kind, 2 * k, (1.0,) * 2 * k, (0.0,) * 2 * k, joints=wrapping)
    elif kind in ("ee_position", "goal_position", "goal_in_ee"):
        return ObservationBlock(kind, 3, (reach,) * 3, (0.0,) * 3)
    elif kind == "last_action":
        return ObservationBlock(kind, n, (1.0,) * n, (0.0,) * n, joints=tuple(range(n)))
    elif kind == "winding_temperature":
        ambient = robot.config.sensors.ambient_temperature
        scale = tuple(m.max_winding_temperature - ambient for m in robot.motors)
        return ObservationBlock(kind, n, scale, (ambient,) * n, joints=tuple(range(n)))
    else:
        raise SpecError(f"observation: block '{kind}' is unknown; expected one of {kind_names()}")


def _action(robot: Robot, mode: str, legged: bool, reference: str, position_range: str):
    """The standard action of ``robot`` in ``mode``: its scale and offset (module docstring)."""
    n = robot.n_joints
    lo, hi = robot.position_lower, robot.position_upper
    if mode == "position" and legged and reference == "absolute":
        scale, offset = (LEGGED_ACTION_SCALE,) * n, tuple(float(h) for h in robot.home)
    elif mode == "position":
        if reference == "absolute" and position_range == "soft":
            # a full action is the soft limit, the furthest target the guard passes unchanged:
            # no action in [-1, 1] is clamped, so a clamp is a real intervention
            scale, offset = _inside_range(robot.soft_lower, robot.soft_upper)
        elif reference == "absolute":  # the hard range: an adversary's, past the soft limits
            scale, offset = tuple((hi - lo) / 2), tuple((hi + lo) / 2)
        else:
            # a full action moves one control period at the velocity limit
            scale = tuple(robot.velocity_limit * robot.control_period)
            offset = (0.0,) * n
    elif mode == "velocity":
        # a full action is the fastest command the runtime issues (the smoother's soft
        # velocity limit): no action in [-1, 1] is clamped, so a clamp is a real intervention
        scale, offset = tuple(robot.soft_velocity_limit), (0.0,) * n
    else:
        scale, offset = tuple(robot.effort_limit), (0.0,) * n
    return ActionSpec(
        mode=mode,
        size=n,
        scale=tuple(float(s) for s in scale),
        offset=tuple(float(o) for o in offset),
        clip=LEGGED_ACTION_CLIP if legged else 1.0,
        reference=reference,
        # the toolkit trains through the runtime, whose smoother shapes a legged robot's targets
        smoothing="jerk_limited" if legged else "",
    )
