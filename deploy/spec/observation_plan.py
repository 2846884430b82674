"""The compiled form of :meth:`deploy.spec.policy_spec.PolicySpec.observation`
(:class:`ObservationPlan`).

A spec builds its plan once, when first asked for an observation: the blocks flattened to
per-entry offset, scale and clip arrays, joint index arrays and the block codes of the compiled
kernel (:mod:`deploy.spec.kernel`), and work buffers grown to the largest batch seen. The
plan assembles the observation with that kernel (every block kind, the floating-base ones
included), or with the numpy reference (``reference=True``); both give the same numbers bit for
bit. The layout itself (block kinds, sizes, scales) is the spec's
(:mod:`deploy.spec.policy_spec`).
"""

from __future__ import annotations

import numpy as np

from deploy.spec.kernel import KIND_CODES
from deploy.spec.kernel import observation as observation_kernel
from deploy.spec.policy_spec import LEGGED_KINDS, PolicySpec, SpecError
from deploy.state import RobotState


def _no_base(kind: str) -> SpecError:
    return SpecError(f"observation: block '{kind}' needs a floating-base robot's state")


def _legged_block(
    kind: str, state: RobotState, raw: np.ndarray, period: float, components: np.ndarray
) -> None:
    """Write the raw entries (envs, size) of one of ``LEGGED_KINDS`` from ``state``; a vector
    block with ``components`` (non-empty) reads those entries of its 3-vector.

    Raises:
        SpecError: a state without the floating-base fields (``RobotState.legged``).
    """
    base = state.base
    if base is None:
        raise _no_base(kind)
    vectors = {
        "base_linear_velocity": base.linear_velocity,
        "base_angular_velocity": base.angular_velocity,
        "projected_gravity": base.projected_gravity,
        "velocity_command": state.command,
    }
    if kind in vectors:
        if components.size:
            np.take(vectors[kind], components, axis=1, out=raw)
        else:
            raw[:] = vectors[kind]
    elif kind == "gait_phase":
        phase = (2.0 * np.pi / period) * state.clock
        raw[:, 0] = np.sin(phase)
        raw[:, 1] = np.cos(phase)
    elif kind == "foot_contact":
        raw[:] = state.foot_contact
    else:  # heading_sincos: the yaw of the base's x axis in the filter's world frame
        w, x, y, z = base.orientation.T
        yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        raw[:, 0] = np.sin(yaw)
        raw[:, 1] = np.cos(yaw)


