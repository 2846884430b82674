"""Soak sessions and campaigns: hours of the runtime against a randomized, faulty MuJoCo plant.

A **session** is one continuous run of :class:`deploy.runtime.Runtime` with the simulated clock
(:class:`~deploy.runtime.SimClock`) for ``hours`` of simulated time (8 by default): a new goal
every ``goal_period`` s (:class:`deploy.goals.GoalScheduler`), dynamics, sensor settings, drift and
a fault schedule drawn from the session seed (:func:`eval.randomization.sample_session`), friction
rising with wear over the session, the motor thermal model running throughout. A **campaign** is
several seeded sessions (seeds ``seed, seed + 1, ...``), run by local processes
(``concurrent.futures.ProcessPoolExecutor``, one worker per core; a campaign of a single batch runs
in the calling process) or by Ray (one task per batch).

Batching. Several sessions run in one process through the runtime's batch axis: one
:class:`~deploy.backends.sim.SimBackend` with ``envs = k`` (one randomized ``MjModel`` per env)
and one :class:`~deploy.runtime.Runtime` over all of them (one ONNX Runtime call per tick). A
session's seeded quantities depend on its own seed only: its randomization; its encoder noise and
dropout draws (one numpy generator per env,
:meth:`~deploy.backends.sim.SimBackend.set_sensor_streams`, where SimBackend has one for the
batch); its goals (one ``GoalScheduler`` for the batch with one goal stream per session); its
faults (a :class:`deploy.faults.FaultInjector` per session on its env, :class:`SessionFaults`); its
operator resets. Every runtime stage computes each env on its own, except Ruckig, which serves
the whole batch and, when it resamples a trajectory for an unchanged input instead of
recalculating it, differs from one instance per env at ~1e-16 (:mod:`deploy.smoothing`). The
harness calls :meth:`~deploy.smoothing.CommandSmoother.recalculate` (``Ruckig.reset()``) after
every tick, so that every step recalculates (as it does
anyway whenever a target changes; a few microseconds more per tick while an env holds still): a
session's results are then the same bit for bit alone or batched with any others.

Checkpoints. Every ``checkpoint_minutes`` of simulated time each session of a batch writes its
complete state (:mod:`eval.checkpoint`) to ``OUT/sessions/<id>/``; ``resume=True`` continues from
there, and the finished session equals an uninterrupted run bit for bit (the checkpoint interval
does not change the results). A finished session writes ``result.json``; a resumed campaign
skips it. Before the runtime starts, the plant streams its sensors for a fixed number of ticks
(the largest latency the ranges allow, plus one encoder period), so that a first reading has
arrived: the plant's clock is that much ahead of the runtime's.

The runtime's responses. Every fault is judged ``FAULT_SETTLE`` s after it ends, against the
runtime's counters and modes at its onset: ``held`` (no safe stop: the runtime held the last
action, predicted through missing data, rode out the force), ``safe_stop`` (stopped, not yet
resolved), ``resumed`` (stopped and running again), ``latched`` (FAULTED), or ``not_running``
(the env was already stopped at the onset). Only ``held`` counts as survived. A latched fault is
cleared by an operator after ``operator_reset`` s (the session goes on: RAMP_IN), and counted.

Violations and interventions. After every tick a :class:`deploy.violations.ViolationMonitor`
counts the true-state violations of every session from the plant's ground truth and a
:class:`deploy.interventions.InterventionMonitor` the commands the guard or the smoother changed
(before the goal scheduler, so that a goal's last tick counts for it); both are reported apart, in
total, per hour and on the curves, and are part of the checkpoints. Goals are also counted per
window of ``window_minutes`` (by their issue time), and each goal replaced unreached is recorded
with its true end state (:class:`deploy.goals.GoalScheduler`).

Divergence: MuJoCo's divergence (:class:`~deploy.backends.sim.SimulationDivergedError`) ends the
session that diverged with ``diverged`` set; the other sessions of its batch continue from their
last checkpoints.
"""

from __future__ import annotations

import concurrent.futures
import json
import math
import multiprocessing
import os
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from deploy.backends.base import SensorFrame
from deploy.errors import Sim2RealError
from deploy.files import atomic_write, sha256_file
from deploy.goals import GoalScheduler
from deploy.interventions import INTERVENTION_CHECKS, InterventionMonitor
from deploy.runtime import FAULT_CAUSES, STAGES, Mode
from deploy.stateful import prefixed, put, take
from deploy.violations import VIOLATION_TYPES, ViolationMonitor
from eval import checkpoint as ckpt
from eval.fault_schedule import FAULT_SETTLE
from eval.randomization import (
    SessionRanges,
    apply_drift,
    apply_sensors,
    joint_dofs,
    randomized_model,
    sample_session,
    session_rng,
)

os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

#: s between the harness's supervision steps (latches, operator resets, fault arming, curves).
SUPERVISE_PERIOD = 0.1
#: s between updates of the drifting friction.
DRIFT_PERIOD = 10.0
#: s of simulated time between progress reports.
PROGRESS_PERIOD = 10.0
#: s before a fault's onset its injector is armed.
ARM_LEAD = 0.5
RESPONSES = ("held", "safe_stop", "resumed", "latched", "not_running")
VIOLATION_SOURCE = "true state (simulation ground truth)"
SESSIONS_DIR = "sessions"
#: The batch's per-env thermal accumulators a checkpoint keeps (``stats/<name>``).
STATS = ("peak", "window_peak", "band_ticks", "over_ticks")


class SessionError(Sim2RealError, ValueError):
    """Bad session options; the message names the option and the expected value."""


