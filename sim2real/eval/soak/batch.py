"""The batched runner: several soak sessions stepped together in one plant and one runtime.

Batching: one :class:`~sim2real.deploy.backends.sim.plant.SimBackend` with ``envs = k`` (one randomized
``MjModel`` per env) and one :class:`~sim2real.deploy.runtime.Runtime` over all of them. A session's seeded
quantities (randomization, encoder noise and dropout, goals or commands, faults, operator resets)
depend on its own seed only, one stream per env. Every stage computes each env on its own except
Ruckig, which serves the batch and, when it resamples an unchanged trajectory instead of
recalculating it, differs at ~1e-16; the harness calls
:meth:`~sim2real.deploy.smoothing.CommandSmoother.recalculate` after every tick, so a session's result is
the same bit for bit alone or batched with any others. The plant and its randomized models are
built by :func:`sim2real.eval.soak.batch_plant.build_plant`.

Checkpoints: every ``checkpoint_minutes`` of simulated time each session writes its complete state
(:mod:`sim2real.eval.soak.checkpoint`) to ``OUT/sessions/<id>/``; ``resume=True`` continues from there and
the finished session equals an uninterrupted run bit for bit.

After every tick a :class:`~sim2real.deploy.monitors.violations.ViolationMonitor` counts the true-state
violations and an :class:`~sim2real.deploy.monitors.interventions.InterventionMonitor` the changed
commands (before the task, so a goal's last tick counts for it); both are reported apart, per hour
and on the curves. The task is :func:`sim2real.deploy.tasks.task.task_for`'s: reach goals, or for a legged
robot (:func:`sim2real.deploy.robot_kind.robot_kind`) velocity commands every ``command_period`` s
(:attr:`~sim2real.eval.soak.session.SessionConfig.command_period`) with their tracking, distance
and falls; a legged session also draws its IMU noise and floor friction, gets no cable pulls,
and its operator resets stand the robot up first (:meth:`SessionBatch.stand_up`).

Divergence: MuJoCo's (:class:`~sim2real.deploy.backends.sim.plant.SimulationDivergedError`) ends the
session that diverged (:exc:`BatchDiverged`); the others continue from their last checkpoints
(:func:`sim2real.eval.soak.executors.run_sessions`).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from sim2real.deploy.core.modes import Mode
from sim2real.deploy.kinds import robot_kind
from sim2real.deploy.tasks.task import follows_velocity_commands
from sim2real.eval.soak import checkpoint as ckpt
from sim2real.eval.soak.batch_plant import build_plant
from sim2real.eval.soak.batch_stats import BatchStats
from sim2real.eval.soak.batch_tick import BatchTick
from sim2real.eval.soak.camera_faults import attach_session_cameras
from sim2real.eval.soak.camera_verdict import CameraVerdict
from sim2real.eval.soak.curriculum_walk import CurriculumWalk
from sim2real.eval.soak.exhibition import exhibition_task
from sim2real.eval.soak.faults import SessionFaults
from sim2real.eval.soak.push_response import PushResponse
from sim2real.eval.soak.result import session_result
from sim2real.eval.soak.session import (
    SESSIONS_DIR,
    Session,
    SessionConfig,
    SessionError,
    session_dir,
)
from sim2real.eval.soak.soak_faces import OPERATOR_OF_KIND
from sim2real.eval.soak.terrain_figures import TerrainFigures
from sim2real.eval.world.drift import apply_drift, joint_dofs
from sim2real.eval.world.pushes import DomainPushes
from sim2real.eval.world.session_draw import sample_session, session_rng
from sim2real.eval.world.world_faces import WORLD_OF_KIND
from sim2real.robots.errors import Sim2RealError
from sim2real.robots.files import atomic_write, sha256_file

os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

#: s between the harness's supervision steps (latches, operator resets, fault arming, curves).
SUPERVISE_PERIOD = 0.1
#: s between updates of the drifting friction.
DRIFT_PERIOD = 10.0
#: s of simulated time between progress reports.
PROGRESS_PERIOD = 10.0


def _ticks(seconds: float, dt: float) -> int:
    return max(int(round(seconds / dt)), 1)


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
        recorders: Recorders that watch the batch, each a class built as ``recorder(batch)``
            (a campaign's workers receive it by name) with ``supervise(runtime)``,
            ``checkpointed()`` and ``finish()`` (:class:`sim2real.eval.film.strip.FilmRecorder`).
        replay_stops: A floating-base robot's hard-limit stops are replayed without the stop
            (:class:`sim2real.eval.soak.counterfactual.StopReplay`) and its falls in the policy's
            own loop and with other noise (:class:`sim2real.eval.soak.fall_replay.FallReplay`),
            so each fall says whether the robot was falling anyway. False in the replays' copy.

    Raises:
        SessionError: sessions with different options, or duplicate seeds.
        ValueError: unreadable robot or policy (``RobotSpecError``, ``PolicyLoadError``).
        sim2real.eval.soak.checkpoint.CheckpointError: a checkpoint that cannot be read or does not fit.
    """

    def __init__(
        self,
        configs: list[SessionConfig],
        out: str | os.PathLike,
        resume: bool = False,
        progress: bool = True,
        on_progress=None,
        recorders: tuple = (),
        replay_stops: bool = True,
    ):
        from sim2real.deploy.rig.rig import Rig
        from sim2real.robots import load_robot

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
        self.out, self.write_progress, self.on_progress = Path(out), progress, on_progress
        from sim2real.deploy.spec.drive import drive_robot

        robot = load_robot(first.robot)
        self.policy = first.load_policy(robot)
        # the plant runs the policy's PD gains and default pose (a policy trained elsewhere)
        robot = self.robot = drive_robot(robot, self.policy.spec)[0]
        self.policy_sha256 = sha256_file(first.policy)
        self.mode = mode = self.policy.spec.action.mode
        self.dt = dt = robot.control_period
        k = len(configs)
        draws = [sample_session(robot, c.seed, c.duration, c.ranges, c.faults) for c in configs]
        self.kind = robot_kind(robot)
        backend, models = build_plant(robot, mode, configs, draws)
        self.backend = backend
        dofs = joint_dofs(models[0], robot)
        self.initial_friction = np.stack([m.dof_frictionloss[dofs].copy() for m in models])
        #: the pushes of the policy's training domain (legged_gym's push_robots), or None
        pushes = WORLD_OF_KIND.get(self.kind).domain_pushes(first.ranges)
        self.pushes = None if pushes is None else DomainPushes(seeds, pushes, dt)
        #: the base estimate in the second after each push, against the truth (None: no pushes)
        self.push_response = None if pushes is None else PushResponse(self.pushes, dt)
        # a fault's push or cable pull adds to a domain push's force in force (not replaces it)
        forces = self.pushes.wrench[:, :3] if self.pushes is not None else None
        self.faults = SessionFaults(backend, base_forces=forces)
        # the runtime, then its monitors and task (one stream per session): the soak's order
        commands = follows_velocity_commands(robot)  # a command's period, else a goal's
        task = {
            "period": first.command_period if commands else first.goal_period,
            "rng": [session_rng(c.seed, "goals") for c in configs],
            "success_time": first.success_time,
            "window": first.window_minutes * 60.0,
            "ranges": first.ranges.commands,
        }
        exhibition_task(task, self.policy, robot, k, first)  # a tracking policy's dance
        # a camera policy: the plant's camera, each session's camera faults drawn from its seed
        self.camera = attach_session_cameras(backend, self.policy.spec, configs)
        self.rig = Rig(
            robot, self.policy, backend, envs=k, task=task, runtime={"injector": self.faults},
            start=True,
        )  # fmt: skip
        self.rig.add(BatchTick(self))  # the batch's bookkeeping, after the monitors and task
        self.rt, self.task = self.rig.runtime, self.rig.task
        if self.camera is not None:  # a task scene's marker at the sessions' goals
            self.camera.show_goal(self.rt.goal)
        self.violations, self.interventions = self.rig.violations, self.rig.interventions
        #: a legged robot's base estimate against the plant's truth (None for an arm)
        self.estimation = self.rig.estimation
        self.terrain_figures = TerrainFigures.of_batch(draws, self.task, dt)  # None: no terrain
        #: a curriculum walk on terrain (None: none); a replay's copy keeps its episodes' state
        #: but respawns no timed-out robot (a respawn would end the replay's own loop early)
        self.curriculum = CurriculumWalk.of_batch(
            draws, self.terrain_figures, getattr(backend, "grounds", None), dt,
            [session_rng(c.seed, "curriculum_walk") for c in configs],
        )  # fmt: skip
        self.curriculum_respawns = replay_stops

        #: the thermal and speed accumulators, a stage of the checkpoints; their arrays (envs, n)
        #: are the batch's too: winding peak, window peak, band and over ticks, speed peak (rad/s)
        self.stats = BatchStats(backend, robot)
        self.peak, self.window_peak = self.stats.peak, self.stats.window_peak
        self.band_ticks, self.over_ticks = self.stats.band_ticks, self.stats.over_ticks
        self.speed_peak = self.stats.speed_peak
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
        self.sessions = [
            Session(self, e, c, d) for e, (c, d) in enumerate(zip(configs, draws, strict=True))
        ]
        #: a camera policy's: what each session's camera faults did (None without a camera)
        self.camera_verdict = CameraVerdict.of_batch(self)
        self._next_event = self.every
        self._ruckig = mode != "torque"
        #: what the operator does with a robot of this kind (a legged one: stands it up)
        self.operator = OPERATOR_OF_KIND.get(self.kind)
        self.stop_replay = self.fall_replay = None
        if replay_stops:  # a legged robot's: its every stop lays it down
            self.stop_replay, self.fall_replay = self.operator.replays(self)
        self._wall0 = time.perf_counter()
        if resume:
            self._resume()
        self.recorders = [recorder(self) for recorder in recorders]

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
        for s, d, (arrays, meta) in have:
            s.restore(arrays, meta, d / ckpt.MANIFEST)
        self._align_events(m0)

    def _align_events(self, meta: dict) -> None:
        """The supervision's next ticks from a capture's ``meta``, after its restore."""
        self.next_ticks = {k: int(v) for k, v in meta["next"].items()}
        self._next_event = (self.rt.ticks // self.every + 1) * self.every
        self._wall0 = time.perf_counter()

    def restore(self, arrays: dict, meta: dict, where) -> None:
        """Continue a one-session batch from its session's :meth:`Session.capture
        <sim2real.eval.soak.session.Session.capture>` (a checkpoint's content, in memory; ``where`` names
        it in messages). The batch then repeats the captured session tick for tick.

        Raises:
            sim2real.eval.soak.checkpoint.CheckpointError: the capture does not fit (see
                :meth:`Session.restore <sim2real.eval.soak.session.Session.restore>`).
            SessionError: the batch has more than one session.
        """
        if len(self.sessions) != 1:
            raise SessionError(
                f"restore: expected a batch of one session, got {len(self.sessions)}"
            )
        self.sessions[0].restore(arrays, meta, where)
        self._align_events(meta)

    def checkpoint(self) -> None:
        """Write every session's checkpoint (atomically, see :mod:`sim2real.eval.soak.checkpoint`)."""
        for s in self.sessions:
            arrays, meta = s.capture()
            ckpt.write_checkpoint(session_dir(self.out, s.config.seed), arrays, meta)

    # ------------------------------------------------------------------ per tick
    def on_tick(self, rt) -> bool:
        """``Rig.after_tick`` (the monitors, the task, then the hook :meth:`bookkeeping`) after
        each tick; what :meth:`run` passes to ``Runtime.run(on_tick=...)``, a replay too."""
        return self.rig.after_tick(rt)

    def bookkeeping(self, rt) -> None:
        """The batch's per-tick work after the rig's (peaks, pushes, supervision, replays)."""
        if self._ruckig:
            # the next step recalculates every trajectory from its input, in every env: the same
            # numbers whatever the neighbours (see the module docstring) and across a restore
            rt.smoother.recalculate()
        if self.pushes is not None:  # the estimate judged against the truth its frame sampled
            self.push_response(rt, self.backend)
            self.pushes(rt, self.backend)
        self.stats.update(self.backend)
        if rt.ticks >= self._next_event:
            self._supervise(rt)
        if self.stop_replay is not None:  # last: a capture must hold this whole tick
            self.stop_replay(rt)
            self.fall_replay(rt)

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
                self.operator.before_reset(self, due)  # a legged robot: stood up first
                if due.any():
                    rt.reset_faults(due)
                    for e in np.flatnonzero(due):
                        s = self.sessions[e]
                        s.operator_resets += 1
                        s.latches[-1]["reset_s"] = t
                    self.faulted[due] = False
        if self.camera_verdict is not None:
            self.camera_verdict.step(rt, t)
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
                self.task.curve_point(c, e)
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
        for recorder in self.recorders:
            recorder.supervise(rt)

    def stand_up(self, envs: np.ndarray, end: str = "stop") -> None:
        """A legged operator's reset, first part: put the robots of ``envs`` (bool mask) back on
        their feet, at rest at home at the start of the floor (``SimBackend.reset`` of those
        envs: the MJCF's standing pose), their motors as warm as they were, and restart them
        there (``Runtime.restart``: the estimators anchored at rest where the encoders read the
        joints, as an operator's restart on hardware can only be, the session's estimator counts
        kept, RAMP_IN). Anchored at the nominal home instead, a robot whose encoders read it with
        an offset (``[sensors] encoder_bias``) fell 3.3 s after every stand-up.

        On a curriculum walk (:mod:`sim2real.eval.soak.curriculum_walk`) the episode ends there
        (``end``: ``"stop"``, an operator's reset after a stop, or ``"timeout"``): its level moves by
        legged_gym's rule, the robot is put on its new level's tile instead of the start, and
        its command schedule draws a new command at once (legged_gym's ``reset_idx``)."""
        b = self.backend
        walk = self.curriculum
        offsets = None
        if walk is not None:
            offsets = walk.end_episodes(envs, b, self.rt.velocity_command, end)
        th = b.thermal
        winding = th.winding_temperature[envs].copy()
        housing = th.housing_temperature[envs].copy()
        reading = b.frame.winding_temperature[envs].copy()
        if offsets is None:
            b.reset(envs=envs)
        else:
            b.reset(envs=envs, base_offset=offsets)
        th.winding_temperature[envs] = winding
        th.housing_temperature[envs] = housing
        b.frame.winding_temperature[envs] = reading
        # the runtime restarts them there (estimators anchored at rest where the encoders read
        # the joints, a lost reading at home; counts kept; RAMP_IN)
        read = b.read().position
        anchor = np.broadcast_to(self.robot.home, read.shape).copy()
        anchor[envs] = np.where(np.isfinite(read[envs]), read[envs], anchor[envs])
        self.rt.restart(envs, anchor, b.frame.time)
        if self.terrain_figures is not None:  # put down by hand: anchored there, no crossing
            self.terrain_figures.carried(envs, b)
        schedule = getattr(self.task, "schedule", None)
        if walk is not None and schedule is not None:
            schedule.resample(envs)

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
        from sim2real.deploy.backends.sim.plant import SimulationDivergedError

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
                for recorder in self.recorders:
                    recorder.checkpointed()
        for recorder in self.recorders:
            recorder.finish()
        results = [session_result(s) for s in self.sessions]
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
            atomic_write(d / "result.json", json.dumps(session_result(s)))
            seeds.append(s.config.seed)
        raise BatchDiverged(seeds, str(exc)) from exc
