"""The compiled form of :meth:`sim2real.deploy.spec.policy_spec.PolicySpec.observation`
(:class:`ObservationPlan`).

A spec builds its plan once, when first asked for an observation: the blocks with their
registered kinds (:mod:`sim2real.deploy.spec.kinds`), flattened to per-entry offset, scale and clip
arrays, joint index arrays and the kinds' kernel codes (:mod:`sim2real.deploy.spec.kernel`), and work
buffers grown to the largest batch seen. The plan assembles the observation with that kernel;
the numpy reference (:mod:`sim2real.deploy.spec.reference`) gives the same numbers bit for bit, and runs
in the plan's place only for a block that reads some components of a vector
(:func:`sim2real.deploy.spec.kinds.numpy_reason`, kept in ``numpy_reason``). The layout itself (block
kinds, sizes, scales) is the spec's (:mod:`sim2real.deploy.spec.policy_spec`). A spec with a frame
history (:mod:`sim2real.deploy.spec.history`) has the blocks make one frame per call and the plan's
ring stack the frames (compiled too); :meth:`ObservationPlan.reset_history` starts it again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from inspect import signature

import numpy as np

from sim2real.deploy.core.state import RobotState
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.spec import kernel as ok
from sim2real.deploy.spec.history import FrameRing, gather_table, stacked_dim
from sim2real.deploy.spec.kernel import observation as observation_kernel
from sim2real.deploy.spec.kinds import KINDS, ObservationKind, numpy_reason
from sim2real.deploy.spec.policy_spec import PolicySpec, SpecError
from sim2real.deploy.spec.reference import assemble


def _no_base(kind: str) -> SpecError:
    return SpecError(f"observation: block '{kind}' needs a floating-base robot's state")


class GaitClocks:
    """The gait clocks of a plan's blocks (:func:`sim2real.deploy.spec.kernel.gait_clock`).

    Attributes:
        params: (blocks, ``CLOCK_COLUMNS``) float64, each block's period, stand threshold, held
            phase's sin and cos and first-tick lead (the ``C_*`` columns of
            :mod:`sim2real.deploy.spec.kernel`; zeros but the lead for a block without a clock).
        kernel, reference: (rows, blocks) float64, each env's clock state, the kernel's and the
            numpy reference's (+inf: the env's first tick is to come), rows those of the
            plan's work array.
    """

    def __init__(self, blocks, lead: float):
        self.params = np.zeros((len(blocks), ok.CLOCK_COLUMNS))
        for i, b in enumerate(blocks):
            held = float(b.stand_phase)
            self.params[i] = (b.period, b.stand_below, math.sin(held), math.cos(held), lead)
        self.kernel = np.full((0, len(blocks)), np.inf)
        self.reference = self.kernel.copy()

    def grow(self, rows: int) -> None:
        """Both states with ``rows`` rows (the new envs' first tick to come)."""
        for name in ("kernel", "reference"):
            old = getattr(self, name)
            new = np.full((rows, old.shape[1]), np.inf)
            new[: len(old)] = old[:rows]
            setattr(self, name, new)

    def reset(self, envs: np.ndarray | None = None) -> None:
        """The clocks of the envs of ``envs`` (bool mask (envs,); default all) start again: their
        next tick is their first."""
        for state in (self.kernel, self.reference):
            if envs is None:
                state[:] = np.inf
            else:
                mask = np.asarray(envs, dtype=bool)
                state[: len(mask)][mask[: len(state)]] = np.inf


@dataclass(frozen=True)
class PlanBlock:
    """One block as the plan runs it.

    Attributes:
        kind: Its registered kind. columns: Its columns in the observation.
        joints: (k,) intp, the joints it reads. components: (c,) intp, the entries of its
            3-vector it reads (empty: all). period: The gait clock's period, s (0: none).
        index: Its place among the plan's blocks. clocks: The plan's gait clocks (its row
            ``index`` is this block's).
    """

    kind: ObservationKind
    columns: slice
    joints: np.ndarray
    components: np.ndarray
    period: float
    index: int = 0
    clocks: GaitClocks | None = None


class ObservationPlan:
    """:meth:`PolicySpec.observation` precompiled: per-entry offset, scale and clip arrays, joint
    index arrays, and work buffers grown to the largest batch seen (no allocation per tick)."""

    def __init__(self, spec: PolicySpec):
        self.spec_blocks = bl = spec.observation_blocks
        unknown = [b.name for b in bl if b.name not in KINDS]
        if unknown:
            raise SpecError(f"observation: block '{unknown[0]}' is not a registered kind")
        self.blocks: list[PlanBlock] = []
        #: the gait clocks' parameters and state (a clock that stops holds one per env)
        self.clocks = GaitClocks(bl, 1.0 / spec.control_rate if spec.control_rate > 0 else 0.0)
        start = 0
        for i, b in enumerate(bl):
            joints = np.array(b.joints, dtype=np.intp)
            components = np.array(b.components, dtype=np.intp)
            columns = slice(start, start + b.size)
            kind = KINDS[b.name]
            self.blocks.append(
                PlanBlock(kind, columns, joints, components, b.period, i, self.clocks)
            )
            start += b.size
        self.offset = np.concatenate([np.asarray(b.offset, float) for b in bl]) if bl else []
        self.scale = np.concatenate([np.asarray(b.scale, float) for b in bl]) if bl else []
        self.clip = np.concatenate([np.full(b.size, float(b.clip)) for b in bl]) if bl else []
        #: entries of one frame (the blocks'); ``out_dim``: of the observation (the graph's input)
        self.dim = start
        #: the spec's frame history (None: the observation is one frame) and, with one, the rings
        #: of past frames of the kernel and of the numpy reference
        self.history = spec.history
        self.out_dim = stacked_dim(spec.history, tuple(b.size for b in bl))
        if spec.history is not None:
            table = gather_table(spec.history, tuple(b.size for b in bl))
            self.ring = FrameRing(spec.history, table, start)
            self.reference_ring = FrameRing(spec.history, table, start)
        self._raw = np.zeros((0, start))
        self.vec = np.zeros((0, 3))
        self.rot = np.zeros((0, 3))
        #: the first floating-base block (a state without a base is refused), or None
        self.base_block = next((b.name for b in bl if KINDS[b.name].needs_base), None)
        self._no_base: tuple[np.ndarray, ...] = ()
        #: the kernel's arguments of the last call with an ``out``, and its (out, state, goal,
        #: state.q, state.base), compared by identity (:meth:`observation`)
        self._args: tuple[np.ndarray, ...] = ()
        self._bound: tuple = ()
        #: the kernel bound to those arguments' packed table (one argument for the kernel's
        #: 20: :data:`sim2real.deploy.spec.kernel.OBSERVATION`), or None: the kernel is called
        #: with its arguments
        self._table = None
        #: why the plan runs the numpy reference, not the kernel (None: it runs the kernel;
        #: ``sim2real.deploy.spec.kinds.numpy_reason``); an empty spec has nothing to compile
        self.numpy_reason = next(filter(None, map(numpy_reason, bl)), None)
        self.compiled = bool(bl) and self.numpy_reason is None
        if self.compiled:
            self.kinds = np.array([KINDS[b.name].kernel_code for b in bl], dtype=np.int64)
            self.components = np.full((len(bl), 4), -1, dtype=np.int64)
            for i, b in enumerate(bl):  # a block naming none reads its kind's own in order
                picked = b.components or range(min(b.size, 4))
                self.components[i, : len(picked)] = picked
            self.starts = np.array([p.columns.start for p in self.blocks], dtype=np.int64)
            width = max(1, max(len(b.joints) for b in bl))
            self.joints = np.full((len(bl), width), -1, dtype=np.int64)
            for i, b in enumerate(bl):
                self.joints[i, : len(b.joints)] = b.joints
            self.norm = np.ascontiguousarray(np.stack([self.offset, self.scale, self.clip]))
            #: the kernel's block table: code, start, components, joints (one argument)
            self.layout = np.ascontiguousarray(
                np.concatenate(
                    [self.kinds[:, None], self.starts[:, None], self.components, self.joints],
                    axis=1,
                )
            )
            self._warm()

    def _warm(self) -> None:
        """Compile the kernel (or load numba's cache) now, not in the first tick."""
        n = max(int(self.joints.max()) + 1, 1)
        feet = max((b.size for b in self.spec_blocks if KINDS[b.name].per_foot), default=0)
        state = RobotState.legged(1, n, feet) if self.base_block else RobotState.zeros(1, n)
        out = np.zeros((1, self.dim), dtype=np.float32)
        self._run_kernel(state, np.zeros((1, 3)), out)
        self.clocks.reset()  # the warm-up was no env's first tick
        bind(ok.observation_over, ok.OBSERVATION.empty())
        if self.history is not None:  # the stacking, on a ring of its own
            ring = FrameRing(self.history, self.ring.table, self.dim)
            ring.stack(ring.frame_buffer(1), np.zeros((1, self.out_dim), dtype=np.float32))

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
        if self.base_block is not None:
            raise _no_base(self.base_block)
        if not self._no_base or self._no_base[0].shape[0] < envs:
            v = np.zeros((envs, 3))
            self._no_base = (v, v, v, v, np.zeros((envs, 4)), np.zeros(envs), np.zeros((envs, 0)))
        return self._no_base

    def _run_kernel(self, state: RobotState, goal: np.ndarray, out: np.ndarray) -> None:
        envs = state.q.shape[0]
        self.raw(envs)
        observation_kernel(*self.kernel_args(state, goal, out, envs))

    def kernel_args(
        self, state: RobotState, goal: np.ndarray, out: np.ndarray, envs: int
    ) -> tuple[np.ndarray, ...]:
        """The arguments of :func:`sim2real.deploy.spec.kernel.observation` for these
        arrays, the live ones (no copies; a caller may keep their addresses while they are the
        same objects), in its order: ``layout`` (blocks, width) int64, the gait clocks'
        ``params`` (blocks, ``CLOCK_COLUMNS``) and ``kernel`` state (raw's rows, blocks), the
        state's ``q``, ``dq`` (envs, n), ``ee_position`` (envs, 3),
        ``ee_rotation`` (envs, 3, 3), ``goal`` (envs, 3), ``last_action``,
        ``winding_temperature`` (envs, n); the 7 base inputs (linear and angular velocity,
        projected gravity, command (envs, 3), orientation (envs, 4), clock (envs,), foot
        contact (envs, feet); without a base, zeros of at least ``envs`` rows, one (envs, 3)
        array for the first four); ``norm`` (3, dim), the plan's ``raw`` buffer (rows >= envs once
        :meth:`raw` grew it) and ``out`` float32 (envs, dim); float64 where not said.

        Raises:
            SpecError: a floating-base block and a state without a base.
        """
        return (
            self.layout,
            self.clocks.params,
            self.clocks.kernel,
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
        """The work array's first ``envs`` rows (grown with the gait clocks' states)."""
        if self._raw.shape[0] < envs:
            self._raw = np.zeros((envs, self.dim))
            self.vec = np.zeros((envs, 3))
            self.rot = np.zeros((envs, 3))
            self.clocks.grow(envs)
        return self._raw[:envs]

    def require_base(self, state: RobotState) -> None:
        """Raises SpecError: the plan has a floating-base block and ``state`` no base."""
        if self.base_block is not None and state.base is None:
            raise _no_base(self.base_block)

    def reset_history(self, envs: np.ndarray | None = None) -> None:
        """Start the frame history of the envs of ``envs`` (bool mask (envs,); default all) again
        (the policy's reset): both rings, the kernel's and the reference's (no-op without a
        history), and the gait clocks that stop (their next tick is their first)."""
        self.clocks.reset(envs)
        if self.history is not None:
            self.ring.reset(envs)
            self.reference_ring.reset(envs)

    def state_fields(self, envs: int) -> dict[str, np.ndarray]:
        """The plan's state from one tick to the next for a batch of ``envs`` (its buffers sized
        for them first; the live arrays, leading env axis, for
        :mod:`sim2real.deploy.core.stateful`'s ``take`` and ``put``): the gait clocks'
        ``clock_starts`` and ``clock_starts_reference`` (envs, blocks) s (+inf: first tick to
        come, NaN: standing) and, with a frame history, each ring's (the kernel's ``ring/``, the
        numpy reference's ``reference_ring/``) ``frames`` (envs, length, frame) float32, ``head``
        and ``count`` (envs,) int64. A resume without them starts the history and the clocks
        again: another observation than the uninterrupted run's."""
        self.raw(envs)
        fields = {
            "clock_starts": self.clocks.kernel[:envs],
            "clock_starts_reference": self.clocks.reference[:envs],
        }
        if self.history is not None:
            for name, ring in (("ring", self.ring), ("reference_ring", self.reference_ring)):
                ring.frame_buffer(envs)  # sized for the batch (as its first tick does)
                fields.update(
                    {
                        f"{name}/frames": ring.ring,
                        f"{name}/head": ring.head,
                        f"{name}/count": ring.count,
                    }
                )
        return fields

    def observation(
        self, state: RobotState, goal: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        """:meth:`PolicySpec.observation` (see there) with this plan: the kernel, or the numpy
        reference for a plan with a ``numpy_reason``; with a frame history, this tick's frame
        pushed into the ring and the frames stacked into ``out`` (float32 (envs, ``out_dim``))."""
        if self.history is None:
            return self._frame(state, goal, out)
        envs = state.q.shape[0]
        frame = self._frame(state, goal, self.ring.frame_buffer(envs))
        if out is None:
            out = np.empty((envs, self.out_dim), dtype=np.float32)
        return self.ring.stack(frame, out)

    def _frame(
        self, state: RobotState, goal: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        """One frame (float32 (envs, ``dim``)). The kernel's arguments for a given ``out`` are
        made once and used again while the call's state, goal and ``out`` (and the state's
        ``q`` and ``base``) are the same objects (the runtime's, every tick)."""
        b = self._bound
        if (
            b
            and out is b[0]
            and state is b[1]
            and goal is b[2]
            and state.q is b[3]
            and state.base is b[4]
        ):
            if self._table is not None:
                self._table()
            else:
                observation_kernel(*self._args)
            return out
        if not self.compiled:
            return assemble(self, state, goal, out)
        if out is None:
            out = np.empty((state.q.shape[0], self.dim), dtype=np.float32)
        else:
            self._bound = (out, state, goal, state.q, state.base)
        envs = state.q.shape[0]
        self.raw(envs)
        self._args = self.kernel_args(state, goal, out, envs)
        self._table = self._address_table(self._args)
        observation_kernel(*self._args)
        return out

    def _address_table(self, args: tuple[np.ndarray, ...]):
        """:func:`~sim2real.deploy.spec.kernel.observation_over` bound to the packed table of the
        kernel's arguments ``args`` (in its order), or None if one has another dtype, shape or
        layout than its field's, or the plan's ``raw`` has fewer rows than the envs."""
        names = list(signature(ok.observation.py_func).parameters)
        values = dict(zip(names, args, strict=True))
        q, raw = values["q"], values["raw"]
        if q.ndim != 2 or raw.shape[0] < q.shape[0]:
            return None
        table = ok.OBSERVATION.pack_or_none(**values)
        return None if table is None else bind(ok.observation_over, table)