@dataclass(frozen=True)
class SessionConfig:
    """Options of one soak session (a campaign's sessions differ only in ``seed``).

    Attributes:
        robot: Shipped robot name or robot.toml path.
        policy: ONNX policy (made by policy-export).
        seed: Session seed (>= 0); every random draw of the session derives from it.
        hours: Simulated hours.
        goal_period: s between new goals.
        success_time: A goal counts as reached within this many seconds.
        checkpoint_minutes: Simulated minutes between checkpoints (0: none).
        curve_seconds: Simulated seconds between points of the downsampled curves.
        operator_reset: s a latched fault stays before an operator clears it (0: never).
        faults: Inject the seeded fault schedule.
        ranges: What the randomization draws from.
        window_minutes: Simulated minutes per window of the windowed goal success rate.
    """

    robot: str = "arm3"
    policy: str = "policies/arm.onnx"
    seed: int = 0
    hours: float = 8.0
    goal_period: float = 4.0
    success_time: float = 3.0
    checkpoint_minutes: float = 5.0
    curve_seconds: float = 60.0
    operator_reset: float = 10.0
    faults: bool = True
    ranges: SessionRanges = field(default_factory=SessionRanges)
    window_minutes: float = 10.0

    def __post_init__(self):
        def bad(name: str, expected: str) -> SessionError:
            return SessionError(f"{name}: expected {expected}, got {getattr(self, name)!r}")

        if not isinstance(self.seed, int) or self.seed < 0:
            raise bad("seed", "an integer >= 0")
        for name in ("hours", "goal_period", "success_time", "curve_seconds", "window_minutes"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise bad(name, "a finite number > 0")
        for name in ("checkpoint_minutes", "operator_reset"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise bad(name, "a finite number >= 0")

    @property
    def duration(self) -> float:
        """Session length, s."""
        return self.hours * 3600.0

    @property
    def id(self) -> str:
        """The session's name: ``seed<seed>``."""
        return f"seed{self.seed:04d}"

    def to_dict(self) -> dict:
        """JSON-ready options (tuples become lists)."""
        return json.loads(json.dumps(asdict(self)))

    def batch_key(self) -> dict:
        """The options sessions of one batch must share (all but the seed)."""
        d = self.to_dict()
        d.pop("seed")
        return d


def session_dir(out: str | os.PathLike, seed: int) -> Path:
    """Folder of session ``seed`` in campaign folder ``out``."""
    return Path(out) / SESSIONS_DIR / SessionConfig(seed=seed).id


# ====================================================================== batch plumbing
class _BackendSlice:
    """Env ``e`` of a SimBackend as a one-env backend: what a FaultInjector uses (views of the
    per-env sensor settings, the env's model, forces)."""

    envs = 1

    def __init__(self, backend, e: int):
        self._backend, self._e = backend, e
        self.dropout_probability = backend.dropout_probability[e : e + 1]
        self.latency_ticks = backend.latency_ticks[e : e + 1]
        self.max_latency_ticks = backend.max_latency_ticks
        self.models = [backend.models[e]]

    def set_external_force(self, env: int, force: np.ndarray, body: str | None = None) -> None:
        self._backend.set_external_force(self._e, force, body)


class SessionFaults:
    """The fault injector the runtime sees: one :class:`deploy.faults.FaultInjector` per session,
    on that session's env only, armed from ``ARM_LEAD`` s before each fault until it is judged.

    Per-session injectors keep the sessions of a batch apart (one injector for the batch freezes
    one frame for every stale fault and resets every env's sensor settings each tick), and only
    armed injectors cost time in the tick.
    """

    def __init__(self, backend):
        self.backend = backend
        self.slices = [_BackendSlice(backend, e) for e in range(backend.envs)]
        f = backend.frame
        self.frames = [
            SensorFrame(
                time=f.time[e : e + 1],
                position=f.position[e : e + 1],
                position_stamp=f.position_stamp[e : e + 1],
                winding_temperature=f.winding_temperature[e : e + 1],
                temperature_stamp=f.temperature_stamp[e : e + 1],
            )
            for e in range(backend.envs)
        ]
        self.armed: list = [None] * backend.envs
        self._items: list = []

    def arm(self, e: int, fault):
        from deploy.faults import FaultInjector

        self.armed[e] = FaultInjector([fault], self.slices[e])
        self._items = [(i, inj) for i, inj in enumerate(self.armed) if inj is not None]
        return self.armed[e]

    def disarm(self, e: int):
        inj, self.armed[e] = self.armed[e], None
        self._items = [(i, x) for i, x in enumerate(self.armed) if x is not None]
        return inj

    def before_read(self, t: float) -> None:
        for _, inj in self._items:
            inj.before_read(t)

    def filter_frame(self, t: float, frame: SensorFrame) -> SensorFrame:
        for e, inj in self._items:
            inj.filter_frame(t, self.frames[e])
        return frame

    def filter_action(self, t: float, action: np.ndarray) -> np.ndarray:
        for e, inj in self._items:
            inj.filter_action(t, action[e : e + 1])
        return action


class _Stats:
    """The batch's thermal accumulators (``STATS``: winding peak, window peak, ticks in the
    derating band, ticks over the maximum; (envs, n)) as a stage of a checkpoint
    (:mod:`deploy.stateful`)."""

    def __init__(self, batch):
        self.batch = batch

    def _fields(self) -> dict[str, np.ndarray]:
        return {name: getattr(self.batch, name) for name in STATS}

    def state_dict(self, env: int | None = None) -> dict[str, np.ndarray]:
        return take(self._fields(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        put(self._fields(), state, env)


def _ticks(seconds: float, dt: float) -> int:
    return max(int(round(seconds / dt)), 1)


# ====================================================================== one session
class _Session:
    """Book-keeping of one session (env ``e`` of a batch): goals, faults, latches, curves."""

    def __init__(self, batch: SessionBatch, e: int, config: SessionConfig, draw):
        self.batch, self.e, self.config, self.draw = batch, e, config, draw
        rt, robot = batch.rt, batch.robot
        self.goals = batch.goals  # env e of the batch's scheduler, on this session's own stream
        dt = robot.control_period
        self.schedule = list(draw.faults)
        self.fault_index = 0
        self.fault_armed = False
        self.fault_snapshot: dict = {}
        self.fault_events: list[dict] = []
        self.next_fault_tick = self._arm_tick(0, dt)
        self.latches: list[dict] = []
        self.operator_resets = 0
        self.latched_since = -1.0
        self.hours: list[dict] = []
        self.hour_base = self.counters()
        self.curve: dict = {
            "t_s": [0.0],
            "winding_c": [[float(x) for x in batch.backend.thermal.winding_temperature[e]]],
            "issued": [0],
            "reached": [0],
            "violations": [self.hour_base["violations"]],
            "interventions": [self.hour_base["interventions"]],
            "mode": [int(rt.mode[e])],
        }
        self.friction = [float(x) for x in self.batch.initial_friction[e]]
        self.wall_s = 0.0
        self.diverged: str | None = None

    # ------------------------------------------------------------------ counters
    def counters(self) -> dict:
        """The session's cumulative counters: ``ticks``, ``violations`` {type: ticks, "any"}
        (true state), ``interventions`` {check: ticks, "any"}, ``warnings`` {name: ticks}."""
        b, e = self.batch, self.e
        iv = b.interventions
        interventions = {c: int(v[e]) for c, v in iv.counts.items()}
        interventions["any"] = int(iv.any[e])
        return {
            "ticks": iv.ticks,
            "violations": b.violations.env_counts(e),
            "interventions": interventions,
            "warnings": {k: int(v[e]) for k, v in iv.warnings().items()},
        }

    def hour_row(self, start: float, end: float) -> dict:
        """The counters since the last hour row (``hour_base``), as a row of ``hours``."""
        now, base = self.counters(), self.hour_base
        row = {"hour": len(self.hours), "start_s": start, "end_s": end}
        row["ticks"] = now["ticks"] - base["ticks"]
        for key in ("violations", "interventions", "warnings"):
            row[key] = {k: v - base[key].get(k, 0) for k, v in now[key].items()}
        return row

    # ------------------------------------------------------------------ faults
    def _arm_tick(self, index: int, dt: float) -> float:
        if index >= len(self.schedule):
            return math.inf
        return math.floor((self.schedule[index].start - ARM_LEAD) / dt)

    def _counters(self) -> dict:
        rt, e = self.batch.rt, self.e
        est = rt.estimator
        return {
            "safe_stops": int(rt.counters.safe_stops[e]),
            "non_finite_actions": int(rt.counters.non_finite_actions[e]),
            "resyncs": int(rt.counters.resyncs[e]),
            "anchors": int(rt.counters.anchors[e]),
            "missing_readings": int(est.missing_per_joint[e].sum()),
            "stale_readings": int(est.stale_per_joint[e].sum()),
            "latches": len(self.latches),
            **{f"cause/{c}": int(v[e]) for c, v in rt.counters.faults.items()},
        }

    def fault_step(self, ticks: int) -> None:
        """Arm the next fault, or judge the armed one (at its supervision tick)."""
        batch, e = self.batch, self.e
        rt, dt = batch.rt, batch.dt
        if not self.fault_armed:
            fault = self.schedule[self.fault_index]
            batch.faults.arm(e, fault)
            self.fault_armed = True
            self.fault_snapshot = self._counters()
            self.fault_snapshot["mode"] = Mode(int(rt.mode[e])).name
            self.next_fault_tick = math.ceil((fault.start + fault.duration + FAULT_SETTLE) / dt)
            return
        fault = self.schedule[self.fault_index]
        inj = batch.faults.disarm(e)
        now, before = self._counters(), self.fault_snapshot
        delta = {k: now[k] - before[k] for k in now}
        mode = Mode(int(rt.mode[e]))
        if before["mode"] in ("SAFE_STOP", "FAULTED"):
            response = "not_running"
        elif delta["safe_stops"] == 0 and delta["latches"] == 0 and mode != Mode.FAULTED:
            response = "held"
        elif delta["latches"] > 0 or mode == Mode.FAULTED:
            response = "latched"
        elif mode in (Mode.RUNNING, Mode.RAMP_IN):
            response = "resumed"
        else:
            response = "safe_stop"
        self.fault_events.append(
            {
                "kind": fault.kind,
                "start_s": fault.start,
                "duration_s": fault.duration,
                "magnitude": fault.magnitude,
                "applied": bool(inj is not None and inj.log),
                "mode_at_onset": before["mode"],
                "response": response,
                "survived": response == "held",
                "causes": [c for c in FAULT_CAUSES if delta[f"cause/{c}"] > 0],
                "non_finite_actions_held": delta["non_finite_actions"],
                "missing_readings": delta["missing_readings"],
                "stale_readings": delta["stale_readings"],
                "resyncs": delta["resyncs"],
                "mode_after": mode.name,
            }
        )
        self.fault_armed = False
        self.fault_index += 1
        self.next_fault_tick = self._arm_tick(self.fault_index, dt)

    # ------------------------------------------------------------------ checkpoint
    def capture(self) -> tuple[dict, dict]:
        rt, e, b = self.batch.rt, self.e, self.batch
        state = rt.state_dict(e)  # the runtime and its stages, the plant and policy included
        state.update(prefixed("goals", self.goals.state_dict(e)))
        state.update(prefixed("stats", _Stats(b).state_dict(e)))
        state.update(prefixed("violations", b.violations.state_dict(e)))
        state.update(prefixed("interventions", b.interventions.state_dict(e)))
        if self.fault_armed:
            state.update(prefixed("injector", b.faults.armed[e].state_dict()))
        meta = {
            "tick": rt.ticks,
            "session": {
                "fault_index": self.fault_index,
                "fault_armed": self.fault_armed,
                "fault_snapshot": self.fault_snapshot,
                "fault_events": self.fault_events,
                "next_fault_tick": self.next_fault_tick,
                "latches": self.latches,
                "operator_resets": self.operator_resets,
                "latched_since": self.latched_since,
                "faulted": bool(b.faulted[e]),
                "hours": self.hours,
                "hour_base": self.hour_base,
                "curve": self.curve,
                "friction": self.friction,
                "wall_s": self.wall_s + b.wall_elapsed(),
            },
            "next": dict(b.next_ticks),
            "config": self.config.batch_key(),
            "seed": self.config.seed,
            "policy_sha256": b.policy_sha256,
            "randomization": self.draw.to_dict(),
            "batch": [s.config.seed for s in b.sessions],
        }
        return state, meta

    def restore(self, arrays: dict, meta: dict, where: Path) -> None:
        b, e = self.batch, self.e
        expected = self.config.batch_key()
        stored = meta.get("config", {})
        for key, value in expected.items():
            if key in ("policy", "checkpoint_minutes"):
                continue
            if stored.get(key) != value:
                raise ckpt.CheckpointError(
                    f"{where}: the checkpoint was made with {key} = {stored.get(key)!r}, this run "
                    f"has {value!r}; resume with the options of the interrupted campaign"
                )
        if meta.get("policy_sha256") != b.policy_sha256:
            raise ckpt.CheckpointError(
                f"{where}: the checkpoint was made with another policy file (SHA-256 "
                f"{meta.get('policy_sha256')}); this run's {self.config.policy} differs"
            )
        if meta.get("randomization") != self.draw.to_dict():
            raise ckpt.CheckpointError(
                f"{where}: the randomization stored in the checkpoint differs from the one drawn "
                f"for seed {self.config.seed} (another version of eval.randomization?)"
            )
        ckpt.load_stage(b.rt, arrays, e, where)
        ckpt.load_stage(self.goals, arrays, e, where, "goals")
        ckpt.load_stage(_Stats(b), arrays, e, where, "stats")
        ckpt.load_stage(b.violations, arrays, e, where, "violations")
        ckpt.load_stage(b.interventions, arrays, e, where, "interventions")
        s = meta["session"]
        self.fault_index = int(s["fault_index"])
        self.fault_armed = bool(s["fault_armed"])
        self.fault_snapshot = s["fault_snapshot"]
        self.fault_events = s["fault_events"]
        self.next_fault_tick = s["next_fault_tick"]
        if self.fault_armed:
            inj = b.faults.arm(e, self.schedule[self.fault_index])
            ckpt.load_stage(inj, arrays, None, where, "injector")
        self.latches = s["latches"]
        self.operator_resets = int(s["operator_resets"])
        self.latched_since = float(s["latched_since"])
        b.faulted[e] = bool(s["faulted"])
        self.hours = s["hours"]
        self.hour_base = s["hour_base"]
        self.curve = s["curve"]
        self.friction = s["friction"]
        self.wall_s = float(s["wall_s"])

    # ------------------------------------------------------------------ result
    def result(self) -> dict:
        """The session's result (see :mod:`eval.report` for the schema)."""
        b, e, rt, robot = self.batch, self.e, self.batch.rt, self.batch.robot
        names = list(robot.joint_names)
        dt = b.dt
        t_end = rt.time
        hours = list(self.hours)
        last_end = hours[-1]["end_s"] if hours else 0.0
        if t_end > last_end + 1e-9:
            hours.append(self.hour_row(last_end, t_end))
        now = self.counters()
        sim_h = t_end / 3600.0
        g, e = self.goals, self.e
        times = g.hit_times[e]
        windows = g.windows(e, t_end)
        true = now["violations"]
        interventions = b.interventions.summary(e)
        responses = {r: 0 for r in RESPONSES}
        for ev in self.fault_events:
            responses[ev["response"]] += 1
        motors = robot.motors
        est = rt.estimator
        tick_cost = rt.tick_cost
        nz = np.flatnonzero(tick_cost.counts[0])
        wall = self.wall_s + b.wall_elapsed()
        return {
            "id": self.config.id,
            "seed": self.config.seed,
            "status": "diverged" if self.diverged else "complete",
            "simulated_s": t_end,
            "simulated_hours": sim_h,
            "ticks": rt.ticks,
            "control_mode": b.mode,
            "options": self.config.batch_key(),
            "policy_sha256": b.policy_sha256,
            "randomization": self.draw.to_dict(),
            "violations": {
                "source": VIOLATION_SOURCE,
                "total": {k: true[k] for k in VIOLATION_TYPES},
                "any": true["any"],
                "per_hour": [
                    {
                        "hour": h["hour"],
                        "start_s": h["start_s"],
                        "end_s": h["end_s"],
                        "counts": {k: h["violations"][k] for k in VIOLATION_TYPES},
                        "any": h["violations"]["any"],
                    }
                    for h in hours
                ],
                "rate_per_hour": {
                    k: (true[k] / sim_h if sim_h > 0 else 0.0) for k in VIOLATION_TYPES
                },
            },
            "interventions": {
                **interventions,
                "per_hour": [
                    {
                        "hour": h["hour"],
                        "start_s": h["start_s"],
                        "end_s": h["end_s"],
                        "ticks": h["ticks"],
                        "counts": {k: h["interventions"][k] for k in INTERVENTION_CHECKS},
                        "any": h["interventions"]["any"],
                        "warnings": h["warnings"],
                    }
                    for h in hours
                ],
            },
            "goals": {
                "issued": int(g.issued[e]),
                "reached": int(g.hit_count[e]),
                "success_rate": int(g.hit_count[e]) / int(g.issued[e]) if g.issued[e] else None,
                "median_time_to_reach_s": float(np.median(times)) if times else None,
                "within_s": self.config.success_time,
                "period_s": self.config.goal_period,
                "window_s": g.window,
                "windows": windows,
                "min_window_success_rate": (
                    min(w["success_rate"] for w in windows) if windows else None
                ),
                "missed": list(g.missed[e]),
                "missed_dropped": int(g.missed_dropped[e]),
            },
            "faults": {
                "scheduled": len(self.schedule),
                "injected": len(self.fault_events),
                "survived": sum(1 for ev in self.fault_events if ev["survived"]),
                "responses": responses,
                "events": self.fault_events,
            },
            "runtime": {
                "safe_stops": int(rt.counters.safe_stops[e]),
                "by_cause": {c: int(v[e]) for c, v in rt.counters.faults.items()},
                "non_finite_actions": int(rt.counters.non_finite_actions[e]),
                "resyncs": int(rt.counters.resyncs[e]),
                "anchors": int(rt.counters.anchors[e]),
                "latched_faults": len(self.latches),
                "latches": self.latches,
                "operator_resets": self.operator_resets,
                "final_mode": Mode(int(rt.mode[e])).name,
                "final_cause": FAULT_CAUSES[rt.cause[e]] if rt.cause[e] >= 0 else None,
            },
            "estimator": {
                "missing_readings": int(est.missing_per_joint[e].sum()),
                "stale_readings": int(est.stale_per_joint[e].sum()),
                "reinitializations": int(est.reinitializations_per_joint[e].sum()),
            },
            "thermal": {
                "joints": names,
                "derating_start_c": {
                    j: m.derating_start_temperature for j, m in zip(names, motors, strict=True)
                },
                "max_winding_c": {
                    j: m.max_winding_temperature for j, m in zip(names, motors, strict=True)
                },
                "peak_c": dict(zip(names, b.peak[e].tolist(), strict=True)),
                "derating_band_s": dict(
                    zip(names, ((b.band_ticks[e] - b.over_ticks[e]) * dt).tolist(), strict=True)
                ),
                "over_temperature_s": dict(
                    zip(names, (b.over_ticks[e] * dt).tolist(), strict=True)
                ),
                "curve": {
                    "t_s": self.curve["t_s"],
                    "winding_c": {
                        j: [row[i] for row in self.curve["winding_c"]] for i, j in enumerate(names)
                    },
                },
            },
            "curves": {
                "t_s": self.curve["t_s"],
                "goals_issued": self.curve["issued"],
                "goals_reached": self.curve["reached"],
                "violations": {
                    k: [row[k] for row in self.curve["violations"]]
                    for k in (*VIOLATION_TYPES, "any")
                },
                "interventions": {
                    k: [row[k] for row in self.curve["interventions"]]
                    for k in (*INTERVENTION_CHECKS, "any")
                },
                "mode": [Mode(m).name for m in self.curve["mode"]],
            },
            "drift": {"friction_final_nm": dict(zip(names, self.friction, strict=True))},
            "diverged": self.diverged,
            "wall": {
                "wall_s": wall,
                "speed": t_end / wall if wall > 0 else None,
                "batch": [s.config.seed for s in b.sessions],
                "tick_cost_us": tick_cost.summary(),
                "tick_cost_histogram": {
                    "bin_us": nz.tolist(),
                    "count": tick_cost.counts[0][nz].tolist(),
                },
                "stage_cost_us": {s: rt.latency.summary(i) for i, s in enumerate(STAGES)},
            },
        }


# ====================================================================== a batch of sessions
class BatchDiverged(Sim2RealError, RuntimeError):
    """MuJoCo diverged in some envs of a batch; ``seeds`` names their sessions."""

    def __init__(self, seeds: list[int], message: str):
        super().__init__(message)
        self.seeds = seeds


class SessionBatch:
    """Sessions run together through the runtime's batch axis, in this process.

    Args:
        configs: The sessions (same options but the seed).
        out: Campaign folder; each session keeps ``sessions/<id>/`` there.
        resume: Continue from the sessions' checkpoints (they must be at the same tick).
        progress: Write ``progress.json`` per session every ``PROGRESS_PERIOD`` simulated s.
        on_progress: Optional callable, called after each progress write.
        film: Keep every checkpoint and note the worst moments for the film strip
            (:class:`eval.film.FilmRecorder`; it only reads the batch).

    Raises:
        SessionError: sessions with different options, or duplicate seeds.
        ValueError: unreadable robot or policy (``RobotSpecError``, ``PolicyLoadError``).
        eval.checkpoint.CheckpointError: a checkpoint that cannot be read or does not fit.
    """

    def __init__(
        self,
        configs: list[SessionConfig],
        out: str | os.PathLike,
        resume: bool = False,
        progress: bool = True,
        on_progress=None,
        film: bool = False,
    ):
        from deploy.backends.sim import SimBackend
        from deploy.policy import OnnxPolicy
        from deploy.runtime import Runtime
        from robots import load_robot

        if not configs:
            raise SessionError("a batch needs at least one session")
        first = configs[0]
        for c in configs[1:]:
            if c.batch_key() != first.batch_key():
                raise SessionError("the sessions of a batch must share every option but the seed")
        seeds = [c.seed for c in configs]
        if len(set(seeds)) != len(seeds):
            raise SessionError(f"seeds: duplicate session seeds in {seeds}")
        self.configs = list(configs)
        self.out = Path(out)
        self.write_progress = progress
        self.on_progress = on_progress
        robot = self.robot = load_robot(first.robot)
        self.policy = OnnxPolicy(first.policy, robot)
        self.policy_sha256 = sha256_file(first.policy)
        self.mode = mode = self.policy.spec.action.mode
        self.dt = dt = robot.control_period
        k = len(configs)
        draws = [sample_session(robot, c.seed, c.duration, c.ranges, c.faults) for c in configs]
        models = [randomized_model(robot, mode, d.dynamics) for d in draws]
        backend = self.backend = SimBackend(robot, mode=mode, envs=k, models=models)
        backend.set_sensor_streams([session_rng(c.seed, "sensor_noise") for c in configs])
        for e, d in enumerate(draws):
            apply_sensors(backend, e, d.sensors)
        backend.reset()  # the first readings from the sessions' own streams and settings
        # the drives stream for a while before the runtime starts, so that a reading has arrived
        # despite the latency (the same number of ticks for every session, alone or batched)
        for _ in range(first.ranges.sensors.latency_ticks[1] + backend.encoder_every):
            backend.advance()
        dofs = joint_dofs(models[0], robot)
        self.initial_friction = np.stack([m.dof_frictionloss[dofs].copy() for m in models])
        self.faults = SessionFaults(backend)
        self.rt = Runtime(robot, self.policy, backend, injector=self.faults)
        self.rt.start()

        n = robot.n_joints
        self.peak = backend.thermal.winding_temperature.copy()
        self.window_peak = self.peak.copy()
        self.band_ticks = np.zeros((k, n), dtype=np.int64)
        self.over_ticks = np.zeros((k, n), dtype=np.int64)
        self._mask = np.zeros((k, n), dtype=bool)
        self._t_start = np.array([m.derating_start_temperature for m in robot.motors])
        self._t_max = np.array([m.max_winding_temperature for m in robot.motors])
        self.faulted = np.zeros(k, dtype=bool)

        self.total_ticks = int(round(first.duration / dt))
        self.every = _ticks(SUPERVISE_PERIOD, dt)
        self.periods = {
            "drift": _ticks(DRIFT_PERIOD, dt),
            "curve": _ticks(first.curve_seconds, dt),
            "hour": _ticks(3600.0, dt),
            "progress": _ticks(PROGRESS_PERIOD, dt),
        }
        self.next_ticks = dict(self.periods)
        self.checkpoint_ticks = (
            _ticks(first.checkpoint_minutes * 60.0, dt) if first.checkpoint_minutes > 0 else 0
        )
        # what the plant really did (true state) and what the guard and smoother changed
        self.violations = ViolationMonitor(robot, k)
        self.interventions = InterventionMonitor(self.rt.guard, self.rt.smoother)
        self.goals = GoalScheduler(
            robot,
            k,
            first.goal_period,
            None,
            first.success_time,
            [session_rng(c.seed, "goals") for c in configs],
            window=first.window_minutes * 60.0,
            interventions=self.interventions,
        )
        self.sessions = [
            _Session(self, e, c, d) for e, (c, d) in enumerate(zip(configs, draws, strict=True))
        ]
        self._next_event = self.every
        self._ruckig = mode != "torque"
        self._wall0 = time.perf_counter()
        if resume:
            self._resume()
        self.film = None
        if film:
            from eval.film import FilmRecorder

            self.film = FilmRecorder(self)

    # ------------------------------------------------------------------ lifecycle
    def wall_elapsed(self) -> float:
        """Wall-clock seconds this process has run the batch since it was built or resumed."""
        return time.perf_counter() - self._wall0

    def _resume(self) -> None:
        loaded = []
        for s in self.sessions:
            d = session_dir(self.out, s.config.seed)
            got = ckpt.read_checkpoint(d)
            loaded.append((s, d, got))
        have = [x for x in loaded if x[2] is not None]
        if not have:
            return
        if len(have) != len(loaded):
            missing = [s.config.id for s, _, got in loaded if got is None]
            raise ckpt.CheckpointError(
                f"sessions {missing} have no checkpoint in {self.out / SESSIONS_DIR} while others "
                "of their batch do; resume them separately"
            )
        ticks = {int(got[1]["tick"]) for _, _, got in have}
        if len(ticks) != 1:
            raise ckpt.CheckpointError(
                f"the checkpoints of a batch are at different ticks {sorted(ticks)} in "
                f"{self.out / SESSIONS_DIR}"
            )
        _, _, (_, m0) = have[0]
        self.next_ticks = {k: int(v) for k, v in m0["next"].items()}
        for s, d, (arrays, meta) in have:
            s.restore(arrays, meta, d / ckpt.MANIFEST)
        self._next_event = (self.rt.ticks // self.every + 1) * self.every
        self._wall0 = time.perf_counter()

    def checkpoint(self) -> None:
        """Write every session's checkpoint (atomically, see :mod:`eval.checkpoint`)."""
        for s in self.sessions:
            arrays, meta = s.capture()
            ckpt.write_checkpoint(session_dir(self.out, s.config.seed), arrays, meta)

    # ------------------------------------------------------------------ per tick
    def on_tick(self, rt) -> None:
        """The batch's per-tick bookkeeping after each runtime tick (monitors, goals, peaks,
        supervision); what :meth:`run` passes to ``Runtime.run(on_tick=...)``, and a replay of
        the session must pass too."""
        if self._ruckig:
            # the next step recalculates every trajectory from its input, in every env: the same
            # numbers whatever the neighbours (see the module docstring) and across a restore
            rt.smoother.recalculate()
        self.violations.update(self.backend)
        self.interventions.update()  # before the goals: a goal's last tick counts for it
        self.goals(rt)
        temp = self.backend.thermal.winding_temperature
        np.maximum(self.peak, temp, out=self.peak)
        np.maximum(self.window_peak, temp, out=self.window_peak)
        np.greater_equal(temp, self._t_start, out=self._mask)
        self.band_ticks += self._mask
        np.greater(temp, self._t_max, out=self._mask)
        self.over_ticks += self._mask
        if rt.ticks >= self._next_event:
            self._supervise(rt)

    def _supervise(self, rt) -> None:
        ticks, t = rt.ticks, rt.time
        self._next_event = ticks + self.every
        faulted = rt.mode == Mode.FAULTED
        if faulted.any() or self.faulted.any():
            for e in np.flatnonzero(faulted & ~self.faulted):
                s = self.sessions[e]
                s.latches.append({"t_s": t, "cause": rt.cause_names()[e], "reset_s": None})
                s.latched_since = t
            self.faulted[:] = faulted
            reset_after = self.configs[0].operator_reset
            if reset_after > 0:
                due = np.zeros_like(faulted)
                for e in np.flatnonzero(faulted):
                    if t - self.sessions[e].latched_since >= reset_after - 1e-9:
                        due[e] = True
                if due.any():
                    rt.reset_faults(due)
                    for e in np.flatnonzero(due):
                        s = self.sessions[e]
                        s.operator_resets += 1
                        s.latches[-1]["reset_s"] = t
                    self.faulted[due] = False
        for s in self.sessions:
            if ticks >= s.next_fault_tick:
                s.fault_step(ticks)
        nt = self.next_ticks
        if ticks >= nt["drift"]:
            nt["drift"] += self.periods["drift"]
            for s in self.sessions:
                value = apply_drift(
                    self.backend.models[s.e],
                    self.robot,
                    self.initial_friction[s.e],
                    s.draw.drift,
                    t,
                )
                s.friction = [float(x) for x in value]
        if ticks >= nt["curve"]:
            nt["curve"] += self.periods["curve"]
            for s in self.sessions:
                c, e = s.curve, s.e
                c["t_s"].append(t)
                c["winding_c"].append([float(x) for x in self.window_peak[e]])
                c["issued"].append(int(self.goals.issued[e]))
                c["reached"].append(int(self.goals.hit_count[e]))
                now = s.counters()
                c["violations"].append(now["violations"])
                c["interventions"].append(now["interventions"])
                c["mode"].append(int(rt.mode[e]))
            self.window_peak[:] = self.backend.thermal.winding_temperature
        if ticks >= nt["hour"]:
            nt["hour"] += self.periods["hour"]
            for s in self.sessions:
                start = s.hours[-1]["end_s"] if s.hours else 0.0
                s.hours.append(s.hour_row(start, t))
                s.hour_base = s.counters()
        if ticks >= nt["progress"]:
            nt["progress"] += self.periods["progress"]
            self._progress()
        if self.film is not None:
            self.film.supervise(rt)

    def _progress(self, done: bool = False) -> None:
        if not self.write_progress:
            return
        try:
            self._write_progress(done)
        finally:
            if self.on_progress is not None:
                self.on_progress()

    def _write_progress(self, done: bool) -> None:
        for s in self.sessions:
            d = session_dir(self.out, s.config.seed)
            d.mkdir(parents=True, exist_ok=True)
            atomic_write(
                d / "progress.json",
                json.dumps(
                    {
                        "simulated_s": self.rt.time,
                        "total_s": self.total_ticks * self.dt,
                        "wall_s": s.wall_s + self.wall_elapsed(),
                        "done": done,
                    }
                ),
            )

    # ------------------------------------------------------------------ the run
    def run(self) -> list[dict]:
        """Run every session to its end (from where it stands) and return their results.

        Checkpoints are written every ``checkpoint_minutes``; each finished session writes
        ``result.json`` (atomically).

        Raises:
            BatchDiverged: MuJoCo diverged in some envs; their results are written (``diverged``
                set), the other sessions must continue from their checkpoints.
        """
        from deploy.backends.sim import SimulationDivergedError

        rt = self.rt
        every = self.checkpoint_ticks
        while rt.ticks < self.total_ticks:
            stop = self.total_ticks
            if every:
                stop = min(stop, (rt.ticks // every + 1) * every)
            try:
                rt.run(stop - rt.ticks, on_tick=self.on_tick)
            except SimulationDivergedError as exc:
                self._diverged(exc)
            if every and rt.ticks % every == 0 and rt.ticks < self.total_ticks:
                self.checkpoint()
                if self.film is not None:
                    self.film.checkpointed()
        if self.film is not None:
            self.film.finish()
        results = [s.result() for s in self.sessions]
        for s, r in zip(self.sessions, results, strict=True):
            d = session_dir(self.out, s.config.seed)
            d.mkdir(parents=True, exist_ok=True)  # a session shorter than PROGRESS_PERIOD
            atomic_write(d / "result.json", json.dumps(r))
        self._progress(done=True)
        return results

    def _diverged(self, exc: Exception) -> None:
        bad = []
        for e in range(self.backend.envs):
            try:
                self.backend.check_divergence(e)
            except Exception as err:  # noqa: BLE001 - the backend's own check, re-run per env
                bad.append((e, str(err)))
        if not bad:
            bad = [(e, str(exc)) for e in range(len(self.sessions))]
        seeds = []
        for e, message in bad:
            s = self.sessions[e]
            s.diverged = message
            d = session_dir(self.out, s.config.seed)
            d.mkdir(parents=True, exist_ok=True)
            atomic_write(d / "result.json", json.dumps(s.result()))
            seeds.append(s.config.seed)
        raise BatchDiverged(seeds, str(exc)) from exc


def read_result(out: str | os.PathLike, seed: int) -> dict | None:
    """The finished result of session ``seed`` in campaign folder ``out``, or None."""
    path = session_dir(out, seed) / "result.json"
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ckpt.CheckpointError(
            f"{path}: not a readable session result ({exc}); delete it to run the session again"
        ) from None


def _check_result(result: dict, config: SessionConfig, out) -> None:
    """A finished session may only stand for ``config`` if it was run with the same options."""
    path = session_dir(out, config.seed) / "result.json"
    stored, expected = result.get("options", {}), config.batch_key()
    for key, value in expected.items():
        if key not in ("policy", "checkpoint_minutes") and stored.get(key) != value:
            raise ckpt.CheckpointError(
                f"{path}: the session was run with {key} = {stored.get(key)!r}, this run has "
                f"{value!r}; resume with the options of that campaign or use another --out"
            )
    if result.get("policy_sha256") != sha256_file(config.policy):
        raise ckpt.CheckpointError(
            f"{path}: the session was run with another policy file than {config.policy}"
        )


def run_sessions(
    configs: list[SessionConfig],
    out: str,
    resume: bool = False,
    on_progress=None,
    film: bool = False,
) -> list[dict]:
    """Run sessions as one batch in this process (the work of one executor task); ``film``: see
    :class:`SessionBatch`.

    Finished sessions (``result.json``) are skipped when resuming. If MuJoCo diverges in one
    session, it ends there (``diverged`` set) and the others continue from their last
    checkpoints, in a batch without it.

    Returns:
        One result per config, in order.
    """
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    results: dict[int, dict] = {}
    pending = list(configs)
    if resume:
        for c in configs:
            r = read_result(out, c.seed)
            if r is not None:
                _check_result(r, c, out)
                results[c.seed] = r
        pending = [c for c in configs if c.seed not in results]
    while pending:
        try:
            batch = SessionBatch(pending, out, resume=resume, on_progress=on_progress, film=film)
            for r in batch.run():
                results[r["seed"]] = r
            pending = []
        except BatchDiverged as exc:
            for seed in exc.seeds:
                results[seed] = read_result(out, seed)
            pending = [c for c in pending if c.seed not in exc.seeds]
            resume = True
    return [results[c.seed] for c in configs]


# ====================================================================== campaigns
def plan_batches(
    configs: list[SessionConfig], out: str | os.PathLike, per_process: int, resume: bool
) -> list[list[SessionConfig]]:
    """Group sessions into batches of at most ``per_process``. When resuming, sessions that were
    checkpointed together are grouped as they were (same neighbours, same tick), so that the
    resumed run equals the uninterrupted one."""
    if per_process < 1:
        raise SessionError(f"sessions_per_process: expected an integer >= 1, got {per_process}")
    batches: list[list[SessionConfig]] = []
    fresh: list[SessionConfig] = []
    if resume:
        groups: dict[tuple, list[SessionConfig]] = {}
        by_seed = {c.seed: c for c in configs}
        for c in configs:
            if read_result(out, c.seed) is not None:
                continue
            got = ckpt.read_checkpoint(session_dir(out, c.seed))
            if got is None:
                fresh.append(c)
                continue
            meta = got[1]
            key = (int(meta["tick"]), tuple(int(s) for s in meta.get("batch", [c.seed])))
            groups.setdefault(key, []).append(by_seed[c.seed])
        batches.extend(groups.values())
    else:
        fresh = list(configs)
    for i in range(0, len(fresh), per_process):
        batches.append(fresh[i : i + per_process])
    return batches


def default_workers() -> int:
    """One worker per core available to this process."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


class _Progress:
    """Campaign progress in simulated hours and speed (simulated / wall), from the sessions'
    ``progress.json`` files, shown with tqdm."""

    def __init__(self, configs: list[SessionConfig], out: Path, show: bool):
        self.configs, self.out = configs, out
        self.total_h = sum(c.hours for c in configs)
        self.start = {c.seed: self._done_s(c.seed) for c in configs}
        self.t0 = time.perf_counter()
        self.bar = None
        self._last, self._shown = -1.0, 0.0
        if show:
            from tqdm import tqdm

            self.bar = tqdm(
                total=round(self.total_h, 4),
                unit="sim-h",
                desc="soak",
                bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.3f}/{total:.3f} simulated h "
                "[{elapsed}<{remaining}{postfix}]",
                dynamic_ncols=True,
            )
            self.update()

    def _done_s(self, seed: int) -> float:
        path = session_dir(self.out, seed) / "progress.json"
        try:
            return float(json.loads(path.read_text())["simulated_s"])
        except (OSError, ValueError, KeyError, json.JSONDecodeError):
            return 0.0

    def update(self) -> None:
        if self.bar is None:
            return
        done = {c.seed: self._done_s(c.seed) for c in self.configs}
        total_s = sum(done.values())
        new_s = sum(max(done[s] - self.start[s], 0.0) for s in done)
        wall = time.perf_counter() - self.t0
        if total_s == self._last and wall - self._shown < 5.0:
            return
        self._last, self._shown = total_s, wall
        self.bar.n = round(total_s / 3600.0, 4)
        self.bar.set_postfix_str(f"speed {new_s / wall:.1f}x real time" if wall > 0 else "")
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.update()
            self.bar.close()


def run_campaign(
    template: SessionConfig,
    sessions: int,
    out: str | os.PathLike,
    *,
    resume: bool = False,
    executor: str = "local",
    address: str | None = None,
    sessions_per_process: int = 1,
    workers: int | None = None,
    progress: bool = True,
    film: bool = False,
) -> list[dict]:
    """Run ``sessions`` seeded sessions (seeds ``template.seed + i``) and return their results.

    Args:
        template: Options of every session; its seed is the first session's.
        sessions: Number of sessions (>= 1).
        out: Campaign folder (``sessions/<id>/`` holds checkpoints, progress and results).
        resume: Continue an interrupted campaign from its checkpoints; without it, the sessions'
            earlier state in ``out`` is discarded.
        executor: ``'local'`` (processes; a campaign of one batch runs in this process) or
            ``'ray'``.
        address: Ray cluster address (``ray.init(address)``); None starts a local Ray instance
            unless one is already initialized in this process.
        sessions_per_process: Sessions batched in one runtime.
        workers: Local processes (default: one per core).
        progress: Show a progress bar (simulated hours and speed).
        film: Record for the film strip (:class:`SessionBatch`; :func:`eval.film.film_campaign`
            renders it afterwards).

    Raises:
        SessionError: bad options (named).
        ValueError: unreadable robot or policy; eval.checkpoint.CheckpointError when resuming.
    """
    from deploy.policy import OnnxPolicy
    from robots import load_robot

    if not isinstance(sessions, int) or sessions < 1:
        raise SessionError(f"sessions: expected an integer >= 1, got {sessions!r}")
    if executor not in ("local", "ray"):
        raise SessionError(f"executor: expected 'local' or 'ray', got {executor!r}")
    if workers is not None and workers < 1:
        raise SessionError(f"workers: expected an integer >= 1, got {workers}")
    out = Path(out)
    robot = load_robot(template.robot)
    OnnxPolicy(template.policy, robot)  # bad input fails here, before any worker starts
    configs = [replace(template, seed=template.seed + i) for i in range(sessions)]
    if not resume:
        for c in configs:
            shutil.rmtree(session_dir(out, c.seed), ignore_errors=True)
    else:
        for c in configs:  # finished sessions must have been run with these options
            r = read_result(out, c.seed)
            if r is not None:
                _check_result(r, c, out)
    (out / SESSIONS_DIR).mkdir(parents=True, exist_ok=True)
    batches = plan_batches(configs, out, sessions_per_process, resume)
    bar = _Progress(configs, out, progress)
    try:
        if executor == "local" and len(batches) == 1:  # one batch: no process to spawn
            results = [run_sessions(batches[0], str(out), resume, bar.update, film)]
        elif executor == "local":
            results = _run_local(batches, out, resume, workers or default_workers(), bar, film)
        else:
            results = _run_ray(batches, out, resume, address, workers, bar, film)
    finally:
        bar.close()
    by_seed = {r["seed"]: r for rs in results for r in rs}
    for c in configs:  # sessions finished before a resume
        if c.seed not in by_seed:
            by_seed[c.seed] = read_result(out, c.seed)
    return [by_seed[c.seed] for c in configs]


def _run_local(batches, out: Path, resume: bool, workers: int, bar: _Progress, film=False) -> list:
    if not batches:
        return []
    ctx = multiprocessing.get_context("spawn")  # the parent holds ONNX Runtime threads: no fork
    workers = min(workers, len(batches))
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        futures = [pool.submit(run_sessions, b, str(out), resume, None, film) for b in batches]
        pending = set(futures)
        while pending:
            _, pending = concurrent.futures.wait(
                pending, timeout=0.5, return_when=concurrent.futures.FIRST_COMPLETED
            )
            bar.update()
        return [f.result() for f in futures]


def _run_ray(
    batches, out: Path, resume: bool, address, workers, bar: _Progress, film=False
) -> list:
    import ray

    started = False
    if not ray.is_initialized():
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(
                num_cpus=workers or default_workers(), include_dashboard=False, log_to_driver=False
            )
        started = True
    try:
        task = ray.remote(num_cpus=1)(run_sessions)
        refs = [task.remote(b, str(out), resume, None, film) for b in batches]
        pending = list(refs)
        while pending:
            _, pending = ray.wait(pending, num_returns=len(pending), timeout=0.5)
            bar.update()
        return ray.get(refs)
    finally:
        if started:
            ray.shutdown()
