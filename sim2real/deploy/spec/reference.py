"""The numpy reference of :meth:`sim2real.deploy.spec.policy_spec.PolicySpec.observation`.

:func:`observation_reference` assembles the observation in numpy, block by block, with each
kind's writer (``ObservationKind.numpy`` in :mod:`sim2real.deploy.spec.kinds`, the writers below), then
normalizes: ``(raw - offset) / scale``, the upper clip, the lower clip, the cast to float32. The
compiled kernel (:mod:`sim2real.deploy.spec.kernel`) gives the same numbers bit for bit; tests compare the
two. A writer fills ``raw`` (envs, size), float64, with the block's raw quantity in SI units from
the state, the goal (envs, 3) m, the plan's block (joints, components, period) and two (envs, 3)
work arrays. A spec with a frame history (:mod:`sim2real.deploy.spec.history`) stacks the frames
in numpy too, in a ring of its own (``ObservationPlan.reference_ring``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.spec import kernel

if TYPE_CHECKING:
    from sim2real.deploy.spec.observation_plan import ObservationPlan, PlanBlock
    from sim2real.deploy.spec.policy_spec import PolicySpec


def observation_reference(
    spec: PolicySpec, state: RobotState, goal: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """``spec.observation(state, goal, out=out)`` computed in numpy (same numbers bit for bit).

    Args:
        spec: The policy spec (its plan is built on the first call).
        state: Estimated state with end-effector pose filled (``Kinematics.update``).
        goal: (envs, 3) m, goal position in the base frame.
        out: Optional float32 (envs, obs_dim) array to write into.

    Returns:
        float32 (envs, obs_dim), ``out`` when given.

    Raises:
        SpecError: a floating-base block and a state without a base.
    """
    plan = spec.plan
    if plan.history is None:
        return assemble(plan, state, goal, out)
    envs = state.q.shape[0]
    frame = assemble(plan, state, goal, plan.reference_ring.frame_buffer(envs))
    if out is None:
        out = np.empty((envs, plan.out_dim), dtype=np.float32)
    return plan.reference_ring.stack_reference(frame, out)


def assemble(
    plan: ObservationPlan, state: RobotState, goal: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """One frame of :func:`observation_reference` with the spec's plan: float32 (envs,
    ``plan.dim``), the observation itself for a spec without a frame history."""
    envs = state.q.shape[0]
    if out is None:
        out = np.empty((envs, plan.dim), dtype=np.float32)
    raw = plan.raw(envs)
    plan.require_base(state)
    vec, rot = plan.vec[:envs], plan.rot[:envs]
    for block in plan.blocks:
        block.kind.numpy(state, goal, raw[:, block.columns], block, vec, rot)
    raw -= plan.offset
    raw /= plan.scale
    np.minimum(raw, plan.clip, out=raw)
    np.maximum(raw, -plan.clip, out=raw)
    out[:] = raw
    return out


# ---------------------------------------------------------------------- the kinds' writers
# Signature: (state, goal, raw, block, vec, rot) -> None, ``raw`` the block's (envs, size) columns.


def joint_position(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    np.take(state.q, block.joints, axis=1, out=raw)


def joint_position_zero(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    raw[:] = 0.0


def joint_velocity(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    np.take(state.dq, block.joints, axis=1, out=raw)


def joint_position_sincos(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    q = state.q[:, block.joints]
    k = len(block.joints)
    np.sin(q, out=raw[:, :k])
    np.cos(q, out=raw[:, k:])


def ee_position(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    raw[:] = state.ee_position


def goal_position(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    raw[:] = goal


def goal_in_ee(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    np.subtract(goal, state.ee_position, out=vec)
    np.matmul(vec[:, None, :], state.ee_rotation, out=rot[:, None, :])
    raw[:] = rot


def last_action(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    np.take(state.last_action, block.joints, axis=1, out=raw)


def winding_temperature(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    np.take(state.winding_temperature, block.joints, axis=1, out=raw)


def _vector(raw: np.ndarray, vector: np.ndarray, components: np.ndarray) -> None:
    """A vector block: the whole 3-vector, or its ``components`` (non-empty) in order."""
    if components.size:
        np.take(vector, components, axis=1, out=raw)
    else:
        raw[:] = vector


def base_linear_velocity(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    _vector(raw, state.base.linear_velocity, block.components)


def base_angular_velocity(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    _vector(raw, state.base.angular_velocity, block.components)


def projected_gravity(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    _vector(raw, state.base.projected_gravity, block.components)


def velocity_command(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    _vector(raw, state.command, block.components)


def gait_phase(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    """sin p, cos p, sin(p + pi), cos(p + pi) (its components); a clock that stops
    (``sim2real.deploy.spec.kernel.gait_clock``): every foot at the held phase while standing."""
    params = block.clocks.params[block.index]
    below = params[kernel.C_STAND_BELOW]
    if below <= 0.0:  # a clock that never stops
        phase = (2.0 * np.pi / block.period) * state.clock
    else:
        phase = _stopping_clock(state, block, params, raw.shape[0])
    sp, cp = np.sin(phase), np.cos(phase)
    entries = np.stack([sp, cp, -sp, -cp], axis=1)  # the second foot half a period later
    if below > 0.0:
        held = (params[kernel.C_HELD_SIN], params[kernel.C_HELD_COS])
        entries[np.isnan(phase)] = held + held
    if block.components.size:
        np.take(entries, block.components, axis=1, out=raw)
    else:
        raw[:] = entries[:, :2]


def _stopping_clock(state, block: PlanBlock, params: np.ndarray, envs: int) -> np.ndarray:
    """The phase of a clock that stops, per env (NaN: standing), its reference state updated."""
    starts = block.clocks.reference[:envs, block.index]
    c, t = state.command, state.clock
    below = params[kernel.C_STAND_BELOW]
    standing = (np.sqrt(c[:, 0] * c[:, 0] + c[:, 1] * c[:, 1]) < below) & (np.abs(c[:, 2]) < below)
    restart = np.where(np.isinf(starts), t - params[kernel.C_LEAD], starts)
    t0 = np.where(np.isnan(starts), t, restart)
    t0[standing] = np.nan
    starts[:] = t0
    return (2.0 * np.pi / params[kernel.C_PERIOD]) * (t - t0)


def foot_contact(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    raw[:] = state.foot_contact


def heading_sincos(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    """The yaw of the base's x axis in the attitude filter's world frame, as sin, cos."""
    w, x, y, z = state.base.orientation.T
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    raw[:, 0] = np.sin(yaw)
    raw[:, 1] = np.cos(yaw)


def base_euler_angles(state, goal, raw, block: PlanBlock, vec, rot) -> None:
    """Roll, pitch, yaw of the base in the attitude filter's world frame (its components)."""
    w, x, y, z = state.base.orientation.T
    picked = block.components if block.components.size else range(3)
    for i, c in enumerate(picked):
        if c == 0:
            raw[:, i] = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        elif c == 1:
            raw[:, i] = np.arcsin(np.maximum(np.minimum(2.0 * (w * y - z * x), 1.0), -1.0))
        else:
            raw[:, i] = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
