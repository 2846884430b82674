"""Kernel of :meth:`sim2real.deploy.spec.policy_spec.PolicySpec.observation`: assemble, normalize, clip,
cast.

Each block is coded by its kind's branch code (``ObservationKind.kernel_code`` in the registry
:mod:`sim2real.deploy.spec.kinds`, one of ``BRANCHES`` below); each block has its start column, size and
joint indices (a (blocks, max_joints) int64 array, padded). The arithmetic is the reference's
(:mod:`sim2real.deploy.spec.reference`): ``(raw - offset) / scale``, then the upper clip, then the lower
clip, then the cast to float32; ``goal_in_ee`` is ``(goal - ee) @ R`` summed in the order of
numpy's matmul loop; ``gait_phase`` is ``sin p, cos p, sin(p + pi), cos(p + pi)`` of
``p = (2 pi / period) * clock`` (the second foot half a period later), of which a block reads its
``components`` (default the first two); a clock that stops (:func:`gait_clock`) reads every
foot's phase as the held one while the command is below its threshold; a vector block reads its
``components`` of its 3-vector; and
``heading_sincos`` of the yaw ``atan2(2 (w z + x y), 1 - 2 (y^2 + z^2))``; ``base_euler_angles``
its components of roll ``atan2(2 (w x + y z), 1 - 2 (x^2 + y^2))``, pitch ``asin(2 (w y - z x))``
(clipped to [-1, 1] first) and that yaw. A new kind adds its branch here (a new code in
``BRANCHES``, and its input array when the state has a new field). :func:`stack_history` stacks
the frames of a history (:mod:`sim2real.deploy.spec.history`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim2real.deploy.kernels import np_max, np_min
from sim2real.deploy.kernels.tables import Table

#: The kernel's branch codes, one per block kind it assembles.
JOINT_POSITION = 0
JOINT_VELOCITY = 1
JOINT_POSITION_SINCOS = 2
EE_POSITION = 3
GOAL_POSITION = 4
GOAL_IN_EE = 5
LAST_ACTION = 6
WINDING_TEMPERATURE = 7
BASE_LINEAR_VELOCITY = 8
BASE_ANGULAR_VELOCITY = 9
PROJECTED_GRAVITY = 10
VELOCITY_COMMAND = 11
GAIT_PHASE = 12
FOOT_CONTACT = 13
HEADING_SINCOS = 14
BASE_EULER_ANGLES = 15
JOINT_POSITION_ZERO = 16
#: Every code the kernel has a branch for (``sim2real.deploy.spec.kinds.register_kind`` refuses others).
BRANCHES = frozenset(
    (
        JOINT_POSITION,
        JOINT_VELOCITY,
        JOINT_POSITION_SINCOS,
        EE_POSITION,
        GOAL_POSITION,
        GOAL_IN_EE,
        LAST_ACTION,
        WINDING_TEMPERATURE,
        BASE_LINEAR_VELOCITY,
        BASE_ANGULAR_VELOCITY,
        PROJECTED_GRAVITY,
        VELOCITY_COMMAND,
        GAIT_PHASE,
        FOOT_CONTACT,
        HEADING_SINCOS,
        BASE_EULER_ANGLES,
        JOINT_POSITION_ZERO,
    )
)


#: Columns of a block's row of ``clocks`` (:func:`observation`): the gait clock's period, s; the
#: command below which it stops (0: never); sin and cos of the phase it is held at; the phase's
#: lead at an env's first tick, s.
C_PERIOD, C_STAND_BELOW, C_HELD_SIN, C_HELD_COS, C_LEAD = range(5)
#: Columns of ``clocks``.
CLOCK_COLUMNS = 5


@numba.njit(cache=True, nogil=True, _nrt=False)
def gait_clock(
    clocks: np.ndarray, starts: np.ndarray, command: np.ndarray, clock: np.ndarray, e: int, b: int
) -> float:
    """The phase ``p`` of env ``e``'s gait clock of block ``b`` (rad, not wrapped), or NaN
    while it stands, updating ``starts[e, b]``: the clock reading at which its phase was 0
    (+inf: the env's first tick to come; NaN: standing). A clock that never stops
    (``clocks[b, C_STAND_BELOW]`` 0) is ``(2 pi / period) * clock``. One that stops stands while
    ``|(vx, vy)| < stand_below`` and ``|yaw rate| < stand_below``; on the first tick after it
    stood it restarts at phase 0, and on an env's first tick it reads ``lead`` s already run."""
    period, below = clocks[b, C_PERIOD], clocks[b, C_STAND_BELOW]
    if below <= 0.0:
        return (2.0 * math.pi / period) * clock[e]
    vx, vy, yaw = command[e, 0], command[e, 1], command[e, 2]
    if math.sqrt(vx * vx + vy * vy) < below and abs(yaw) < below:
        starts[e, b] = math.nan
        return math.nan
    t0 = starts[e, b]
    if math.isnan(t0):
        t0 = clock[e]
    elif math.isinf(t0):
        t0 = clock[e] - clocks[b, C_LEAD]
    starts[e, b] = t0
    return (2.0 * math.pi / period) * (clock[e] - t0)


@numba.njit(cache=True, nogil=True, _nrt=False)
def observation(
    layout: np.ndarray,
    clocks: np.ndarray,
    clock_starts: np.ndarray,
    q: np.ndarray,
    dq: np.ndarray,
    ee_position: np.ndarray,
    ee_rotation: np.ndarray,
    goal: np.ndarray,
    last_action: np.ndarray,
    temperature: np.ndarray,
    linear_velocity: np.ndarray,
    angular_velocity: np.ndarray,
    gravity: np.ndarray,
    command: np.ndarray,
    orientation: np.ndarray,
    clock: np.ndarray,
    contact: np.ndarray,
    norm: np.ndarray,
    raw: np.ndarray,
    out: np.ndarray,
) -> None:
    """Write the observation of every env into ``out`` (float32 (envs, dim)).

    Args:
        layout: (blocks, 6 + k) int64, per block: its code (``BRANCHES``), its first column,
            the 4 entries of its raw vector a vector or ``gait_phase`` block reads, in order
            (its kind's own, 0, 1, ..., where it names none; -1 padded), and its k joint indices
            (-1 padded; a block's size is its column span).
        clocks: (blocks, ``CLOCK_COLUMNS``) float64, a ``gait_phase`` block's clock (the
            ``C_*`` columns); clock_starts: (>= envs, blocks) float64, each env's clock state
            (:func:`gait_clock`).
        q, dq, last_action, temperature: (envs, n); ee_position, goal (envs, 3); ee_rotation
            (envs, 3, 3): the inputs of the reference, same units.
        linear_velocity, angular_velocity, gravity, command: (envs, 3) base linear velocity
            (m/s), angular velocity (rad/s), projected gravity, velocity command (vx, vy m/s,
            yaw rate rad/s), base frame; orientation (envs, 4) ``[w, x, y, z]``; clock (envs,)
            s; contact (envs, feet). Read by the floating-base blocks only.
        norm: (3, dim) float64 rows offset, scale, clip.
        raw: (>= envs, dim) float64 work array.
    """
    kinds, starts, components, joints = layout[:, 0], layout[:, 1], layout[:, 2:6], layout[:, 6:]
    envs = q.shape[0]
    dim = out.shape[1]
    blocks = kinds.shape[0]
    for e in range(envs):
        for b in range(blocks):
            kind, s0 = kinds[b], starts[b]
            s1 = starts[b + 1] if b + 1 < blocks else dim
            size = s1 - s0
            if kind == JOINT_POSITION:
                for i in range(size):
                    raw[e, s0 + i] = q[e, joints[b, i]]
            elif kind == JOINT_VELOCITY:
                for i in range(size):
                    raw[e, s0 + i] = dq[e, joints[b, i]]
            elif kind == JOINT_POSITION_ZERO:
                for i in range(size):
                    raw[e, s0 + i] = 0.0
            elif kind == JOINT_POSITION_SINCOS:
                k = size // 2
                for i in range(k):
                    raw[e, s0 + i] = math.sin(q[e, joints[b, i]])
                for i in range(k):
                    raw[e, s0 + k + i] = math.cos(q[e, joints[b, i]])
            elif kind == EE_POSITION:
                for i in range(size):
                    raw[e, s0 + i] = ee_position[e, i]
            elif kind == GOAL_POSITION:
                for i in range(size):
                    raw[e, s0 + i] = goal[e, i]
            elif kind == GOAL_IN_EE:
                v0 = goal[e, 0] - ee_position[e, 0]
                v1 = goal[e, 1] - ee_position[e, 1]
                v2 = goal[e, 2] - ee_position[e, 2]
                for i in range(3):
                    acc = 0.0
                    acc += v0 * ee_rotation[e, 0, i]
                    acc += v1 * ee_rotation[e, 1, i]
                    acc += v2 * ee_rotation[e, 2, i]
                    raw[e, s0 + i] = acc
            elif kind == LAST_ACTION:
                for i in range(size):
                    raw[e, s0 + i] = last_action[e, joints[b, i]]
            elif kind == WINDING_TEMPERATURE:
                for i in range(size):
                    raw[e, s0 + i] = temperature[e, joints[b, i]]
            elif kind == BASE_LINEAR_VELOCITY:
                for i in range(size):
                    raw[e, s0 + i] = linear_velocity[e, components[b, i]]
            elif kind == BASE_ANGULAR_VELOCITY:
                for i in range(size):
                    raw[e, s0 + i] = angular_velocity[e, components[b, i]]
            elif kind == PROJECTED_GRAVITY:
                for i in range(size):
                    raw[e, s0 + i] = gravity[e, components[b, i]]
            elif kind == VELOCITY_COMMAND:
                for i in range(size):
                    raw[e, s0 + i] = command[e, components[b, i]]
            elif kind == GAIT_PHASE:
                phase = gait_clock(clocks, clock_starts, command, clock, e, b)
                if math.isnan(phase):  # standing: every foot held at one phase
                    sp, cp = clocks[b, C_HELD_SIN], clocks[b, C_HELD_COS]
                    held = (sp, cp, sp, cp)
                else:
                    sp, cp = math.sin(phase), math.cos(phase)
                    held = (sp, cp, -sp, -cp)
                for i in range(size):
                    raw[e, s0 + i] = held[components[b, i]]
            elif kind == FOOT_CONTACT:
                for i in range(size):
                    raw[e, s0 + i] = contact[e, i]
            elif kind == HEADING_SINCOS:
                w, x = orientation[e, 0], orientation[e, 1]
                y, z = orientation[e, 2], orientation[e, 3]
                yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
                raw[e, s0] = math.sin(yaw)
                raw[e, s0 + 1] = math.cos(yaw)
            elif kind == BASE_EULER_ANGLES:
                w, x = orientation[e, 0], orientation[e, 1]
                y, z = orientation[e, 2], orientation[e, 3]
                for i in range(size):
                    c = components[b, i]
                    if c == 0:
                        angle = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
                    elif c == 1:
                        sine = np_max(np_min(2.0 * (w * y - z * x), 1.0), -1.0)
                        angle = math.asin(sine)
                    else:
                        angle = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
                    raw[e, s0 + i] = angle
        for i in range(dim):
            v = raw[e, i] - norm[0, i]
            v = v / norm[1, i]
            v = np_min(v, norm[2, i])
            v = np_max(v, -norm[2, i])
            out[e, i] = np.float32(v)


@numba.njit(cache=True, nogil=True, _nrt=False)
def stack_history(
    frame: np.ndarray,
    ring: np.ndarray,
    head: np.ndarray,
    count: np.ndarray,
    runs: np.ndarray,
    fill_first: bool,
    out: np.ndarray,
) -> None:
    """Push each env's ``frame`` into its ring and write the graph's input into ``out``
    (:class:`sim2real.deploy.spec.history.FrameRing`).

    Args:
        frame: float32 (envs, frame), this tick's frame.
        ring: float32 (envs, length, frame), the past frames; ``head`` (envs,) int64 its newest
            slot, ``count`` (envs,) int64 the frames pushed since the env's reset (<= length).
        runs: (runs, 4) int64, the input's runs of consecutive entries: the tick they read (0
            the present), their first frame column, their first input entry, their length
            (:func:`sim2real.deploy.spec.history.runs_of`).
        fill_first: A tick before the reset reads the first frame after it (else 0).
        out: float32 (envs, entries).
    """
    envs, width, length = frame.shape[0], frame.shape[1], ring.shape[1]
    for e in range(envs):
        h = head[e] + 1
        if h >= length:
            h = 0
        head[e] = h
        for i in range(width):
            ring[e, h, i] = frame[e, i]
        pushed = count[e] + 1
        if pushed > length:
            pushed = length
        count[e] = pushed
        for r in range(runs.shape[0]):
            lag, c0, o0, n = runs[r, 0], runs[r, 1], runs[r, 2], runs[r, 3]
            if lag >= pushed:
                if not fill_first:
                    for i in range(n):
                        out[e, o0 + i] = np.float32(0.0)
                    continue
                lag = pushed - 1
            slot = h - lag
            if slot < 0:
                slot += length
            for i in range(n):
                out[e, o0 + i] = ring[e, slot, c0 + i]


#: :func:`observation`'s arguments (their names; shapes as there: the floating-base inputs with
#: at least ``envs`` rows, of which the kernel reads ``envs``), one table.
OBSERVATION = Table(
    "sim2real.deploy.spec.kernel:OBSERVATION",
    layout="i8[blocks,*]", clocks=f"f8[blocks,{CLOCK_COLUMNS}]", clock_starts="f8[raw_rows,blocks]",
    q="f8[envs,n]", dq="f8[envs,n]", ee_position="f8[envs,3]", ee_rotation="f8[envs,3,3]",
    goal="f8[envs,3]", last_action="f8[envs,n]", temperature="f8[envs,n]",
    linear_velocity="f8[envs+,3]", angular_velocity="f8[envs+,3]", gravity="f8[envs+,3]",
    command="f8[envs+,3]", orientation="f8[envs+,4]", clock="f8[envs+]",
    contact="f8[envs+,*]", norm="f8[3,dim]", raw="f8[raw_rows,dim]", out="f4[envs,dim]",
)  # fmt: skip


@numba.njit(cache=True, nogil=True)
def observation_over(t) -> None:
    """:func:`observation` on the packed table ``t`` (:data:`OBSERVATION`)."""
    observation(
        t.layout, t.clocks, t.clock_starts, t.q, t.dq, t.ee_position, t.ee_rotation, t.goal,
        t.last_action, t.temperature, t.linear_velocity, t.angular_velocity, t.gravity,
        t.command, t.orientation, t.clock, t.contact, t.norm, t.raw, t.out,
    )  # fmt: skip
