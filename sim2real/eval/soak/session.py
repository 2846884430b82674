"""One soak session: its options, its folder, and its book-keeping inside a batch.

A **session** is one continuous run of :class:`sim2real.deploy.runtime.Runtime` with the simulated clock
(:class:`~sim2real.deploy.runtime.SimClock`) for ``hours`` of simulated time (8 by default): a new goal
every ``goal_period`` s (:class:`sim2real.deploy.tasks.goals.GoalScheduler`), dynamics, sensor settings,
drift and a fault schedule drawn from the session seed
(:func:`sim2real.eval.world.session_draw.sample_session`), friction rising with wear over the
session, the motor thermal model running throughout. It runs as env ``e`` of a batch
(:class:`sim2real.eval.soak.batch.SessionBatch`); :class:`Session` keeps what is its own there:
its fault schedule and the runtime's responses, latches, operator resets, hourly rows, curves,
drift, and its part of a checkpoint. Its folder is ``OUT/sessions/<id>/`` (:func:`session_dir`);
its result document is built by :mod:`sim2real.eval.soak.result`. A legged robot's session
(:func:`sim2real.deploy.tasks.task.task_for`) follows velocity commands instead of goals
(:mod:`sim2real.eval.soak.batch`): its ``goal_period`` is the period of the commands, ``success_time`` is
unused, and its success is the tracking success of :class:`sim2real.deploy.tasks.locomotion.CommandTracker`.

The runtime's responses. Every fault is judged ``FAULT_SETTLE`` s after it ends, against the
runtime's counters and modes at its onset: ``held`` (no safe stop: the runtime held the last
action, predicted through missing data, rode out the force), ``safe_stop`` (stopped, not yet
resolved), ``resumed`` (stopped and running again), ``latched`` (FAULTED), or ``not_running``
(the env was already stopped at the onset). A push is applied only to a RUNNING robot at least
the schedule's ``warmup`` after its last operator reset; the others are not injected but listed
(``skipped_pushes``). Only ``held`` counts as survived. A latched fault is
cleared by an operator after ``operator_reset`` s (the session goes on: RAMP_IN), and counted;
one that followed a stale-camera stop after an injected camera fault stopped the robot safely
(its ``injected``, :mod:`sim2real.eval.soak.camera_verdict`): counted, not failed.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

from sim2real.deploy.core.modes import FAULT_CAUSES, Mode
from sim2real.deploy.core.stateful import parts_state_dict, prefixed
from sim2real.eval.soak import checkpoint as ckpt
from sim2real.eval.world.fault_draws import FAULT_DRAWS
from sim2real.eval.world.fault_schedule import FAULT_SETTLE
from sim2real.eval.world.session_ranges import SessionRanges
from sim2real.robots.errors import Sim2RealError

#: s before a fault's onset its injector is armed.
ARM_LEAD = 0.5
#: The runtime's responses a fault is judged to have (module docstring); ``held`` is survived.
RESPONSES = ("held", "safe_stop", "resumed", "latched", "not_running")
#: The sessions' folder in a campaign folder (``OUT/sessions/<id>/``).
SESSIONS_DIR = "sessions"


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
        spec: PolicySpec JSON for an ONNX without our metadata (``deploy-run --spec``), or None.
        engine: Physics engine of the plant (:func:`sim2real.deploy.backends.sim.engines.engines`).
        plant_motors: A plant motors file (:mod:`sim2real.robots.plant_motors`): the motors as the plant
            simulates them, when they differ from the robot's description; None: as described.
        motion: A motion-tracking policy's clip in place of the one its contract names (None:
            the contract's); such a policy dances an exhibition: clip, ``rest_s`` s standing at
            home, clip again (:class:`~sim2real.deploy.tasks.motion.clock.MotionClock`).
        rest_s: s of rest standing between an exhibition's clips.
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
    spec: str | None = None
    engine: str = "mujoco"
    plant_motors: str | None = None
    motion: str | None = None
    rest_s: float = 10.0

    def __post_init__(self):
        def bad(name: str, expected: str) -> SessionError:
            return SessionError(f"{name}: expected {expected}, got {getattr(self, name)!r}")

        if not isinstance(self.seed, int) or self.seed < 0:
            raise bad("seed", "an integer >= 0")
        for name in ("hours", "goal_period", "success_time", "curve_seconds", "window_minutes"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise bad(name, "a finite number > 0")
        from sim2real.deploy.backends.sim.engines import engines

        if self.engine not in engines():
            raise bad("engine", f"one of {engines()}")
        for name in ("checkpoint_minutes", "operator_reset", "rest_s"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise bad(name, "a finite number >= 0")

    @property
    def command_period(self) -> tuple[float, float]:
        """s between a legged robot's velocity commands, ``(low, high)`` (each drawn
        uniformly): its ranges' ``commands.period`` when set, else ``(goal_period,
        goal_period)``."""
        commands = self.ranges.commands
        if commands is not None and commands.period is not None:
            return commands.period
        return (float(self.goal_period), float(self.goal_period))

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

    def load_policy(self, robot):
        """The session's :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy` for ``robot``: the ONNX
        ``policy`` with the contract of ``spec`` when given, else its own metadata.

        Raises:
            sim2real.deploy.spec.onnx_checks.PolicyLoadError, sim2real.deploy.spec.policy_spec.SpecError: an
                unreadable policy or spec (the message names the file).
        """
        from sim2real.deploy.policy.onnx_policy import OnnxPolicy
        from sim2real.deploy.spec.policy_spec import PolicySpec

        spec = None
        if self.spec is not None:
            spec = PolicySpec.from_json(Path(self.spec).read_text(), source=self.spec)
        return OnnxPolicy(self.policy, robot, spec=spec)

    def batch_key(self) -> dict:
        """The options sessions of one batch must share (all but the seed)."""
        d = self.to_dict()
        d.pop("seed")
        return d


def option_difference(stored: dict, expected: dict) -> tuple[str, object, object] | None:
    """The first option of ``expected`` (:meth:`SessionConfig.batch_key`) that ``stored`` (a
    checkpoint's or result's) does not have the same, but the policy path and the checkpoint
    interval (a resumed run may change those): ``(name, stored value, expected value)``, nested
    options named by their path (``ranges.sensors.noise_sigma``); None when all agree."""

    def walk(name: str, old, new):
        if isinstance(old, dict) and isinstance(new, dict):
            for key in [*new, *(k for k in old if k not in new)]:
                found = walk(f"{name}.{key}", old.get(key), new.get(key))
                if found:
                    return found
            return None
        return None if old == new else (name, old, new)

    for key, value in expected.items():
        if key in ("policy", "checkpoint_minutes"):
            continue
        # results written before the engine option ran on MuJoCo
        found = walk(key, stored.get(key, "mujoco" if key == "engine" else None), value)
        if found:
            return found
    return None


def session_dir(out: str | os.PathLike, seed: int) -> Path:
    """Folder of session ``seed`` in campaign folder ``out``."""
    return Path(out) / SESSIONS_DIR / SessionConfig(seed=seed).id


# ====================================================================== one session
class Session:
    """Book-keeping of one session (env ``e`` of a batch): goals, faults, latches, curves; its
    result document is :func:`sim2real.eval.soak.result.session_result`.

    Args:
        batch: The batch the session runs in (:class:`sim2real.eval.soak.batch.SessionBatch`).
        e: The session's env index in the batch.
        config: The session's options.
        draw: Its randomization (:func:`sim2real.eval.world.session_draw.sample_session`).
    """

    def __init__(self, batch, e: int, config: SessionConfig, draw):
        self.batch, self.e, self.config, self.draw = batch, e, config, draw
        rt, robot = batch.rt, batch.robot
        #: env e of the batch's task (goals or velocity commands), on this session's own stream
        self.task = batch.task
        dt = robot.control_period
        self.schedule = list(draw.faults)
        self.fault_index = 0
        self.fault_armed = False
        self.fault_snapshot: dict = {}
        self.fault_events: list[dict] = []
        self.skipped_pushes: list[dict] = []  # scheduled pushes not applied (_pushable)
        self.next_fault_tick = self._arm_tick(0, dt)
        self.latches: list[dict] = []
        self.operator_resets = 0
        self.stood_up = 0  # legged: operator resets that stood the robot up
        self.latched_since = -1.0
        self.hours: list[dict] = []
        self.hour_base = self.counters()
        self.curve: dict = {
            "t_s": [0.0],
            "winding_c": [[float(x) for x in batch.backend.thermal.winding_temperature[e]]],
            **self.task.curve_start(),  # goals, or commands, falls and tracking (cumulative)
            "violations": [self.hour_base["violations"]],
            "interventions": [self.hour_base["interventions"]],
            "mode": [int(rt.mode[e])],
        }
        self.friction = [float(x) for x in self.batch.initial_friction[e]]
        self.wall_s = 0.0
        self.diverged: str | None = None

    # ------------------------------------------------------------------ counters
    def counters(self) -> dict:
        """The session's cumulative counters: ``ticks`` (the robot up: a legged robot's ticks
        lying down after a stop left out), ``violations`` {type: ticks, "any"} (true state),
        ``interventions`` {check: ticks, "any"} (of the ticks up), ``warnings`` {name: ticks}."""
        b, e = self.batch, self.e
        iv = b.interventions
        interventions = {c: int(v[e] - iv.down_counts[c][e]) for c, v in iv.counts.items()}
        interventions["any"] = int(iv.any[e] - iv.down_any[e])
        return {
            "ticks": iv.ticks - int(iv.down_ticks[e]),
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

    def _pushable(self, start: float) -> bool:
        """Whether a push starting at ``start`` (s) may land: the env RUNNING now, and its last
        operator reset (a legged robot's stand-up) at least the schedule's ``warmup`` before
        ``start``, the quiet time a session begins with (the training stacks wait after a
        reset before their next push, :mod:`sim2real.eval.world.pushes`)."""
        if int(self.batch.rt.mode[self.e]) != Mode.RUNNING:
            return False
        resets = [x["reset_s"] for x in self.latches if x["reset_s"] is not None]
        return not resets or start - resets[-1] >= self.config.ranges.faults.warmup

    def _skip(self, fault, mode: str) -> None:
        """Record a push not applied (:meth:`_pushable`) in ``skipped_pushes``, apart from the
        injected faults, and move on to the next fault."""
        self.skipped_pushes.append(
            {
                "start_s": fault.start,
                "magnitude": fault.magnitude,
                "mode": mode,
                "reason": "not_running" if mode != "RUNNING" else "after_reset",
            }
        )
        self.fault_index += 1
        self.next_fault_tick = self._arm_tick(self.fault_index, self.batch.dt)

    def fault_step(self, ticks: int) -> None:
        """Arm the next fault, or judge the armed one (at its supervision tick)."""
        batch, e = self.batch, self.e
        rt, dt = batch.rt, batch.dt
        if not self.fault_armed:
            fault = self.schedule[self.fault_index]
            if FAULT_DRAWS.get(fault.kind).only_while_running and not self._pushable(fault.start):
                self._skip(fault, Mode(int(rt.mode[e])).name)
                return
            batch.faults.arm(e, [fault])
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
        """The session's checkpoint: ``(arrays, meta)`` for
        :func:`sim2real.eval.soak.checkpoint.write_checkpoint`
        (the runtime's, goals', thermal accumulators', monitors' and armed injector's state of env
        ``e``; the book-keeping, options, policy digest and randomization as JSON metadata)."""
        rt, e, b = self.batch.rt, self.e, self.batch
        state = rt.state_dict(e)  # the runtime and its stages, the plant and policy included
        parts = self.task.parts() | {
            "stats": b.stats,
            "violations": b.violations,
            "interventions": b.interventions,
        }
        state.update(parts_state_dict(parts | ckpt.optional_stages(b), e))
        if self.fault_armed:
            state.update(prefixed("injector", b.faults.armed[e].state_dict()))
        meta = {
            "tick": rt.ticks,
            "session": {
                "fault_index": self.fault_index,
                "fault_armed": self.fault_armed,
                "fault_snapshot": self.fault_snapshot,
                "fault_events": self.fault_events,
                "skipped_pushes": self.skipped_pushes,
                "next_fault_tick": self.next_fault_tick,
                "latches": self.latches,
                "operator_resets": self.operator_resets,
                "stood_up": self.stood_up,
                "latched_since": self.latched_since,
                "faulted": bool(b.faulted[e]),
                "hours": self.hours,
                "hour_base": self.hour_base,
                "curve": self.curve,
                "friction": self.friction,
                "wall_s": self.wall_s + b.wall_elapsed(),
                "push_times": b.pushes.times[e] if b.pushes is not None else None,
                "push_next": (
                    [int(b.pushes.index[e]), int(b.pushes.next_tick[e])]
                    if b.pushes is not None
                    else None
                ),
                "push_force": (
                    {
                        "wrench": b.pushes.wrench[e].tolist(),
                        "until": int(b.pushes.until[e]),
                        "last_tick": int(b.pushes.last_tick[e]),
                        "running": bool(b.pushes.running[e]),
                        "response": b.push_response.state_dict(e),
                    }
                    if b.pushes is not None
                    else None
                ),
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
        """Continue from a checkpoint made by :meth:`capture` (``where``: its file, for messages).

        Raises:
            sim2real.eval.soak.checkpoint.CheckpointError: the checkpoint was made with other options (but
            the
                policy path and checkpoint interval), another policy file, or another
                randomization; or an array does not fit (named).
        """
        b, e = self.batch, self.e
        differs = option_difference(meta.get("config", {}), self.config.batch_key())
        if differs is not None:
            key, old, new = differs
            raise ckpt.CheckpointError(
                f"{where}: the checkpoint was made with {key} = {old!r}, this run has {new!r}; "
                f"resume with the options of the interrupted campaign"
            )
        if meta.get("policy_sha256") != b.policy_sha256:
            raise ckpt.CheckpointError(
                f"{where}: the checkpoint was made with another policy file (SHA-256 "
                f"{meta.get('policy_sha256')}); this run's {self.config.policy} differs"
            )
        if meta.get("randomization") != self.draw.to_dict():
            raise ckpt.CheckpointError(
                f"{where}: the randomization stored in the checkpoint differs from the one drawn "
                f"for seed {self.config.seed} (another version of sim2real.eval.world.session_draw?)"
            )
        ckpt.load_stage(b.rt, arrays, e, where)
        for prefix, part in self.task.parts().items():
            ckpt.load_stage(part, arrays, e, where, prefix)
        ckpt.load_stage(b.stats, arrays, e, where, "stats")
        ckpt.load_stage(b.violations, arrays, e, where, "violations")
        ckpt.load_stage(b.interventions, arrays, e, where, "interventions")
        for prefix, part in ckpt.optional_stages(b).items():
            ckpt.load_stage(part, arrays, e, where, prefix)
        s = meta["session"]
        self.fault_index = int(s["fault_index"])
        self.fault_armed = bool(s["fault_armed"])
        self.fault_snapshot = s["fault_snapshot"]
        self.fault_events = s["fault_events"]
        self.skipped_pushes = s.get("skipped_pushes", [])
        self.next_fault_tick = s["next_fault_tick"]
        if self.fault_armed:
            inj = b.faults.arm(e, [self.schedule[self.fault_index]])
            ckpt.load_stage(inj, arrays, None, where, "injector")
        self.latches = s["latches"]
        self.operator_resets = int(s["operator_resets"])
        self.stood_up = int(s.get("stood_up", 0))
        self.latched_since = float(s["latched_since"])
        b.faulted[e] = bool(s["faulted"])
        self.hours = s["hours"]
        self.hour_base = s["hour_base"]
        self.curve = s["curve"]
        self.friction = s["friction"]
        self.wall_s = float(s["wall_s"])
        if b.pushes is not None:
            b.pushes.times[e] = [float(t) for t in s.get("push_times") or []]
            if s.get("push_next") is not None:  # the next push of a random interval
                b.pushes.index[e], b.pushes.next_tick[e] = s["push_next"]
            force = s.get("push_force")
            if force is not None:  # a push's force in force, the second after a push judged
                b.pushes.wrench[e] = force["wrench"]
                b.pushes.until[e] = force["until"]
                b.pushes.last_tick[e] = force["last_tick"]
                # before the wait restarted at a reset: taken as RUNNING (DomainPushes.running)
                b.pushes.running[e] = bool(force.get("running", True))
                b.push_response.load_state_dict(force["response"], e)
