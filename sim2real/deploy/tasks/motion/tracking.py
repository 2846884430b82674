"""The motion-tracking task: the clip a whole-body tracking policy is commanded by, and how well
the robot followed it.

:class:`TrackingTask` (a :class:`~sim2real.deploy.tasks.task.Task`, registered as ``tracking``)
owns the :class:`~sim2real.deploy.tasks.motion.clock.MotionClock` and writes, after every tick,
the next tick's reference into ``RobotState.motion`` (the blocks of
:mod:`sim2real.deploy.spec.motion_blocks` read it):

- before the robot is RUNNING (RAMP_IN to the home pose), the clip's first frame, yaw-aligned to
  the robot as it stands now (rl_sar's ``Reset`` on entering its tracking state);
- on the first RUNNING tick the clip starts (that tick read its time 0), or ``start_after`` s of
  RUNNING later (the policy reads the first frame meanwhile, at rest: zero joint velocity, as
  holosoma_inference pins the clip at its first step until the operator starts it), aligned
  again to the robot then (a stand-up's RAMP_IN ends on its first tick); each RUNNING tick
  moves it one control period on; at its end the clock's playback (``stand``: a transition to
  home, then home; ``once``: the last frame);
- a stop (a fall, the operator) ends the play: the next RUNNING starts the clip again.

Each play is logged (:attr:`TrackingTask.play_log`; checkpointed with the figures, the part
``figures``): its share completed, whether a stop ended it, its errors, the guard's interventions.
The reference's own self-contacts (:mod:`~sim2real.deploy.tasks.motion.self_contact`) are screened
once; :meth:`TrackingTask.reference_contacts` tells the violation monitor which pairs it touches.

Judged while the clip plays (not while its last frame holds), on the plant's truth in simulation
(the estimate on hardware, the IMU's own attitude for the anchor where it sends one): joint-angle
error (rad RMS) per body group (legs, waist, arms: by the joint's name), the anchor's orientation
error (deg, the torso of the true base and joint angles against the aligned reference), the bodies'
position error (MPJPE, mm, root-relative: both poses' forward kinematics with the base at the
origin, Pinocchio; the bodies the joints move), the share of the clip completed; falls by the
velocity tracker (a zero command).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.attitude import yaw_of
from sim2real.deploy.core.modes import RUNNING
from sim2real.deploy.spec.motion_blocks import (
    anchor_base_orientation,
    axis_quat,
    quat_conj,
    quat_mul,
    torso_quat,
)
from sim2real.deploy.tasks.motion.clock import MotionClock
from sim2real.deploy.tasks.motion.pose_error import BodyPositions, body_groups
from sim2real.deploy.tasks.motion.self_contact import clip_self_contacts
from sim2real.deploy.tasks.motion.tracking_figures import TrackingFigures
from sim2real.deploy.tasks.motion.travel import ClipTravel
from sim2real.deploy.tasks.velocity import VelocityTask


class TrackingTask:
    """The ``tracking`` task of ``envs`` legged robots (module docstring).

    Args:
        robot: The robot. envs: Batch size. backend: The runtime's backend (its truth judges).
        clock: The :class:`MotionClock` (the clip in the robot's joint order).
        waist: Robot joint indices of the waist's yaw, roll and pitch (the anchor block's).
        interventions: Optional :class:`~sim2real.deploy.monitors.interventions.InterventionMonitor`
            (its ``any`` and ``safety`` ticks are counted per play).
        start_after: s of RUNNING before the clip starts (module docstring; >= 0).

    Attributes:
        motion: The :class:`MotionClock`. velocity: The :class:`VelocityTask` (zero command)
            whose tracker counts the falls. progress: (envs,) s, the farthest clip time reached.
        sq_error: (envs, n) rad^2, squared joint-angle error summed over the playing ticks;
            anchor_sum: (envs,) deg, anchor error summed; anchor_max: (envs,) deg; ticks:
            (envs,) playing ticks judged. heading: (envs,) rad, the true base yaw less the
            sensed one (the anchor's source) when the clip was last aligned (the anchor is
            judged against the clip turned by it: that heading's error then is not the
            policy's).
        contacts: The reference's self-contacts
            (:class:`~sim2real.deploy.tasks.motion.self_contact.ClipContacts`).
        play_log: per env, a list of ended plays: ``completed`` (share of the clip),
            ``stopped`` (a stop ended it), ``joint_rms_rad``, ``anchor_error_deg_mean``,
            ``mpjpe_mm`` (None for a play with no judged tick), ``ticks``, ``interventions`` and
            ``safety_interventions`` (ticks, while the clip and its transition played),
            ``rest_interventions`` and ``rest_safety_interventions`` (after them, until the play
            was logged: an exhibition's rest), ``hard_limit_ticks`` and ``violation_ticks``
            (true state, the rig's monitor: :meth:`watch_violations`; 0 without it) and the
            rest's ``rest_hard_limit_ticks``, ``rest_violation_ticks``, ``travel`` (the base
            against the clip's root path: :meth:`ClipTravel.figures
            <sim2real.deploy.tasks.motion.travel.ClipTravel.figures>`), ``end_s`` and its heat
            (``hottest``, ``hottest_c``, ``derating``). A play the run's end cut short is no
            entry of it: :meth:`plays` adds it (``unfinished``).
    """

    name = "tracking"

    def __init__(
        self, robot, envs: int, backend, clock: MotionClock, waist, interventions=None,
        start_after: float = 0.0,
    ):  # fmt: skip
        if not (np.isfinite(start_after) and start_after >= 0.0):
            raise ValueError(f"motion start after {start_after!r} s: expected a time >= 0")
        self.robot, self.envs, self.motion = robot, envs, clock
        self.start_after = float(start_after)
        self.waited = np.zeros(envs)  # s of RUNNING before the clip started
        self.interventions = interventions
        self.contacts = clip_self_contacts(robot, clock.reference_poses(), clock.clip.fps)
        self.play_log: list[list[dict]] = [[] for _ in range(envs)]
        self._clock_now = 0.0  # s, the runtime's time at the last tick
        # this play's sq error, ticks, any, safety, anchor, mpjpe; the rest's any, safety; the
        # play's true-state hard-limit and any-violation ticks, then the rest's
        self._play = np.zeros((envs, 12))
        self._seen = np.zeros((envs, 2), dtype=np.int64)  # interventions any, safety last tick
        self._vseen = np.zeros((envs, 2), dtype=np.int64)  # violations hard_limit, any last tick
        self.violations = None  # the rig's true-state violation monitor (watch_violations)
        #: (envs, 3) after the clip's end (its hold, or the policy handed over to), RUNNING:
        #: guard intervention ticks, true-state hard-limit ticks, ticks with any violation
        self.after_counts = np.zeros((envs, 3), dtype=np.int64)
        self._thermal = getattr(backend, "thermal", None)
        self._peak = np.full((envs, robot.n_joints), -np.inf)  # this play's winding peak, degC
        self._derate = np.array([m.derating_start_temperature for m in robot.motors])
        self.dt = robot.control_period
        self.waist = np.asarray(waist, dtype=np.intp)
        self.velocity = VelocityTask(envs, self.dt, backend, 1.0, None, np.zeros(3))
        self.truth = getattr(backend, "true_base_state", None)
        self.true_q = getattr(backend, "true_position", None)
        self.groups = body_groups(robot.joint_names)
        n = robot.n_joints
        self.progress = np.zeros(envs)
        self.sq_error = np.zeros((envs, n))
        self.anchor_sum = np.zeros(envs)
        self.anchor_max = np.zeros(envs)
        self.ticks = np.zeros(envs, dtype=np.int64)
        self.mpjpe_sum = np.zeros(envs)
        self.heading = np.zeros(envs)
        self.travel = ClipTravel(clock, envs)
        #: (envs,) bool: the clip is over and the robot handed to another policy
        #: (:meth:`hand_over`): the clip does not start again
        self.handed_over = np.zeros(envs, dtype=bool)
        #: what follows the clip, as the run decided it (:meth:`follows`)
        self.after: dict = {"follows": clock.playback}
        self.bodies = BodyPositions(robot)

    def _buffer(self, runtime) -> np.ndarray:
        state = runtime.state
        if state.motion is None:
            state.motion = np.zeros((self.envs, 2 * self.robot.n_joints + 4))
        return state.motion

    def reset(self, runtime, envs: np.ndarray) -> None:
        """The zero velocity command; the clip's first frame aligned to the robots of ``envs``."""
        self.velocity.reset(runtime, envs)
        self.motion.stop(envs)
        self._align(runtime, envs)

    def _align(self, runtime, envs: np.ndarray) -> None:
        state = runtime.state
        self.motion.align(envs, anchor_base_orientation(state), state.q[:, self.waist])
        self._true_heading(state, envs)
        self.motion.write(self._buffer(runtime), envs)

    def _true_heading(self, state, envs: np.ndarray) -> None:
        """Note, for the envs of ``envs`` just aligned, the truth's base yaw less the sensed one
        (rad; 0 without a truth): the clip was aligned to the heading the anchor reads (the
        IMU's own or the estimate's: :func:`anchor_base_orientation`), and is judged turned by
        it against the true robot (:meth:`_judge`), so that that heading's error at the
        alignment is not counted as the policy's anchor error."""
        if self.truth is None:
            return
        e = np.flatnonzero(envs)
        turn = yaw_of(self.truth()[e, 3:7]) - yaw_of(anchor_base_orientation(state)[e])
        self.heading[e] = np.angle(np.exp(1j * turn))

    def follows(self, follows: str, policy: str | None = None, blend_s: float = 0.0) -> None:
        """Say what follows the clip (the summary's): ``handover`` to ``policy`` (blended over
        ``blend_s`` s), else the playback's hold."""
        self.after = {"follows": follows, "policy": policy, "blend_s": blend_s}

    def hand_over(self, envs: np.ndarray) -> None:
        """The envs of ``envs`` (bool) are handed to another policy at their clip's end: their
        clip does not start again (a stop and a new RUNNING run that policy)."""
        self.handed_over |= np.asarray(envs, dtype=bool)

    def __call__(self, runtime, truth: np.ndarray | None = None) -> None:
        """One tick (module docstring): judge the tick that ran, then write the next one's."""
        self.velocity(runtime, truth)
        self._clock_now = runtime.time
        truth = None if self.truth is None else self.truth()
        self.travel.locate(truth, runtime.state.base, self.dt)
        running = runtime.mode == RUNNING
        clock = self.motion
        playing = ~np.isnan(clock.time)
        first = running & ~playing & ~self.handed_over
        if first.any() and self.start_after > 0.0:
            first &= self.waited >= self.start_after - 0.5 * self.dt
            self.waited[running & ~playing] += self.dt
        if first.any():
            # aligned to the robot as it stands now (rl_sar's Reset on entering its state): a
            # RAMP_IN that ends on its first tick (an operator's stand-up puts the robot at home,
            # at rest) leaves no idle tick after the stand-up, and the last alignment was the
            # robot's lying on the floor before it (a clip turned by that heading fell < 1.4 s in)
            self._align(runtime, first)
            clock.start(first)  # this tick read the first frame: it was time 0
            self.travel.begin(first)
        playing = running & ~np.isnan(clock.time)
        if playing.any():
            clip = playing & (np.nan_to_num(clock.time, nan=np.inf) < clock.length)
            self._judge(runtime, clip)  # the clip, not its last frame held
            clock.advance(self.dt, playing)
            self.travel.reach(clock.time, playing)
            if clock.restarted.any():  # an exhibition's next play: aligned as at its start
                state = runtime.state
                base = anchor_base_orientation(state)
                clock.align(clock.restarted, base, state.q[:, self.waist])
                self._true_heading(state, clock.restarted)
            now = np.where(playing, np.minimum(clock.time, clock.length), 0.0)
            np.maximum(self.progress, now, out=self.progress)
            clock.write(self._buffer(runtime), playing)
        with np.errstate(invalid="ignore"):
            clip = playing & (clock.time <= clock.total)
            after = running & (clock.time >= clock.length)
            self._count_interventions(clip, playing & ~clip, after)
        if clock.playback in ("loop", "exhibition"):  # logged with its rest, at the restart
            ended = clock.restarted & (self._play[:, 1] > 0)
        else:
            ended = playing & (clock.time >= clock.total) & (self._play[:, 1] > 0)
        self._heat(playing)
        stopped = ~running & ~np.isnan(clock.time)
        for e in np.flatnonzero(ended | stopped):
            self._log_play(e, bool(stopped[e]))
        if clock.restarted.any():  # the next play's root path laid from here
            self.travel.begin(clock.restarted)
        if stopped.any():
            clock.stop(stopped)
        idle = ~running
        if idle.any():
            self.waited[idle] = 0.0
            self._align(runtime, idle)
        if self.start_after > 0.0:
            self._pin(runtime, running & np.isnan(clock.time) & ~self.handed_over)

    def _pin(self, runtime, pinned: np.ndarray) -> None:
        """A clip pinned at its first frame (``start_after``) stands still: zero joint velocity,
        but on the tick it starts (the frame's own, as rl_sar's first tick). gangnam_style's
        rows 0-1 jump 26 rad/s: held for the wait, that threw the G1 over within 1.5 s."""
        if not pinned.any():
            return
        buffer = self._buffer(runtime)
        self.motion.write(buffer, pinned)
        held = pinned & (self.waited < self.start_after - 0.5 * self.dt)
        n = self.robot.n_joints
        buffer[held, n : 2 * n] = 0.0

    def _judge(self, runtime, envs: np.ndarray) -> None:
        """Add this tick's errors of the envs of ``envs`` against the reference it read."""
        state, n = runtime.state, self.robot.n_joints
        ref = state.motion
        q = state.q
        if self.true_q is not None:
            q = self.true_q()
        quat = anchor_base_orientation(state) if self.truth is None else self.truth()[:, 3:7]
        torso = torso_quat(quat, q[:, self.waist])
        anchor = quat_mul(axis_quat(2, self.heading), ref[:, 2 * n : 2 * n + 4])
        rel = quat_mul(quat_conj(torso), anchor)
        angle = np.degrees(2.0 * np.arccos(np.clip(np.abs(rel[:, 0]), 0.0, 1.0)))
        e = np.flatnonzero(envs)
        if not len(e):
            return
        self.sq_error[e] += (q[e] - ref[e, :n]) ** 2
        self.anchor_sum[e] += angle[e]
        np.maximum(self.anchor_max, np.where(envs, angle, 0.0), out=self.anchor_max)
        self.ticks[e] += 1
        self._play[e, 0] += ((q[e] - ref[e, :n]) ** 2).sum(axis=1)
        self._play[e, 1] += 1
        self._play[e, 4] += angle[e]
        for k in e:
            mm = 1000.0 * self.bodies.mpjpe(ref[k, :n], q[k])
            self.mpjpe_sum[k] += mm
            self._play[k, 5] += mm

    def _heat(self, playing: np.ndarray) -> None:
        """Keep each playing env's hottest winding of this play (the plant's thermal model)."""
        if self._thermal is None:
            return
        hot = np.where(playing[:, None], self._thermal.winding_temperature, -np.inf)
        np.maximum(self._peak, hot, out=self._peak)

    def watch_violations(self, monitor) -> None:
        """Count ``monitor``'s (a :class:`~sim2real.deploy.monitors.violations.ViolationMonitor`,
        updated before this task each tick) hard-limit and any-violation ticks per play, the
        clip's apart from its rest's, and after the clip."""
        self.violations = monitor
        self._vseen[:] = np.stack([monitor.counts["hard_limit"], monitor.any], axis=1)

    def _count_interventions(self, playing: np.ndarray, rest: np.ndarray, after) -> None:
        """Add the guard's interventions and the true-state violations of this tick to each
        playing env's play (the clip and its transition), or to its rest after them (``rest``),
        and to the ticks after the clip's end (``after``)."""
        iv, v = self.interventions, self.violations
        if iv is not None:
            now = np.stack([iv.any, iv.safety], axis=1)
            step = now - self._seen
            self._play[:, 2:4] += np.where(playing[:, None], step, 0)
            self._play[:, 6:8] += np.where(rest[:, None], step, 0)
            self.after_counts[:, 0] += np.where(after, step[:, 0], 0)
            self._seen[:] = now
        if v is not None:
            now = np.stack([v.counts["hard_limit"], v.any], axis=1)
            step = now - self._vseen
            self._play[:, 8:10] += np.where(playing[:, None], step, 0)
            self._play[:, 10:12] += np.where(rest[:, None], step, 0)
            self.after_counts[:, 1:3] += np.where(after[:, None], step, 0)
            self._vseen[:] = now

    def _log_play(self, e: int, stopped: bool) -> None:
        """Close env ``e``'s play into :attr:`play_log` and start a new one."""
        self.play_log[e].append(self._play_entry(e, stopped, not stopped))
        self._play[e] = 0.0
        self._peak[e] = -np.inf

    def open_play(self, e: int) -> dict | None:
        """Env ``e``'s play still open when the run or session ends (the clip or its transition
        playing, a tick of it judged), as :attr:`play_log` logs a play with ``unfinished``
        True and ``completed`` the share of the clip reached; an exhibition's or a loop's play
        whose clip had ended (its rest under way: such a play is logged at the next start, with
        its rest) as a whole play with ``rest_cut_short`` True; None without one. Changes no
        state (a checkpoint taken after it resumes the same play)."""
        t = self.motion.time[e]
        if np.isnan(t) or self._play[e, 1] <= 0:
            return None
        if t >= self.motion.length:  # only an exhibition or a loop keeps a play open past it
            return {**self._play_entry(e, False, True), "rest_cut_short": True}
        return {**self._play_entry(e, False, False), "unfinished": True}

    def plays(self, e: int) -> list[dict]:
        """Env ``e``'s plays: :attr:`play_log`, then :meth:`open_play` if any."""
        open_ = self.open_play(e)
        return self.play_log[e] + ([] if open_ is None else [open_])

    def _play_entry(self, e: int, stopped: bool, whole: bool) -> dict:
        """Env ``e``'s play so far as :attr:`play_log` logs it; ``whole``: its clip played to
        the end (``completed`` 1), else the share its clock reached."""
        sq, ticks, any_, safety, anchor, mpjpe, rest_any, rest_safety = self._play[e, :8]
        hard, viol, rest_hard, rest_viol = (int(x) for x in self._play[e, 8:])
        t = self.motion.time[e]
        done = 1.0 if whole else min(float(np.nan_to_num(t)) / self.motion.length, 1.0)
        return {
            "completed": done, "stopped": stopped,
            "stopped_in_rest": bool(stopped and np.nan_to_num(t) >= self.motion.length),
            "joint_rms_rad": float(np.sqrt(sq / (ticks * self.robot.n_joints))) if ticks else None,
            "anchor_error_deg_mean": float(anchor / ticks) if ticks else None,
            "mpjpe_mm": float(mpjpe / ticks) if ticks else None,
            "ticks": int(ticks), "interventions": int(any_), "safety_interventions": int(safety),
            "rest_interventions": int(rest_any), "rest_safety_interventions": int(rest_safety),
            "hard_limit_ticks": hard, "violation_ticks": viol,
            "rest_hard_limit_ticks": rest_hard, "rest_violation_ticks": rest_viol,
            "end_s": float(self._clock_now), **self._play_heat(e),
            "travel": self.travel.figures(e),
        }  # fmt: skip

    def _play_heat(self, e: int) -> dict:
        """Env ``e``'s play: its hottest winding (degC) and the windings past their derating
        start (robot.toml's motors) during it."""
        if self._thermal is None or not np.isfinite(self._peak[e]).any():
            return {"hottest": None, "hottest_c": None, "derating": []}
        peak, names = self._peak[e], self.robot.joint_names
        k = int(np.argmax(peak))
        return {
            "hottest": names[k], "hottest_c": float(peak[k]),
            "derating": [names[i] for i in np.flatnonzero(peak >= self._derate)],
        }  # fmt: skip

    def _from_home(self) -> dict | None:
        """rad RMS of the joints now (truth in simulation) from the home pose over every env:
        ``all`` and per body group."""
        if self.true_q is None:
            return None
        sq = (self.true_q() - self.robot.home) ** 2
        out = {"all": float(np.sqrt(sq.mean()))}
        out.update({g: float(np.sqrt(sq[:, j].mean())) for g, j in self.groups.items()})
        return out

    @property
    def tracker(self):
        """The falls' :class:`~sim2real.deploy.tasks.locomotion.CommandTracker` (the soak's)."""
        return self.velocity.tracker

    schedule = None  #: no velocity command schedule (the soak's locomotion section)

    def reference_contacts(self, env: int) -> np.ndarray | None:
        """(pairs,) bool: the collision pairs the reference of env ``env`` touches within the
        contacts' window around its moment now (the violation monitor's pairs, in its order);
        None when no clip plays there (every contact is then the robot's)."""
        t = self.motion.time[env]
        if np.isnan(t):
            return None
        return self.contacts.allowed(self.motion.reference_index(float(t)))

    def success(self, env: int | None = None) -> float | None:
        """The share of the clip completed (of env ``env``, or the mean)."""
        share = self.progress / self.motion.length
        return float(share.mean() if env is None else share[env])

    def summary(self) -> dict:
        """``tracking``'s report entry (module docstring); errors over every env's playing
        ticks (None before any)."""
        ticks = int(self.ticks.sum())
        rms = {
            g: (float(np.sqrt(self.sq_error[:, j].sum() / (ticks * len(j)))) if ticks else None)
            for g, j in self.groups.items()
        }
        clip = self.motion.clip
        return {
            "clip": str(clip.source),
            "frames": clip.shown[0],  # as its stack states them (MotionClip.stated)
            "fps": clip.shown[1],
            "length_s": self.motion.length,
            "playback": self.motion.playback,
            "plays": int(self.motion.plays.sum()),
            "completed": self.success(),
            "ticks": ticks,
            "joint_rms_rad": rms,
            "joint_rms_rad_all": (
                float(np.sqrt(self.sq_error.sum() / (ticks * self.robot.n_joints)))
                if ticks
                else None
            ),
            "anchor_error_deg_mean": float(self.anchor_sum.sum() / ticks) if ticks else None,
            "anchor_error_deg_max": float(self.anchor_max.max()),
            "mpjpe_mm": float(self.mpjpe_sum.sum() / ticks) if ticks else None,
            "bodies": self.bodies.count,
            "judged_on": "plant truth" if self.truth is not None else "estimate",
            "stand_s": self.motion.stand_s if self.motion.home is not None else None,
            "end_from_home_rad_rms": self._from_home(),
            "reference_contacts": self.contacts.summary(),
            "plays_logged": [p for e in range(self.envs) for p in self.plays(e)],
            "after_clip": dict(self.after),
            "travel": self.travel_summary(),
        }

    def travel_summary(self) -> dict:
        """The base's travel against the clip's root path now, per env
        (:meth:`ClipTravel.figures <sim2real.deploy.tasks.motion.travel.ClipTravel.figures>`:
        ``envs``), the bounds, what judged it and ``off_path``: the envs beyond a bound."""
        return {
            **self.travel.summary(self.truth is not None),
            "after_clip_interventions": int(self.after_counts[:, 0].sum()),
            "after_clip_hard_limit_ticks": int(self.after_counts[:, 1].sum()),
            "after_clip_violation_ticks": int(self.after_counts[:, 2].sum()),
        }  # fmt: skip

    def report(self, runtime) -> dict:
        report = self.velocity.report(runtime)
        report["tracking"] = self.summary()
        return report

    def curve_start(self) -> dict[str, list]:
        return self.velocity.curve_start()

    def curve_point(self, curve: dict[str, list], e: int) -> None:
        self.velocity.curve_point(curve, e)

    def judged_arrays(self) -> dict[str, np.ndarray]:
        """The arrays of the judgement under way, by their state-dict name (the env axis first;
        :class:`~sim2real.deploy.tasks.motion.tracking_figures.TrackingFigures`), the arrays
        themselves: a load writes into them."""
        names = ("progress", "sq_error", "anchor_sum", "anchor_max", "ticks", "mpjpe_sum")
        names += ("waited", "heading", "handed_over", "after_counts")
        out = {k: getattr(self, k) for k in names}
        return out | {
            "play": self._play,
            "seen": self._seen,
            "vseen": self._vseen,
            "peak": self._peak,
        }

    @property
    def clock_now(self) -> float:
        """s, the runtime's time at the last tick."""
        return self._clock_now

    @clock_now.setter
    def clock_now(self, now: float) -> None:
        self._clock_now = float(now)

    def parts(self) -> dict:
        """The stateful parts: the clip's clock, the judged figures and play log
        (:class:`~sim2real.deploy.tasks.motion.tracking_figures.TrackingFigures`), the velocity
        task's (its falls)."""
        return {
            "motion": self.motion, "figures": TrackingFigures(self), "travel": self.travel,
            **self.velocity.parts(),
        }  # fmt: skip

    def state_dict(self, env: int | None = None) -> dict:
        from sim2real.deploy.core.stateful import parts_state_dict

        return parts_state_dict(self.parts(), env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        from sim2real.deploy.core.stateful import load_parts

        load_parts(self.parts(), state, env)