class ObservationPlan:
    """:meth:`PolicySpec.observation` precompiled: per-entry offset, scale and clip arrays, joint
    index arrays, and work buffers grown to the largest batch seen (no allocation per tick)."""

    def __init__(self, spec: PolicySpec):
        self.spec_blocks = spec.observation_blocks
        self.blocks = []
        #: per block: the entries of its 3-vector it reads (empty: all; ``VECTOR_KINDS`` only)
        self.components: list[np.ndarray] = []
        start = 0
        for b in spec.observation_blocks:
            dst = slice(start, start + b.size)
            self.blocks.append((b.name, dst, np.array(b.joints, dtype=np.intp)))
            self.components.append(np.array(b.components, dtype=np.intp))
            start += b.size
        bl = spec.observation_blocks
        self.offset = np.concatenate([np.asarray(b.offset, float) for b in bl]) if bl else []
        self.scale = np.concatenate([np.asarray(b.scale, float) for b in bl]) if bl else []
        self.clip = np.concatenate([np.full(b.size, float(b.clip)) for b in bl]) if bl else []
        self.dim = start
        #: per entry: the gait clock's period of its block (s; 0 outside gait_phase blocks)
        self.periods = np.concatenate([np.full(b.size, b.period) for b in bl]) if bl else []
        self._raw = np.zeros((0, start))
        self.vec = np.zeros((0, 3))
        self.rot = np.zeros((0, 3))
        #: the first floating-base block (a state without a base is refused), or None
        self.legged = next((b.name for b in bl if b.name in LEGGED_KINDS), None)
        self._no_base: tuple[np.ndarray, ...] = ()
        # the compiled kernel's layout (deploy.spec.kernel); a vector block that reads some of
        # its components (a split velocity command) runs the reference
        self.compiled = bool(bl) and all(
            b.name in KIND_CODES
            and (b.name != "joint_position_sincos" or b.size == 2 * len(b.joints))
            and not b.components
            for b in bl
        )
        if self.compiled:
            self.kinds = np.array([KIND_CODES[b.name] for b in bl], dtype=np.int64)
            self.block_periods = np.array([float(b.period) for b in bl], dtype=np.float64)
            self.starts = np.array([s.start for _, s, _ in self.blocks], dtype=np.int64)
            width = max(1, max(len(b.joints) for b in bl))
            self.joints = np.full((len(bl), width), -1, dtype=np.int64)
            for i, b in enumerate(bl):
                self.joints[i, : len(b.joints)] = b.joints
            self.norm = np.ascontiguousarray(np.stack([self.offset, self.scale, self.clip]))
            self._warm()

    def _warm(self) -> None:
        """Compile the kernel (or load numba's cache) now, not in the first tick."""
        n = max(int(self.joints.max()) + 1, 1)
        feet = max((b.size for b in self.spec_blocks if b.name == "foot_contact"), default=0)
        state = RobotState.legged(1, n, feet) if self.legged else RobotState.zeros(1, n)
        out = np.zeros((1, self.dim), dtype=np.float32)
        self._run_kernel(state, np.zeros((1, 3)), out)

    def _base_inputs(self, state: RobotState, envs: int) -> tuple[np.ndarray, ...]:
        """The kernel's floating-base inputs: the state's, or zeros for a fixed-base state
        (never read: the plan has no floating-base block then).

        Raises:
            SpecError: a floating-base block and a state without a base.
        """
        base = state.base
        if base is not None:
            return (
                base.linear_velocity,
                base.angular_velocity,
                base.projected_gravity,
                state.command,
                base.orientation,
                state.clock,
                state.foot_contact,
            )
        if self.legged is not None:
            raise _no_base(self.legged)
        if not self._no_base or self._no_base[0].shape[0] < envs:
            v = np.zeros((envs, 3))
            self._no_base = (v, v, v, v, np.zeros((envs, 4)), np.zeros(envs), np.zeros((envs, 0)))
        return self._no_base

    def _run_kernel(self, state: RobotState, goal: np.ndarray, out: np.ndarray) -> None:
        envs = state.q.shape[0]
        self.raw(envs)
        observation_kernel(
            self.kinds,
            self.starts,
            self.joints,
            self.block_periods,
            state.q,
            state.dq,
            state.ee_position,
            state.ee_rotation,
            goal,
            state.last_action,
            state.winding_temperature,
            *self._base_inputs(state, envs),
            self.norm,
            self._raw,
            out,
        )

    def raw(self, envs: int) -> np.ndarray:
        if self._raw.shape[0] < envs:
            self._raw = np.zeros((envs, self.dim))
            self.vec = np.zeros((envs, 3))
            self.rot = np.zeros((envs, 3))
        return self._raw[:envs]

    def observation(
        self,
        state: RobotState,
        goal: np.ndarray,
        out: np.ndarray | None = None,
        reference: bool = False,
    ) -> np.ndarray:
        """:meth:`PolicySpec.observation` (see there) with this plan."""
        envs = state.q.shape[0]
        if out is None:
            out = np.empty((envs, self.dim), dtype=np.float32)
        raw = self.raw(envs)
        if self.compiled and not reference:
            self._run_kernel(state, goal, out)
            return out
        for (kind, dst, joints), components in zip(self.blocks, self.components, strict=True):
            if kind == "joint_position":
                np.take(state.q, joints, axis=1, out=raw[:, dst])
            elif kind == "joint_velocity":
                np.take(state.dq, joints, axis=1, out=raw[:, dst])
            elif kind == "joint_position_sincos":
                q = state.q[:, joints]
                k = len(joints)
                np.sin(q, out=raw[:, dst.start : dst.start + k])
                np.cos(q, out=raw[:, dst.start + k : dst.stop])
            elif kind == "ee_position":
                raw[:, dst] = state.ee_position
            elif kind == "goal_position":
                raw[:, dst] = goal
            elif kind == "goal_in_ee":
                np.subtract(goal, state.ee_position, out=self.vec[:envs])
                np.matmul(self.vec[:envs, None, :], state.ee_rotation, out=self.rot[:envs, None, :])
                raw[:, dst] = self.rot[:envs]
            elif kind == "last_action":
                np.take(state.last_action, joints, axis=1, out=raw[:, dst])
            elif kind == "winding_temperature":
                np.take(state.winding_temperature, joints, axis=1, out=raw[:, dst])
            else:
                _legged_block(kind, state, raw[:, dst], self.periods[dst.start], components)
        raw -= self.offset
        raw /= self.scale
        np.minimum(raw, self.clip, out=raw)
        np.maximum(raw, -self.clip, out=raw)
        out[:] = raw
        return out
