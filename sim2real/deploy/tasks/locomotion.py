"""How well a legged robot follows its velocity command: distance, speed, tracking, falls.

:class:`CommandTracker` is the legged counterpart of :class:`sim2real.deploy.tasks.goals.GoalScheduler` for
``deploy-run`` and the soak: called after every tick, it measures the base's planar velocity
(the plant's truth in simulation, the base estimator's on hardware) against the command while
the runtime is RUNNING. Tracking success is the fraction of RUNNING time whose planar velocity
error ``|mean v_xy - mean command_xy|`` is within ``TRACKING_TOLERANCE`` (0.2 m/s), both averaged
over the same ``TRACKING_WINDOW`` (a trot's body sways within a stride: the command is a mean
speed; averaging the command too keeps the window's own lag out of the error, so a robot that
follows a step of the command at once tracks it at once); the ``SETTLE_TIME`` after each step
of the planar command counts as tracked (no robot follows a step at once). Yaw-rate tracking
success is the same of the heading's rate, tick to tick, against the yaw-rate command the policy
was given (a heading command's or a heading hold's), within ``YAW_TRACKING_TOLERANCE``: the
planar figure alone reads a robot that turns half of each command as tracking. Falls are the
runtime's safe stops.

:class:`~sim2real.deploy.tasks.commands.CommandSchedule` (:mod:`sim2real.deploy.tasks.commands`)
draws the soak's commands. :class:`sim2real.deploy.tasks.velocity.VelocityTask` is the task
(:func:`sim2real.deploy.tasks.task.task_for`) the tracker and a fixed command or a schedule make
together.
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.core.attitude import tilt_of
from sim2real.deploy.core.modes import FAULT_CAUSES
from sim2real.deploy.core.state import BaseState
from sim2real.deploy.core.stateful import (
    check,
    env_list,
    from_json,
    put,
    read_records,
    records_json,
    scalar,
    take,
)

#: Planar velocity error within which the robot tracks its command, m/s (our acceptance
#: criterion for walking policies; README: soak).
TRACKING_TOLERANCE = 0.2
#: Averaging window of the tracked velocity, s (our choice: two strides of a 0.4 s trot).
TRACKING_WINDOW = 0.8
#: s after a step of the planar command (more than ``TRACKING_TOLERANCE`` from one tick to the
#: next: a joystick's gradual change is no step) that count as tracked while the robot settles
#: (our choice: a base accelerating at 1 m/s^2 reaches a 1 m/s step in 1 s; unitree_rl_mjlab's
#: G1 policy took about that, and the soak's new command every 4 s left it 77 % tracked at best).
SETTLE_TIME = 1.0
#: Yaw-rate error within which the robot tracks its command, rad/s: the planar tolerance's
#: number, as the training's reward weighs them (legged_gym's ``tracking_lin_vel`` and
#: ``tracking_ang_vel`` rewards share one ``tracking_sigma``: an error of 0.2 rad/s in yaw rate
#: costs what one of 0.2 m/s does).
YAW_TRACKING_TOLERANCE = 0.2

#: Index of the ``operator`` cause in :data:`~sim2real.deploy.core.modes.FAULT_CAUSES`: a stop the
#: operator asked for (not a fall).
OPERATOR_CAUSE = FAULT_CAUSES.index("operator")


class CommandTracker:
    """Command tracking of ``envs`` legged robots (module docstring).

    Args:
        envs: Batch size.
        control_period: s.
        backend: The runtime's backend; its ``true_base_state`` (simulation) is used when it
            has one, else the runtime's base estimate.
        window: Optional s: also account the tracking per window of ``window`` s of session
            time (:meth:`windows`; the soak's windowed success).

    Attributes:
        distance: (envs,) m, planar path length of the base while RUNNING.
        forward: (envs,) m, displacement along the base's heading while RUNNING.
        running_time: (envs,) s RUNNING. tracked_time: (envs,) s of it within tolerance, or
            within ``SETTLE_TIME`` of a step of the planar command (``changed_at``, s;
            ``last_command``, (envs, 2) m/s, the previous tick's, NaN before the first).
        falls: (envs,) int64, falls: stops (SAFE_STOP or FAULTED, of any cause) of a robot that
            has been RUNNING since its previous stop. The runtime lays a legged robot down at
            every stop, so a hard-limit or stale-sensor stop leaves the base on the ground as a
            tilt (``fall``) stop does. A robot still lying after a stop, whose RAMP_IN ends in
            another stop, has not fallen again; the runtime's ``counters.faults`` counts those
            stops too.
        falls_by_cause: (envs, len(FAULT_CAUSES)) int64, ``falls`` by the stop's cause
            (:data:`sim2real.deploy.core.modes.FAULT_CAUSES` order).
        operator_stops: (envs,) int64, stops the operator asked for (cause ``operator``: a
            lie-down, a damp, a ROS 2 ``~/stop``) of a robot that was RUNNING: not falls, the
            policy did not lose the robot.
        fall_log: Per env, one dict per fall: ``t_s`` (session time), ``cause`` (the stop's,
            ``FAULT_CAUSES``) and, for a ``hard_limit`` stop, the estimate that began it:
            ``joint`` (the joint farthest past its hard limit) and ``past_rad`` (how far).
        window_running, window_tracked: per env, s RUNNING and tracked per finished window
            (with ``window``).
        yaw_tracked_time: (envs,) s of ``running_time`` whose yaw rate is within
            ``YAW_TRACKING_TOLERANCE`` of the command (module docstring), or within
            ``SETTLE_TIME`` of a step of the yaw-rate command (``yaw_changed_at``, s;
            ``last_yaw_command``, (envs,) rad/s, NaN before the first).
        heading_change, commanded_turn: (envs,) rad, the base's heading change while RUNNING
            (the yaw of its x axis, tick to tick: the truth's in simulation, the estimate's on
            hardware, where nothing else knows it) and the turn the commands asked for (their
            yaw rate, integrated). last_yaw: (envs,) rad, the heading at the previous tick
            (NaN when it was not RUNNING).
        height_sum: (envs,) m s, the fall check's kinematic base height integrated while
            RUNNING (its mean: the height the robot walked at, by its own estimate).
        displacement: (envs, 2) m, the base's planar displacement while RUNNING (its world
            velocity integrated: the truth's in simulation, else the estimate's odometry),
            along and across the heading it had when it first ran (``start_yaw``, rad; NaN
            before). A straight command that ends with a large ``across`` drifted sideways.
    """

    def __init__(self, envs: int, control_period: float, backend, window: float | None = None):
        self.envs, self.dt = envs, float(control_period)
        self.truth = getattr(backend, "true_base_state", None)
        self._ground = getattr(backend, "ground_height", None)  # a plant's ground under the base
        #: the true base (simulation): a BaseState filled from ``truth`` every tick
        self._true_base = BaseState.zeros(envs) if self.truth is not None else None
        self._true_state = None  # (envs, 13) the truth of this tick (simulation)
        self.distance = np.zeros(envs)
        self.forward = np.zeros(envs)
        self.running_time = np.zeros(envs)
        self.tracked_time = np.zeros(envs)
        self.changed_at = np.full(envs, -np.inf)
        self.last_command = np.full((envs, 2), np.nan)
        self.window = max(1, int(round(TRACKING_WINDOW / self.dt)))
        self._ring = np.zeros((self.window, envs, 2))
        self._command_ring = np.zeros((self.window, envs, 2))
        self._filled = np.zeros(envs, dtype=np.int64)
        self.yaw_tracked_time = np.zeros(envs)
        self.yaw_changed_at = np.full(envs, -np.inf)
        self.last_yaw_command = np.full(envs, np.nan)
        self._yaw_ring = np.zeros((self.window, envs))  # rad/s, the heading's rate
        self._yaw_command_ring = np.zeros((self.window, envs))
        self._yaw_filled = np.zeros(envs, dtype=np.int64)  # ticks of known yaw rate in it
        self.judged_on = "true base velocity" if self.truth is not None else "estimated base"
        if window is not None and not (math.isfinite(window) and window > 0):
            raise ValueError(f"window: expected a number of seconds > 0, got {window}")
        self.success_window = None if window is None else float(window)
        self.window_index = 0  # the window being accounted (shared: session time)
        self._window_base = np.zeros((envs, 2))  # running, tracked s at its start
        self.window_running: list[list[float]] = [[] for _ in range(envs)]
        self.window_tracked: list[list[float]] = [[] for _ in range(envs)]
        self.falls = np.zeros(envs, dtype=np.int64)
        self.falls_by_cause = np.zeros((envs, len(FAULT_CAUSES)), dtype=np.int64)
        self.operator_stops = np.zeros(envs, dtype=np.int64)
        self.fall_log: list[list[dict]] = [[] for _ in range(envs)]
        self._up = np.zeros(envs, dtype=bool)  # RUNNING since the last stop
        self.heading_change = np.zeros(envs)
        self.commanded_turn = np.zeros(envs)
        self.height_sum = np.zeros(envs)
        self.height_time = np.zeros(envs)
        self.displacement = np.zeros((envs, 2))
        self.start_yaw = np.full(envs, np.nan)
        self.last_yaw = np.full(envs, np.nan)
        robot = getattr(backend, "robot", None)
        base_cfg = getattr(getattr(robot, "config", None), "base", None)
        #: m, the robot's standing height (robot.toml ``[base]``), for the summary's comparison
        self.standing_height = None if base_cfg is None else float(base_cfg.standing_height)
        self.compiled = True  # False: numpy's path only (the reference of the kernels)
        self._call = None  # the kernels' call, bound to one runtime's arrays
        if self.truth is not None:
            from sim2real.deploy.tasks.locomotion_kernel import load

            load()  # the kernels ready before the first tick

    def kernel_arrays(self) -> dict[str, object]:
        """The arrays the kernels (:mod:`sim2real.deploy.tasks.locomotion_kernel`) update in
        place: the attributes of those names, ``ring`` and ``command_ring`` (window, envs, 2)
        m/s, the planar velocity and command of the last ``window`` ticks, ``filled`` (envs,)
        int64 ticks in them, ``up`` (envs,) bool RUNNING since the last stop, and ``true_base``
        (the :class:`~sim2real.deploy.core.state.BaseState` filled from the truth; None without
        one)."""
        names = ("distance", "forward", "running_time", "tracked_time", "changed_at")
        names += ("last_command", "heading_change", "commanded_turn", "height_sum")
        names += ("height_time", "displacement", "start_yaw", "last_yaw")
        out: dict[str, object] = {k: getattr(self, k) for k in names}
        out |= {"ring": self._ring, "command_ring": self._command_ring, "filled": self._filled}
        out |= {k: getattr(self, k) for k in ("yaw_tracked_time", "yaw_changed_at")}
        out |= {"last_yaw_command": self.last_yaw_command, "yaw_ring": self._yaw_ring}
        out |= {"yaw_command_ring": self._yaw_command_ring, "yaw_filled": self._yaw_filled}
        return out | {"up": self._up, "true_base": self._true_base}

    # ------------------------------------------------------------------ state
    def _fields(self) -> dict[str, np.ndarray]:
        return {
            "distance": self.distance,
            "forward": self.forward,
            "running_time": self.running_time,
            "tracked_time": self.tracked_time,
            "changed_at": self.changed_at,
            "last_command": self.last_command,
            "filled": self._filled,
            "ring": self._ring.swapaxes(0, 1),  # (envs, window, 2), a view
            "command_ring": self._command_ring.swapaxes(0, 1),
            "window_base": self._window_base,
            "falls": self.falls,
            "falls_by_cause": self.falls_by_cause,
            "operator_stops": self.operator_stops,
            "up": self._up,
            "heading_change": self.heading_change,
            "commanded_turn": self.commanded_turn,
            "height_sum": self.height_sum,
            "height_time": self.height_time,
            "displacement": self.displacement,
            "start_yaw": self.start_yaw,
            "last_yaw": self.last_yaw,
            "yaw_tracked_time": self.yaw_tracked_time,
            "yaw_changed_at": self.yaw_changed_at,
            "last_yaw_command": self.last_yaw_command,
            "yaw_ring": self._yaw_ring.swapaxes(0, 1),  # (envs, window), a view
            "yaw_command_ring": self._yaw_command_ring.swapaxes(0, 1),
            "yaw_filled": self._yaw_filled,
        }

    def _records(self) -> dict[str, list]:
        return {
            "window_running": self.window_running,
            "window_tracked": self.window_tracked,
            "fall_log": self.fall_log,
        }

    def state_dict(self, env: int | None = None) -> dict:
        """The tracker's state (copies; conventions of :mod:`sim2real.deploy.core.stateful`): ``distance``,
        ``forward`` (m), ``running_time``, ``tracked_time``, ``changed_at`` (s),
        ``last_command`` (envs, 2) m/s, ``filled`` (int64),
        ``ring`` and ``command_ring`` (envs, window, 2) m/s (the averaging window's planar
        velocities and commands), ``window_base``
        (envs, 2) s, ``falls`` (int64), ``falls_by_cause`` (envs, causes) int64, ``up`` (bool),
        ``heading_change``, ``commanded_turn`` (rad), ``height_sum`` (m s), ``height_time``
        (s), ``displacement`` (envs, 2) m, ``start_yaw``, ``last_yaw`` (rad), the yaw rate's
        ``yaw_tracked_time``, ``yaw_changed_at`` (s), ``last_yaw_command`` (rad/s),
        ``yaw_ring``, ``yaw_command_ring`` (envs, window) rad/s, ``yaw_filled`` (int64); shared:
        ``window_index`` (int); JSON lists over the envs: ``window_running``,
        ``window_tracked``."""
        out: dict = take(self._fields(), env)
        out["window_index"] = int(self.window_index)
        return out | records_json(self._records(), env_list(self.envs, env))

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``; the shared window
        index either way).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        check(self._fields(), state, env)
        index = scalar(state, "window_index", int)
        envs = env_list(self.envs, env)
        lists = read_records(state, ("window_running", "window_tracked"), len(envs))
        put(self._fields(), state, env)
        self.window_index = index
        for e, run, tracked in zip(
            envs, lists["window_running"], lists["window_tracked"], strict=True
        ):
            self.window_running[e] = [float(x) for x in run]
            self.window_tracked[e] = [float(x) for x in tracked]
        logs = from_json(state, "fall_log") if "fall_log" in state else [[] for _ in envs]
        for e, log in zip(envs, logs, strict=True):
            self.fall_log[e] = [dict(x) for x in log]

    # ------------------------------------------------------------------ windows
    def _close_windows(self, t: float) -> None:
        """Close every window that ended by session time ``t`` (s)."""
        index = int(t // self.success_window + 1e-9)
        while self.window_index < index:
            now = np.stack([self.running_time, self.tracked_time], axis=1)
            delta = now - self._window_base
            for e in range(self.envs):
                self.window_running[e].append(float(delta[e, 0]))
                self.window_tracked[e].append(float(delta[e, 1]))
            self._window_base[:] = now
            self.window_index += 1

    def windows(self, e: int, end: float) -> list[dict]:
        """Env ``e``'s tracking success per window of ``window`` s over ``[0, end]`` s, the open
        window included (merged into the previous one when shorter than half a window); windows
        without RUNNING time are left out: ``[{"start_s", "end_s", "running_s", "tracked_s",
        "success_rate"}]``."""
        if self.success_window is None:
            return []
        w = self.success_window
        rows = [
            [k * w, (k + 1) * w, r, x]
            for k, (r, x) in enumerate(
                zip(self.window_running[e], self.window_tracked[e], strict=True)
            )
        ]
        start = self.window_index * w
        last = [
            start,
            max(end, start),
            float(self.running_time[e] - self._window_base[e, 0]),
            float(self.tracked_time[e] - self._window_base[e, 1]),
        ]
        if rows and last[1] - start < 0.5 * w:
            rows[-1][1] = last[1]
            rows[-1][2] += last[2]
            rows[-1][3] += last[3]
        else:
            rows.append(last)
        return [
            {"start_s": a, "end_s": b, "running_s": r, "tracked_s": x, "success_rate": x / r}
            for a, b, r, x in rows
            if r > 0
        ]

    def __call__(self, runtime, asked: np.ndarray | None = None) -> None:
        """Account one tick of ``runtime`` (a floating-base :class:`~sim2real.deploy.runtime.Runtime`);
        ``asked``: (envs, 3) the operator's command when it differs from the one the policy
        was given (a heading hold's yaw rate), for ``commanded_turn``. Judged on the truth
        without success windows, the compiled kernels do it (``compiled``; the same numbers as
        :meth:`reference_call`)."""
        if self.compiled and self.truth is not None and self.success_window is None:
            asked = runtime.velocity_command if asked is None else asked
            call = self._call
            if call is None or not call.ready(runtime, asked):
                from sim2real.deploy.tasks.locomotion_kernel import TrackerCall

                limits = (TRACKING_TOLERANCE, SETTLE_TIME, YAW_TRACKING_TOLERANCE)
                call = self._call = TrackerCall.build(self, runtime, asked, limits)
            truth = self.truth()
            if call.fits and type(truth) is np.ndarray and truth.dtype == np.float64:
                if truth.shape == (self.envs, 13) and truth.flags.c_contiguous:
                    call(runtime, truth)
                    return
            self._true_state = truth
            self._true_base.set_truth(truth)
            self.reference_call(runtime, asked, truth_read=True)
            return
        self.reference_call(runtime, asked)

    def account_falls(self, runtime, down: np.ndarray, truth: np.ndarray | None = None) -> None:
        """Count the stops of the envs ``down`` ((envs,) bool: RUNNING since their previous stop,
        stopped now) as falls or operator stops (``truth``: this tick's (envs, 13), the true
        base already filled from it, for the fall records)."""
        if truth is not None:
            self._true_state = truth
        laid = down & (runtime.cause == OPERATOR_CAUSE)  # the operator laid it down
        self.operator_stops += laid
        fell = down & ~laid
        self.falls += fell
        for e in np.flatnonzero(fell):
            if runtime.cause[e] >= 0:
                self.falls_by_cause[e, runtime.cause[e]] += 1
            self.fall_log[e].append(self._fall(runtime, e))

    def reference_call(self, runtime, asked=None, truth_read: bool = False) -> None:
        """:meth:`__call__` by numpy (the kernels' reference); ``truth_read``: the true base
        is this tick's already."""
        from sim2real.deploy.core.modes import RUNNING, SAFE_STOP

        running = runtime.mode == RUNNING
        if truth_read:
            velocity = self._true_base.linear_velocity[:, :2].copy()
        else:
            velocity = self._planar_velocity(runtime)  # (envs, 2) m/s, base frame; the truth's
        down = self._up & (runtime.mode >= SAFE_STOP)  # any stop lays it down (FAULTED too)
        if down.any():
            self.account_falls(runtime, down)
        self._up &= ~down
        self._up |= running
        step = velocity * self.dt
        self.distance += np.where(running, np.linalg.norm(step, axis=1), 0.0)
        self.forward += np.where(running, step[:, 0], 0.0)
        slot = runtime.ticks % self.window
        self._ring[slot] = velocity
        self._command_ring[slot] = runtime.velocity_command[:, :2]
        self._filled[:] = np.where(running, np.minimum(self._filled + 1, self.window), 0)
        full = self._filled >= self.window
        mean = self._ring.mean(axis=0)
        error = np.linalg.norm(mean - self._command_ring.mean(axis=0), axis=1)
        if self.success_window is not None:
            self._close_windows(runtime.time - self.dt)  # this tick's time counts in its window
        command = runtime.velocity_command[:, :2]
        with np.errstate(invalid="ignore"):  # a step of the command, not a joystick's drift
            changed = np.linalg.norm(command - self.last_command, axis=1) > TRACKING_TOLERANCE
        self.changed_at[changed] = runtime.time
        self.last_command[:] = command
        settling = runtime.time - self.changed_at < SETTLE_TIME
        self.running_time += running * self.dt
        ok = (full & (error <= TRACKING_TOLERANCE)) | settling
        self.tracked_time += (running & ok) * self.dt
        self.last_yaw[~running] = np.nan
        if not running.any():
            return
        from sim2real.deploy.core.attitude import yaw_of

        # the truth's in simulation (the tracker filled it above), else the estimate's
        base = self._true_base if self.truth is not None else runtime.state.base
        # the heading's change, tick to tick (a trot's roll and pitch swing makes the integral
        # of the yaw rate about the world's up differ from it by a fifth)
        yaw = yaw_of(base.orientation)
        turn = np.angle(np.exp(1j * (yaw - self.last_yaw)))  # wrapped; NaN at a walk's first tick
        self.heading_change += np.where(running & np.isfinite(turn), turn, 0.0)
        self._track_yaw(runtime, running, turn, slot)
        self.last_yaw[:] = np.where(running, yaw, np.nan)
        begin = running & np.isnan(self.start_yaw)
        if begin.any():
            self.start_yaw[begin] = yaw[begin]
        heading = np.where(np.isnan(self.start_yaw), 0.0, self.start_yaw)
        c, s = np.cos(heading), np.sin(heading)
        vx, vy = base.linear_velocity_world[:, 0], base.linear_velocity_world[:, 1]
        along, across = c * vx + s * vy, -s * vx + c * vy
        self.displacement += np.where(running[:, None], np.stack([along, across], 1), 0.0) * self.dt
        asked = runtime.velocity_command if asked is None else asked
        self.commanded_turn += np.where(running, asked[:, 2] * self.dt, 0.0)
        detector = getattr(runtime, "fall_detector", None)
        if detector is not None:
            known = running & np.isfinite(detector.height)
            self.height_sum += np.where(known, detector.height, 0.0) * self.dt
            self.height_time += known * self.dt

    def _track_yaw(self, runtime, running, turn, slot) -> None:
        """The yaw-rate tracking of one tick (``turn`` (envs,) rad, the heading's wrapped change
        since the previous tick, NaN at a walk's first; ``slot`` the ring's row)."""
        known = running & np.isfinite(turn)
        command = runtime.velocity_command[:, 2]
        self._yaw_ring[slot] = np.where(known, turn / self.dt, 0.0)
        self._yaw_command_ring[slot] = command
        self._yaw_filled[:] = np.where(known, np.minimum(self._yaw_filled + 1, self.window), 0)
        error = np.abs(self._yaw_ring.mean(axis=0) - self._yaw_command_ring.mean(axis=0))
        with np.errstate(invalid="ignore"):  # a step of the command (NaN before the first)
            changed = np.abs(command - self.last_yaw_command) > YAW_TRACKING_TOLERANCE
        self.yaw_changed_at[changed] = runtime.time
        self.last_yaw_command[:] = command
        settling = runtime.time - self.yaw_changed_at < SETTLE_TIME
        full = self._yaw_filled >= self.window
        ok = (full & (error <= YAW_TRACKING_TOLERANCE)) | settling
        self.yaw_tracked_time += (running & ok) * self.dt

    def _fall(self, runtime, e: int) -> dict:
        """The record of env ``e``'s fall (``fall_log``): with a fall stop, ``signals`` (which
        of the fall check's signals fired, :data:`sim2real.deploy.estimation.fall.SIGNALS`); in
        simulation, the true base at the stop (this tick's, filled by :meth:`_planar_velocity`):
        ``true_height_m`` (the base origin's height above the ground under it: 0 on the plane),
        ``true_vz_m_s`` (m/s world, negative sinking), ``true_tilt_deg``; the estimate's ``tilt_deg``."""
        from sim2real.deploy.estimation.fall import SIGNALS

        cause = int(runtime.cause[e])
        out = {"t_s": float(runtime.time), "cause": FAULT_CAUSES[cause] if cause >= 0 else None}
        detector = getattr(runtime, "fall_detector", None)
        if out["cause"] == "fall" and detector is not None:
            out["signals"] = [s for s, on in zip(SIGNALS, detector.signals[e], strict=True) if on]
        out["tilt_deg"] = float(np.degrees(tilt_of(runtime.state.base.projected_gravity[e])))
        if self.truth is not None:
            z = self._true_state[e, 2]
            if self._ground is not None:  # above the ground under it (0 on the plane)
                z = z - self._ground(self._true_state)[e]
            out["true_height_m"] = float(z)
            out["true_vz_m_s"] = float(self._true_state[e, 9])
            out["true_tilt_deg"] = float(np.degrees(tilt_of(self._true_base.projected_gravity[e])))
        if out["cause"] == "hard_limit":
            robot, q = runtime.robot, runtime.state.q[e]
            past = np.maximum(robot.position_lower - q, q - robot.position_upper)
            j = int(np.argmax(past))
            out.update(joint=robot.joint_names[j], past_rad=float(past[j]))
        return out

    def causes(self, env: int | None = None) -> dict[str, int]:
        """``{cause: falls}`` of env ``env`` (all envs summed by default), causes that occurred."""
        counts = self.falls_by_cause.sum(axis=0) if env is None else self.falls_by_cause[env]
        return {c: int(n) for c, n in zip(FAULT_CAUSES, counts, strict=True) if n}

    def _planar_velocity(self, runtime) -> np.ndarray:
        if self.truth is None:
            return runtime.state.base.linear_velocity[:, :2].copy()
        self._true_state = self.truth()  # (envs, 13) this tick's, for a fall's record too
        return self._true_base.set_truth(self._true_state).linear_velocity[:, :2].copy()

    def summary(self, runtime) -> dict:
        """The report's ``locomotion`` entry (sums over the envs; speeds per RUNNING second)."""
        running = float(self.running_time.sum())
        return {
            "command": runtime.velocity_command.tolist(),
            "distance_m": float(self.distance.sum()),
            "mean_forward_speed_m_s": float(self.forward.sum() / running) if running else None,
            "tracking_success": float(self.tracked_time.sum() / running) if running else None,
            "tracking_tolerance_m_s": TRACKING_TOLERANCE,
            "yaw_tracking_success": (
                float(self.yaw_tracked_time.sum() / running) if running else None
            ),
            "yaw_tracking_tolerance_rad_s": YAW_TRACKING_TOLERANCE,
            "settle_s": SETTLE_TIME,
            "running_s": running,
            "falls": int(self.falls.sum()),
            "falls_by_cause": self.causes(),
            "operator_stops": int(self.operator_stops.sum()),
            "judged_on": self.judged_on,
            "heading_change_deg": float(np.degrees(self.heading_change.sum())),
            "commanded_turn_deg": float(np.degrees(self.commanded_turn.sum())),
            "base_height_m": (
                float(self.height_sum.sum() / self.height_time.sum())
                if self.height_time.sum() > 0
                else None
            ),
            "standing_height_m": self.standing_height,
            "displacement_m": self.displacement.sum(axis=0).tolist(),
        }
