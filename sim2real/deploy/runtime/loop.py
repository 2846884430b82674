"""The control loop (:class:`Runtime`): its stages built over one backend, its lifecycle (start,
restart after the robot was moved, an operator's reset of latched faults), the tick (read top to
bottom in :meth:`Runtime.tick`). It delegates by name to its stages: the state dict to
:class:`~.state.RuntimeState`, the run with the garbage collector frozen to
:class:`~.run_loop.RunLoop`, the part of the tick a robot's base adds to its kind's
(``kind.tick_stage``, :mod:`sim2real.deploy.kinds.legged_tick`); the package's, the tick.
"""

from __future__ import annotations

import gc
import time

import numpy as np

from sim2real.deploy.core.delegate import delegate, forward
from sim2real.deploy.core.latency import BIN_NS, BINS, LatencyHistogram
from sim2real.deploy.core.modes import (
    OVERRUN_RATE_LIMIT,
    RAMP_IN,
    RUNNING,
    START_TIMEOUT,
    Mode,
)
from sim2real.deploy.core.state import Kinematics, RobotState
from sim2real.deploy.estimation.joints import JointStateEstimator
from sim2real.deploy.kernels import any_true
from sim2real.deploy.kinds import robot_kind
from sim2real.deploy.observe import long_ticks as lt
from sim2real.deploy.runtime.anchoring import reanchor, tracking_tolerance
from sim2real.deploy.runtime.camera import exteroception
from sim2real.deploy.runtime.clock import SimClock
from sim2real.deploy.runtime.compiled import CompiledSupervision
from sim2real.deploy.runtime.handover import RampIn, check_policy, follows_targets, switch_policy
from sim2real.deploy.runtime.run_loop import RunLoop
from sim2real.deploy.runtime.stale import StaleStops
from sim2real.deploy.runtime.state import RuntimeState
from sim2real.deploy.runtime.supervision import Supervision
from sim2real.deploy.safety.guard import SafetyGuard
from sim2real.deploy.smoothing import CommandSmoother, SmoothingError
from sim2real.deploy.spec.motion_blocks import motion_buffer
from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots import Robot

#: The tick's stages, as its latency histogram counts them (``Runtime.latency``).
STAGES = ("read", "estimate", "observe", "infer", "guard", "smooth", "write", "physics")


