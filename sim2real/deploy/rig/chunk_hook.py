"""A chunked policy's run figures (:class:`ChunkHook`): its cadence (servo ticks per policy tick,
policy ticks per chunk) and the joint jerk at chunk boundaries against inside chunks
(:func:`sim2real.deploy.observe.chunk_jerk.boundary_jerk`) of env 0, for three signals of the same
run: the joints (the plant's true positions in simulation, the estimate on hardware), the guard's
target (what a loop without the smoother writes to the servos: LeRobot's own, ``send_action`` at
every policy tick) and the command the smoother wrote.

Only RUNNING ticks count; the first chunk of each RUNNING stretch (taken at the end of RAMP_IN,
from rest; with async inference one policy tick later, the arm held at rest meanwhile) is no
boundary. The record stops after :data:`MAX_TICKS` ticks (said in the report).

With async inference the hook also owns the run's side of the policy's worker thread: at the
start it tells the policy whether the run is on the wall clock (its wait for a chunk bounded
there), after each tick it stops safely (cause ``overrun``: the computer, not the robot) the
envs whose chunk came late, and its close and discard (every exit path of a run) end the thread.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.observe.chunk_jerk import boundary_jerk
from sim2real.deploy.rig.hooks import RunHook

#: Servo ticks recorded (our choice: 100 Hz x 2 h, 3 x 6 float64 per tick, 35 MB).
MAX_TICKS = 720_000


class ChunkHook(RunHook):
    """The run's ``chunks`` report section (module docstring) for a policy with ``new_chunk``
    and ``policy_tick`` flags ((envs,) bool, set at each call), ``period`` (s) and ``contract``
    (:class:`~sim2real.deploy.policy.lerobot_policy.LeRobotChunkPolicy`).

    Attributes:
        position, target, command: lists of (n,) rad per recorded tick (env 0).
        boundaries, policy_ticks: recorded tick indices of the chunk boundaries and policy ticks.
        truth: the positions are the plant's true ones (else the runtime's estimate).
    """

    name = "chunks"

    def __init__(self, rig):
        self.rig, self.policy = rig, rig.runtime.policy
        self.truth = bool(rig.simulated and hasattr(rig.backend, "true_position"))
        self.position: list[np.ndarray] = []
        self.target: list[np.ndarray] = []
        self.command: list[np.ndarray] = []
        self.boundaries: list[int] = []
        self.policy_ticks: list[int] = []
        self.starts = 0
        self._running = False
        self._stretch: list[int] = []  # policy ticks per chunk of the run, RUNNING
        self._since = 0  # policy ticks since the last chunk
        self._servo_gaps: list[int] = []
        self._last_policy = None
        self._stretch_starts: list[int] = []  # recorded ticks where a RUNNING stretch began
        self._chunked = False  # this RUNNING stretch has taken its first chunk

    def start(self, rig) -> None:
        if hasattr(self.policy, "wall_clock"):
            self.policy.wall_clock = bool(rig.runtime.clock.realtime)

    def close(self) -> None:
        close = getattr(self.policy, "close", None)
        if close is not None:
            close()

    def after_tick(self, runtime) -> None:
        late = getattr(self.policy, "late", None)
        if late is not None and late.any() and len(late) == runtime.envs:
            runtime.supervision.safe_stop(late.copy(), "overrun")
        if runtime.policy is not self.policy:  # another policy took over (a hand-over)
            self._running = False
            return None
        running = bool(runtime.mode[0] == RUNNING)
        if not running or len(self.position) >= MAX_TICKS:
            self._running = running
            return None
        k = len(self.position)
        q = self.rig.backend.true_position()[0] if self.truth else runtime.state.q[0]
        self.position.append(np.array(q, dtype=float))
        self.target.append(runtime.target[0].copy())
        self.command.append(runtime.command[0].copy())
        tick, new = bool(self.policy.policy_tick[0]), bool(self.policy.new_chunk[0])
        if not self._running:  # the first RUNNING tick: the first chunk (async: asked), from rest
            self.starts += 1
            self._stretch_starts.append(k)
            self._since, self._last_policy, self._chunked = 0, None, new
        elif new and not self._chunked:  # async: the stretch's first chunk, taken from rest
            self._since, self._chunked = 0, True
            self._stretch_starts.append(k)  # its jump from the held joints is no chunk's
        elif new:
            self.boundaries.append(k)
            self._stretch.append(self._since)
            self._since = 0
        if tick:
            self.policy_ticks.append(k)
            if self._last_policy is not None:
                self._servo_gaps.append(k - self._last_policy)
            self._last_policy = k
            self._since += 1
        self._running = True
        return None

    def figures(self) -> dict:
        """The ``chunks`` section: the contract's cadence, the one measured, and
        :func:`boundary_jerk` of ``position``, ``target`` (no smoother) and ``command``."""
        p, c = self.policy, self.policy.contract
        dt = self.rig.robot.control_period
        out = {
            "policy_rate_hz": float(c.fps),
            "servo_rate_hz": 1.0 / dt,
            "chunk_size": c.chunk_size,
            "n_action_steps": c.n_action_steps,
            "temporal_ensemble_coeff": c.temporal_ensemble_coeff,
            "policy_ticks": int(p.policy_ticks[0]),
            "network_calls": int(p.calls[0]),
            "running_ticks": len(self.position),
            "running_stretches": self.starts,
            "recorded_all": len(self.position) < MAX_TICKS,
            "policy_ticks_per_chunk": sorted(set(self._stretch)),
            "servo_ticks_per_policy_tick": sorted(set(self._servo_gaps)),
            "joints": "true" if self.truth else "estimated",
            "inference": getattr(p, "inference", "sync"),
            "network_calls_on_servo_thread": int(getattr(p, "servo_thread_calls", p.calls)[0]),
            "chunk_waits": int(getattr(p, "waits", [0])[0]),
            "chunk_wait_max_ms": 1e3 * float(getattr(p, "wait_max", 0.0)),
            "late_chunks": int(getattr(p, "late_chunks", [0])[0]),
        }
        boundaries, ticks = (
            self._whole(self.boundaries, p.period / dt),
            self._whole(self.policy_ticks, p.period / dt),
        )
        for what in ("position", "target", "command"):
            x = np.asarray(getattr(self, what)).reshape(-1, self.rig.robot.n_joints)
            out[what] = boundary_jerk(x, dt, p.period, boundaries, ticks)
        return out

    def _whole(self, ticks: list[int], period_ticks: float) -> list[int]:
        """``ticks`` whose jerk window (``x[s - 3 : s + span]``) lies within one RUNNING
        stretch and does not start at one (the stretches are recorded end to end; a stretch's
        first tick is its first chunk, from rest)."""
        span = max(1, int(round(period_ticks)))
        starts = np.asarray(self._stretch_starts, dtype=np.int64)
        return [s for s in ticks if not ((starts >= s - 2) & (starts <= s + span - 1)).any()]

    def contribute(self, report: dict) -> None:
        report["chunks"] = self.figures()


def chunk_hook(rig) -> ChunkHook | None:
    """A :class:`ChunkHook` for a rig whose policy runs in chunks, else None."""
    policy = rig.runtime.policy
    if all(hasattr(policy, a) for a in ("new_chunk", "policy_tick", "contract", "period")):
        return ChunkHook(rig)
    return None
