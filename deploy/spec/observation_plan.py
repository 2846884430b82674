"""The compiled form of :meth:`deploy.spec.policy_spec.PolicySpec.observation`
(:class:`ObservationPlan`).

A spec builds its plan once, when first asked for an observation: the blocks flattened to
per-entry offset, scale and clip arrays, joint index arrays and the block codes of the compiled
kernel (:mod:`deploy.spec.kernel`), and work buffers grown to the largest batch seen. The
plan assembles the observation with that kernel, or with the numpy reference (``reference=True``,
and the blocks the kernel does not know, such as the legged ones); both give the same numbers bit
for bit. The layout itself (block kinds, sizes, scales) is the spec's
(:mod:`deploy.spec.policy_spec`).
"""

from __future__ import annotations

import numpy as np

from deploy.spec.kernel import KIND_CODES
from deploy.spec.kernel import observation as observation_kernel
from deploy.spec.policy_spec import PolicySpec, SpecError
from deploy.state import RobotState


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
        raise SpecError(f"observation: block '{kind}' needs a floating-base robot's state")
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
        # the compiled kernel's layout (deploy.spec.kernel); kinds it does not know run
        # the reference
        self.compiled = bool(bl) and all(
            b.name in KIND_CODES
            and (b.name != "joint_position_sincos" or b.size == 2 * len(b.joints))
            for b in bl
        )
        if self.compiled:
            self.kinds = np.array([KIND_CODES[b.name] for b in bl], dtype=np.int64)
            self.starts = np.array([s.start for _, s, _ in self.blocks], dtype=np.int64)
            width = max(1, max(len(b.joints) for b in bl))
            self.joints = np.full((len(bl), width), -1, dtype=np.int64)
            for i, b in enumerate(bl):
                self.joints[i, : len(b.joints)] = b.joints
            self.norm = np.ascontiguousarray(np.stack([self.offset, self.scale, self.clip]))
            self._warm()

    def _warm(self) -> None:
        """Compile the kernel (or load numba's cache) now, not in the first tick."""
        n = int(self.joints.max()) + 1
        state = RobotState.zeros(1, max(n, 1))
        goal = np.zeros((1, 3))
        out = np.zeros((1, self.dim), dtype=np.float32)
        observation_kernel(
            self.kinds,
            self.starts,
            self.joints,
            state.q,
            state.dq,
            state.ee_position,
            state.ee_rotation,
            goal,
            state.last_action,
            state.winding_temperature,
            self.norm,
            self.raw(1),
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
            observation_kernel(
                self.kinds,
                self.starts,
                self.joints,
                state.q,
                state.dq,
                state.ee_position,
                state.ee_rotation,
                goal,
                state.last_action,
                state.winding_temperature,
                self.norm,
                self._raw,
                out,
            )
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