class Runtime:
    """The control loop for ``envs`` robots behind one backend.

    Args:
        robot: Robot description.
        policy: Callable ``(envs, obs_dim) float32 -> (envs, act_dim) float32`` with a ``spec``
            attribute (:class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy`); its ``reset(envs)``
            (boolean mask (envs,)), if it has one, is called where its state must start afresh.
        backend: A :class:`~sim2real.deploy.core.backend.Backend` (``read``, ``write``, ``advance``,
            ``drive_errors``), opened: :class:`~sim2real.deploy.backends.sim.plant.SimBackend` or a servo bus.
        clock: :class:`SimClock` (default) or :class:`WallClock`.
        injector: Optional :class:`~sim2real.deploy.backends.sim.faults.FaultInjector` (simulation only).
        telemetry: Optional :class:`~sim2real.deploy.observe.telemetry.Telemetry` recorder.
        overrun_rate_limit: Fraction of the control periods of the last ``OVERRUN_WINDOW_S``
            seconds the loop may miss on the wall clock before a safe stop (cause ``overrun``);
            default ``OVERRUN_RATE_LIMIT`` of the control mode (0.5 position, 0.25 velocity and
            torque; our choice, :mod:`sim2real.deploy.core.modes`). A transient stall is ridden
            through, the drives holding the last command.
        kind: The robot's kind (the rig's, handed to the guard); None: ``robot_kind(robot)``.

    The tick's numeric logic runs in the compiled kernels of :mod:`sim2real.deploy.kernels`; its
    numpy reference is :class:`sim2real.deploy.runtime.reference.ReferenceRuntime`, whose stages and
    small methods (``_build_stages``, ``_compile``, ``_supervise``, ``_observe``, ``_act``,
    ``_bind_books``) replace these.

    Raises:
        ValueError: a policy of another control mode than the backend's, or an
            ``overrun_rate_limit`` outside (0, 1].
    """

    #: The state machine's class (:class:`.reference.ReferenceRuntime` takes its numpy reference).
    supervision_type = Supervision
    run = forward("run_loop", "run")  # RunLoop.run: ticks with the garbage collector frozen
    gc_collections = delegate("run_loop", "gc_collections", writable=True)
    #: (envs, n) float32: the last tick's screened policy action in [-1, 1] (a view)
    action = delegate("supervision", "action")
    mode_names = forward("supervision", "mode_names")  # each env's mode, by name
    cause_names = forward("supervision", "cause_names")  # each env's fault cause, or None

    def __init__(
        self,
        robot: Robot,
        policy,
        backend,
        clock=None,
        injector=None,
        telemetry=None,
        overrun_rate_limit: float | None = None,
        kind=None,
    ):
        if overrun_rate_limit is None:
            overrun_rate_limit = OVERRUN_RATE_LIMIT[backend.mode]
        if not 0.0 < overrun_rate_limit <= 1.0:
            raise ValueError(f"overrun_rate_limit: expected in (0, 1], got {overrun_rate_limit}")
        self.overrun_rate_limit = overrun_rate_limit
        self.robot, self.policy, self.backend = robot, policy, backend
        self.kind = kind = kind or robot_kind(robot)
        #: what a command means to each drive (the kind's
        #: :class:`~sim2real.deploy.kinds.targets.DriveTargets`)
        self.targets = targets = kind.targets(robot)
        check_policy(policy.spec, robot, backend.mode, targets)
        self.spec: PolicySpec = policy.spec
        #: a hand-over in progress (:meth:`switch_policy`), the last that ended, a slow RAMP_IN
        self.handover = self.last_handover = self.ramp = None
        envs, n = backend.envs, robot.n_joints
        self.envs, self.n = envs, n
        self.mode_name = backend.mode
        self.dt = robot.control_period
        self.clock = clock or SimClock(self.dt)
        self.injector = injector
        self.telemetry = telemetry
        self.estimator = JointStateEstimator(robot, envs)
        self.kinematics = Kinematics(robot)
        self.guard, self.smoother = self._build_stages()
        #: bool: RUNNING envs command the guard's targets, not the smoother's (follows_targets)
        self.follows_targets = follows_targets(self.spec, targets, self.mode_name)
        self.state: RobotState = kind.state(robot, envs)
        #: a tracking policy's clip (RobotState.motion): the warm-up's placeholder; its task's after
        self.state.motion = motion_buffer(self.spec, envs, n)
        self.goal = np.zeros((envs, 3))
        #: a height_scan policy's elevation map, an image input's camera (stale: a safe stop)
        self.height_map, self.cameras = exteroception(self.spec, self.state, envs, robot, backend)
        #: the tick's part the kind's base adds (a floating base: kinds.legged_tick) and its
        #: stages: the base estimate (IMU, leg kinematics) and the fall check (None: an arm)
        self.base_tick = kind.tick_stage(self)
        self.base_estimator, self.fall_detector = self.base_tick.stages
        #: (envs,) bool, an operator laying a legged robot down or standing it up: only a tilt falls
        self.lying_expected = np.zeros(envs, dtype=bool)
        #: (envs, 3) the velocity command of a legged robot (vx, vy m/s, yaw rate rad/s, base
        #: frame): the operator's (deploy-run --command) or the soak's schedule; write into it
        self.velocity_command = (
            self.state.command if self.state.command is not None else np.zeros((envs, 3))
        )
        #: rad: the re-anchoring's tolerance (:func:`reanchor`; inf for a legged robot)
        self.tracking_tolerance = tracking_tolerance(targets, self.mode_name)
        #: the state machine, one per env (:class:`~sim2real.deploy.runtime.supervision.Supervision`):
        #: its arrays below are the runtime's, its transitions in numpy
        self.supervision = sup = self.supervision_type(
            robot,
            envs,
            self.mode_name,
            self.estimator,
            self.guard,
            self.smoother,
            self.clock,
            overrun_rate_limit,
            self._reset_policy,  # the policy of the moment's (switch_policy)
        )
        #: (envs,) int8 modes (:class:`Mode`), and causes (index into FAULT_CAUSES, -1: none)
        self.mode, self.cause = sup.mode, sup.cause
        #: (envs, n) int64, OR of the hardware error bits each drive reported (cause servo_error)
        self.drive_errors = sup.drive_errors
        self.counters = sup.counters
        #: (envs,) int64, supervised ticks since each env's safe stop began (0 outside SAFE_STOP)
        self.stop_ticks = sup.stop_ticks
        #: what went stale at each stale_sensor stop, and why (:class:`StaleStops`)
        self.stale_stops = StaleStops(self, sup)
        self.latency = LatencyHistogram(len(STAGES))
        self.tick_cost = LatencyHistogram()
        #: the longest control periods and their parts (``LongTicks``): the wake-up's lateness,
        #: each stage, the work outside the stages, the loop thread's CPU time (wall clock)
        self.long_ticks = lt.LongTicks(STAGES)
        # the period's stamps (long_ticks.PREV_WAKE ... END_CPU) and the CPU clock (wall clock)
        self._period = np.array([0, 0, -1, 0, 0], dtype=np.int64)
        self._cpu_ns = time.thread_time_ns if self.clock.realtime else None
        self.ticks, self.time = 0, 0.0
        self.run_loop = RunLoop(self, self.tick, self._woke, self.clock)  # and gc_collections
        self.checkpoint = RuntimeState(self)  # the state dict
        self._obs = np.zeros((envs, self.spec.obs_dim), dtype=np.float32)
        self._target = np.zeros((envs, n))
        self._cmd = np.zeros((envs, n))
        #: (envs,) s, the backend's clock of the frame the last tick read (a recorded log maps
        #: its readings' stamps to the ticks with it: sim2real.deploy.observe.command_log)
        self.read_time = np.zeros(envs)
        self._stamps = np.zeros(len(STAGES) + 1, dtype=np.int64)
        self._tracking = np.zeros(envs)
        self._anchored = np.zeros(envs, dtype=np.int64)
        # velocity mode: the position the commands integrate to (Ruckig's state), else None
        self._commanded = self.smoother.position if self.mode_name == "velocity" else None
        #: the estimator's control input (:meth:`SafetyGuard.estimator_input`)
        self._input = self.guard.estimator_input(self.smoother)
        self.guard.trust_estimate(self.estimator.covariance)
        # latency histograms' bins (sim2real.deploy.observe.telemetry)
        self._bins = np.array([BIN_NS, BINS], dtype=np.int64)
        #: the compiled action screen and supervision (sim2real.deploy.kernels); None in the reference
        self._compiled = self._compile()
        self.state.motion = None  # never a zero clip: the motion task writes the reference
        #: a fixed base on the compiled path: estimate and observe in one call (_estimate_observe)
        self._fused = self._compiled is not None and self.base_tick.fusable and self.cameras is None
        self._idle = np.zeros(envs, dtype=bool)  # the envs not RUNNING at the tick's end
        self._idle_rows = self._idle[:, None]  # its view over the joints (no index array)
        self._running = np.zeros(envs, dtype=bool)  # the tick's RUNNING envs (follow)
        self.base_tick.bind()  # compiled (or loaded) and bound before a tick
        #: ``(tick) -> None``: the tick's latency histograms and long periods (:meth:`_bind_books`)
        self._books = self._bind_books()
        self.guard.bind_motion(self.smoother, self.state, self._cmd)  # the tick's arrays
        gc.collect()  # the set-up's garbage, every generation, once: here, not in run() (below)

    def _reset_policy(self, envs: np.ndarray) -> None:
        """The current policy's ``reset(envs)`` (bool mask (envs,)), if it has one, its
        observation's frame history (the envs' next frame is the first) and its last action (0,
        as before its first call; a training episode's reset zeroes it too)."""
        if hasattr(self.policy, "reset"):  # a policy with state (a recurrent one)
            self.policy.reset(envs)
        self.spec.plan.reset_history(envs)
        self.state.last_action[envs] = 0.0

    def ramp_in(self, duration: float, envs=None, running: bool = False) -> None:
        """After :meth:`reset_faults` or :meth:`restart`: ``envs`` (bool (envs,); default all)
        go home in ``duration`` s from their estimated pose (position mode; ``RampIn``).
        ``running``: RUNNING envs, from the last target, then hold home (the policy off)."""
        if self.mode_name == "position" and (duration > 0 or running):
            mask = np.ones(self.envs, bool) if envs is None else np.asarray(envs, dtype=bool)
            ticks, speeds = round(duration / self.dt), self.robot.velocity_driven  # wheels: 0 rad/s
            start = self._target if running else self.state.q  # the last PD target: no torque drop
            self.ramp = RampIn(start, self.supervision.home, mask, ticks, speeds, running=running)

    def switch_policy(self, policy, blend_time: float = 0.0) -> None:
        """Hand control to ``policy`` between ticks, its targets blended in over ``blend_time``
        s (:func:`~sim2real.deploy.runtime.handover.switch_policy`, which says how).

        Raises:
            ValueError: a spec for another robot or control mode, a negative ``blend_time``.
        """
        switch_policy(self, policy, blend_time)

    def _build_stages(self) -> tuple[SafetyGuard, CommandSmoother]:
        """The guard and the smoother (compiled)."""
        envs, mode, kind = self.envs, self.mode_name, self.kind
        wheels, bounded = kind.wheel_drives(self.robot, envs, mode), self.targets.bounded()
        smoother = CommandSmoother(self.robot, envs, mode, bounded=bounded, wheels=wheels)
        return SafetyGuard(self.robot, envs, mode, kind), smoother

    def _compile(self) -> CompiledSupervision | None:
        """The compiled path: :class:`CompiledSupervision` over the runtime's arrays, and one call
        of the observation's kernel: compiled (or loaded from numba's cache) now, not in the
        first tick."""
        args = (self.supervision, self.spec, self.state, self._target, self.tracking_tolerance)
        compiled = CompiledSupervision(*args, self._reanchor)
        self.spec.observation(self.state, self.goal, out=self._obs)  # builds and warms its plan
        return compiled

    def _bind_books(self):
        """``(tick) -> None``, the tick's bookkeeping in one compiled call into :attr:`latency`,
        :attr:`tick_cost` and :attr:`long_ticks` (:mod:`sim2real.deploy.observe.long_ticks`'s
        ``record_tick`` bound to these arrays as one table; they are never replaced)."""
        lat, cost = self.latency, self.tick_cost
        arrays = (self._stamps, self._period, self._bins, lat.counts, lat.max_ns)
        arrays += (cost.counts, cost.max_ns, self.long_ticks.table)
        return lt.bind_record(arrays)  # the tick index, an int, at each call

    # ------------------------------------------------------------------ state and views
    def state_dict(self, env: int | None = None) -> dict:
        """The loop's state and its stages' (:meth:`.state.RuntimeState.state_dict`)."""
        return self.checkpoint.state_dict(env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`, its tick and time included; raises StateDictError
        (:meth:`.state.RuntimeState.load_state_dict`)."""
        self.ticks, self.time = self.checkpoint.load_state_dict(state, env)

    @property
    def target(self) -> np.ndarray:
        """(envs, n): the last tick's guarded target, units of the mode (rad, rad/s, N m; a view)."""
        return self._target

    @property
    def command(self) -> np.ndarray:
        """(envs, n): the command the last tick wrote, units of the mode (a view)."""
        return self._cmd

    @property
    def damping(self) -> np.ndarray:
        """(envs,) bool: the envs whose command damps the joints instead of holding a pose (a
        legged robot's envs in SAFE_STOP or FAULTED: it lies down; all False for an arm)."""
        return self.base_tick.damping(self.mode)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Anchor every stage at the measured state and enter RAMP_IN.

        Waits (``backend.advance()``, the drives holding their initial command) up to
        ``START_TIMEOUT`` s for a reading of every joint: with encoder latency the first readings
        arrive a few ticks late. On a wall clock (hardware) the set-up comes first (the policy's
        first call, a garbage collection) and the anchor must be current: each reading younger
        than half of ``Robot.stale_limit``, so that set-up done after the anchor (a collection
        holds the GIL a backend's reader thread needs) is not taken for a silent sensor.

        Raises:
            RuntimeError: some joint sent no (current) reading within ``START_TIMEOUT``.
        """
        realtime = self.clock.realtime
        if realtime:
            self.policy(self._obs)
            gc.collect()  # holds the GIL a backend's reader thread needs: before the anchor
        max_age = 0.5 * self.robot.stale_limit if realtime else np.inf
        frame = self.backend.read()
        for _ in range(int(np.ceil(START_TIMEOUT / self.dt))):
            if self._current(frame, max_age).all():
                break
            self.backend.advance()
            if realtime:  # hardware: advance returns at once, the clock paces
                time.sleep(self.dt)
            frame = self.backend.read()
        missing = ~self._current(frame, max_age)
        if missing.any():
            raise RuntimeError(
                f"Runtime.start: no encoder reading for joints {np.argwhere(missing).tolist()} "
                f"(env, joint) within {START_TIMEOUT} s"
                + (f" younger than {max_age:g} s" if realtime else "")
                + "; cannot anchor the estimator at a measured pose"
            )
        q = frame.position.copy()
        self.estimator.reset(q, frame.position_stamp)
        self.state.q[:] = q
        self.state.dq[:] = 0.0
        self.guard.reset(q)
        self.smoother.reset(q, self.state.dq)
        self.base_tick.start(frame)  # a floating base: as the IMU's attitude says, yaw 0
        self.mode[:] = RAMP_IN
        self._reset_policy(np.ones(self.envs, dtype=bool))
        self.clock.start()

    @staticmethod
    def _current(frame, max_age: float) -> np.ndarray:
        """(envs, n) bool: the frame's readings that are finite and at most ``max_age`` s old."""
        age = frame.time[:, None] - frame.position_stamp
        return np.isfinite(frame.position) & ~(age > max_age)

    def reset_faults(self, envs: np.ndarray | None = None) -> None:
        """Clear latched faults (an operator's reset): FAULTED envs start again with RAMP_IN.

        Args:
            envs: Optional boolean mask (envs,) of the envs to reset; default all. Other envs are
                untouched (sessions batched in one runtime stay independent).
        """
        faulted = self.mode == Mode.FAULTED
        if envs is not None:
            faulted &= np.asarray(envs, dtype=bool)
        self.supervision.ramp_in_at_rest(faulted, self.state.q)

    def restart(self, envs: np.ndarray, q: np.ndarray, t) -> None:
        """An operator's restart of the envs of ``envs`` (bool mask (envs,)) after the robot was
        moved by hand (stood back up, carried): the joint estimate re-anchored at the pose ``q``
        ((n,) or (envs, n) rad) at rest at time ``t`` (s; float or (envs,)), and the base
        estimator upright, as :meth:`start` anchors them (the estimators' counters of those envs
        are kept: a session's tallies survive its restarts); the guard and smoother at ``q``;
        latched faults cleared; RAMP_IN. Other envs are untouched. (A filter that tracked the
        jump instead would hand the smoother a joint speed of tens of rad/s.)"""
        envs = np.asarray(envs, dtype=bool)
        if not envs.any():
            return
        est = self.estimator
        counters = (est.stale_per_joint, est.missing_per_joint, est.reinitializations_per_joint)
        kept = [c[envs].copy() for c in counters]
        q = np.broadcast_to(np.asarray(q, dtype=np.float64), self.state.q.shape)
        est.reset(q, t, envs=envs)
        for counter, value in zip(counters, kept, strict=True):
            counter[envs] = value
        self.base_tick.restart(t, envs)  # a floating base: upright
        self.state.q[envs] = q[envs]
        self.state.dq[envs] = 0.0
        self.supervision.ramp_in_at_rest(envs, self.state.q)

    # ------------------------------------------------------------------ the tick
    def tick(self) -> None:
        """One control period for every env (see :mod:`sim2real.deploy.runtime`)."""
        st, clock_ns = self._stamps, time.perf_counter_ns
        st[0] = clock_ns()
        if self.injector is not None:
            self.injector.before_read(self.time)
        frame = self.backend.read()
        if self.injector is not None:
            frame = self.injector.filter_frame(self.time, frame)
        self.read_time[:] = frame.time
        drive_errors = self.backend.drive_errors()  # None: drives without error reports
        st[1] = clock_ns()
        if self._fused:  # a fixed base: the four calls below as one (observe in estimate's stamp)
            state, obs = self.state, self._estimate_observe(frame, drive_errors)
            st[2] = st[3] = clock_ns()
        else:
            state = self.estimator.update(frame, self.state, self._input)
            self.kinematics.update(state)
            self.base_tick.update(frame, state)  # a floating base: IMU, contacts, clock; falls
            if self.cameras is not None:  # the image input, into the policy's bound array
                self.cameras.feed(frame, self.policy, self.supervision)
            self._supervise(state, drive_errors)  # with the thermal derating of the effort limits
            st[2] = clock_ns()
            obs = self._observe(state)
            st[3] = clock_ns()
        policy_output = self.policy(obs)
        st[4] = clock_ns()
        action, target = self._act(policy_output, state)  # screen, action_to_target, override
        if self.ramp is not None and self.ramp.shape(target, self.mode):  # ramp_in: slowly home
            self.ramp = None
        if self.handover is not None:  # switch_policy: the outgoing policy's targets blend in
            self.handover.blend(target, state, self.goal, self.mode)
            if self.handover.finished:
                self.last_handover, self.handover = self.handover, None
        target = self.guard.filter(target, state, out=target, commanded_position=self._commanded)
        self.supervision.safe_stop(self.guard.hard_violation, "hard_limit")
        st[5] = clock_ns()
        if self.follows_targets:  # PD targets as trained (torque requests): RUNNING takes them
            np.equal(self.mode, RUNNING, out=self.smoother.follow_envs)
        try:
            cmd = self.smoother.step(target, out=self._cmd)
            cmd = self.guard.check_motion(self.smoother, state, cmd)  # brake an unsafe path
        except SmoothingError as error:  # Ruckig cannot plan: those envs stop, the run goes on
            cmd = self._replan(error, target, state)
        if self.follows_targets:  # the envs still RUNNING after the step command the target
            self.smoother.follow(target, np.equal(self.mode, RUNNING, out=self._running), cmd)
        self.base_tick.damp(cmd, state)  # a legged robot's every stop lies it down, damped
        st[6] = clock_ns()
        self.backend.write(cmd)
        st[7] = clock_ns()
        self.backend.advance()
        st[8] = clock_ns()
        # the action the drives ran: an env not RUNNING ran the runtime's override, not the policy's,
        # whose output fed back to itself would grow unchecked (its last action, lying damped)
        if self._compiled is None or not self._compiled.action_ran(state, action, self._idle):
            state.last_action[:] = action
            if any_true(np.not_equal(self.mode, RUNNING, out=self._idle)):
                np.copyto(state.last_action, 0.0, where=self._idle_rows)
        self.ticks += 1
        self.time += self.dt
        if self.telemetry is not None:
            self.telemetry.record(self)
        period, cpu_ns = self._period, self._cpu_ns
        period[lt.END] = clock_ns()
        if cpu_ns is not None:
            period[lt.END_CPU] = cpu_ns()
        self._books(self.ticks)  # stage histograms, tick cost, long periods: one compiled call
        self.supervision.note_periods(self.clock.wait())  # the periods missed: 0 on time
        self._woke(clock_ns())

    def _replan(self, error: SmoothingError, target: np.ndarray, state: RobotState) -> np.ndarray:
        """The tick's command after Ruckig failed (``error``): the envs it names stop
        (``Supervision.smoothing_failed``) and the step runs again; should that fail too, every
        env stops. Raises the last ``SmoothingError`` if even that cannot be planned."""
        for every in (False, True):
            self.supervision.smoothing_failed(error, state, every=every)
            try:
                cmd = self.smoother.step(target, out=self._cmd)
                return self.guard.check_motion(self.smoother, state, cmd)
            except SmoothingError as again:
                error = again
        raise error

    def _woke(self, now_ns: int) -> None:
        """The period's stamps at a wake-up (:mod:`sim2real.deploy.observe.long_ticks`)."""
        period = self._period
        period[lt.PREV_WAKE] = now_ns
        period[lt.PREV_LATE] = self.clock.late_ns
        period[lt.PREV_CPU] = self._cpu_ns() if self._cpu_ns is not None else -1

    # ------------------------------------------------------------------ stages' helpers
    def _supervise(self, state: RobotState, drive_errors: np.ndarray | None) -> None:
        """The thermal derating of the guard's effort limits; stale sensors, over-temperature,
        drive errors, overruns; end of RAMP_IN and of safe stops; re-anchoring
        (:meth:`CompiledSupervision.supervise`)."""
        self._compiled.supervise(state, drive_errors)

    def _estimate_observe(self, frame, drive_errors: np.ndarray | None) -> np.ndarray:
        """A fixed base's estimator, kinematics, :meth:`_supervise` and :meth:`_observe` in one
        compiled call, the same numbers (:meth:`.fused.TableCalls.estimate_observe`)."""
        args = (frame, drive_errors, self._input, self.spec, self.goal, self._obs)
        return self._compiled.estimate_observe(*args)

    def _observe(self, state: RobotState) -> np.ndarray:
        """(envs, obs_dim) float32: the policy's observation (``spec.observation``, compiled)."""
        return self.spec.observation(state, self.goal, out=self._obs)

    def _act(self, action: np.ndarray, state: RobotState) -> tuple[np.ndarray, np.ndarray]:
        """The policy's output to a target: the fault injector's filter, the screen of
        non-finite actions, ``spec.action_to_target``, the overrides of the envs not RUNNING
        (:meth:`CompiledSupervision.screen`); returns ``(action, target)``, the screened action
        (float32) and the target (units of the mode), (envs, n) each."""
        if self.injector is not None:
            action = self.injector.filter_action(self.time, action)
        self._compiled.screen(action, state, self.spec)
        return self.supervision.action, self._target

    def _reanchor(self, state: RobotState) -> None:
        """:func:`reanchor` the smoother and count it (anchors or resyncs)."""
        moved = reanchor(
            self.smoother, state, self._tracking, self._anchored, self.mode, self.tracking_tolerance
        )
        if moved is not None:
            counter = (
                self.counters.anchors if self.mode_name == "velocity" else self.counters.resyncs
            )
            counter += moved
