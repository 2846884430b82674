"""Runtime: the fixed-rate loop between a neural network and a motor.

The tick (:meth:`Runtime.tick`) reads top to bottom as DESIGN.md draws it::

    frame  = backend.read()                        # encoders, temperatures
    state  = estimator.update(frame, u)            # Kalman filter: q, dq (predict-only on
                                                   # dropouts); u: acceleration last commanded
    obs    = spec.observation(state, goal)         # normalized by physical maxima
    action = policy(obs)                           # ONNX Runtime; non-finite -> hold, count
    target = spec.action_to_target(action, state)  # physical units of the control mode
    target = guard.filter(target, state)           # Pinocchio: clamp or reject, count
    cmd    = smoother.step(target)                 # Ruckig: velocity, acceleration, jerk limits
    backend.write(cmd)

State machine (one per env): ``IDLE -> RAMP_IN -> RUNNING -> SAFE_STOP -> FAULTED``. RAMP_IN brings
the robot from its measured pose to the home pose before the policy takes over. A recurrent
policy's state is reset (``policy.reset(envs)``) for the envs that enter RAMP_IN (start, operator
reset, cool-down resume) and again for those whose RAMP_IN ends: the policy takes control from its
initial state, as in a fresh episode. SAFE_STOP brings
every joint to rest within the smoother's limits and holds; a safe stop for over-temperature resumes
(RAMP_IN) once every winding has cooled below its derating start, any other cause ends in FAULTED,
latched until :meth:`Runtime.reset_faults`.

Faults and responses (DESIGN.md): non-finite policy output holds the last valid action, and
``NAN_ACTION_LIMIT`` consecutive ones make a safe stop; sensor data stale longer than
``safety.stale_limit`` makes a safe stop; a hard-limit violation makes a safe stop; a winding above
its maximum makes a safe stop latched until cool, and the effort limit is derated linearly in the
derating band down to the continuous torque, as the drives derate theirs
(:class:`deploy.thermal.EffortDerating`); a wall-clock overrun rate above ``OVERRUN_RATE_LIMIT``
makes a safe stop; a hardware error a drive reports (``backend.drive_errors()``: a servo's
overload, overheating or voltage bits) makes a safe stop (cause ``servo_error``), the bits latched
per joint in :attr:`Runtime.drive_errors`.

The backend is any :class:`deploy.backends.base.Backend`: the simulated plant, or a servo bus
(:mod:`deploy.backends.feetech`, :mod:`deploy.backends.dynamixel`) with the wall clock.

Clocks: :class:`SimClock` runs in lockstep with a simulated plant as fast as the CPU allows;
:class:`WallClock` waits for absolute deadlines, skips missed periods instead of bursting, and
counts overruns and jitter.

The garbage collector is frozen and disabled while :meth:`Runtime.run` loops.
"""

from __future__ import annotations

import gc
import time
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from deploy.estimation import JointStateEstimator
from deploy.safety import SafetyGuard
from deploy.smoothing import CommandSmoother
from deploy.spec import PolicySpec
from deploy.state import Kinematics, RobotState
from deploy.telemetry import LatencyHistogram
from robots import Robot

#: Consecutive non-finite policy outputs before a safe stop (0.05 s at 200 Hz).
NAN_ACTION_LIMIT = 10
#: Fraction of overrun ticks over the last ``OVERRUN_WINDOW`` ticks that makes a safe stop.
OVERRUN_RATE_LIMIT = 0.05
OVERRUN_WINDOW = 200
#: A joint is at rest below this speed, rad/s (ends a safe stop, ends RAMP_IN).
REST_SPEED = 0.05
#: Runtime.start waits this long for the first reading of every joint, s.
START_TIMEOUT = 0.5
#: RAMP_IN ends within this distance of the home pose, rad.
HOME_TOLERANCE = 0.05
#: Gain of the RAMP_IN approach in velocity and torque mode, 1/s (the smoother bounds the rest).
RAMP_GAIN = 2.0
#: Joint damping of the torque-mode safe stop, N m s/rad per N m of effort limit.
STOP_DAMPING = 0.2
#: Position mode: a command this far (rad) from the measured pose (the arm was pushed or blocked)
#: is re-anchored at the measured state, so that the servo does not yank the arm back; counted.
TRACKING_TOLERANCE = 0.6  # arm3's servo lags up to 0.45 rad at full speed
#: Velocity mode: Ruckig's integrated position is kept within this distance (rad) of the measured
#: pose (:meth:`~deploy.smoothing.CommandSmoother.anchor`); moves are counted as anchors. Our
#: choice: twice the position lag of a PI velocity drive at its effort limit, 2 x 22.5 N m /
#: kp 400 N m/rad = 0.11 rad on arm3 (robot.toml), rounded to 0.1; a drive that lags further
#: saturates, and its own anti-windup lets go of the gap too.
VELOCITY_TRACKING_TOLERANCE = 0.1

STAGES = ("read", "estimate", "observe", "infer", "guard", "smooth", "write", "physics")


class Mode(IntEnum):
    IDLE = 0
    RAMP_IN = 1
    RUNNING = 2
    SAFE_STOP = 3
    FAULTED = 4


# The modes as plain ints for the hot path (an IntEnum attribute lookup costs ~1 us).
IDLE, RAMP_IN, RUNNING, SAFE_STOP, FAULTED = (int(m) for m in Mode)

#: Causes of a safe stop. ``servo_error``: a drive reported a hardware error (overload,
#: overheating, input voltage, ...; ``Backend.drive_errors``), latched in ``Runtime.drive_errors``.
FAULT_CAUSES = (
    "hard_limit",
    "non_finite_action",
    "stale_sensor",
    "overrun",
    "over_temperature",
    "servo_error",
)


def reanchor(
    smoother: CommandSmoother,
    state: RobotState,
    tracking: np.ndarray,
    anchored: np.ndarray,
    mode: np.ndarray | None = None,
) -> np.ndarray | None:
    """The tick's re-anchoring of the smoother at the measured state (the runtime's and the
    training env's, :class:`policies.envs.ReachTask`).

    Velocity mode: Ruckig's integrated position is kept within ``VELOCITY_TRACKING_TOLERANCE``
    of ``state.q`` in every env (:meth:`~deploy.smoothing.CommandSmoother.anchor`). Position
    mode: an env whose command is more than ``TRACKING_TOLERANCE`` from ``state.q`` is re-synced
    at ``state.q``, ``state.dq``. Torque mode: nothing.

    Args:
        smoother: The smoother to re-anchor.
        state: Estimated state (``q`` rad, ``dq`` rad/s, (envs, n)).
        tracking: (envs,) float work array (position mode's tracking error, rad).
        anchored: (envs,) int64 work array (velocity mode's anchored envs).
        mode: Optional (envs,) state-machine modes: envs in SAFE_STOP or FAULTED are not
            re-synced (position mode) and not counted (velocity mode).

    Returns:
        None when nothing moved, else an (envs,) mask (int64 or bool) of the counted envs.
    """
    if smoother.mode == "velocity":
        moved = smoother.anchor(state.q, VELOCITY_TRACKING_TOLERANCE, out=anchored)
    elif smoother.mode == "position":
        moved = smoother.tracking_error(state.q, out=tracking) > TRACKING_TOLERANCE
    else:
        return None
    if not moved.any():
        return None
    if mode is not None:
        moved &= (mode != SAFE_STOP) & (mode != FAULTED)
    if smoother.mode == "position" and moved.any():
        smoother.sync(state.q, state.dq, envs=moved)
    return moved


def _no_reset(envs: np.ndarray) -> None:
    """The reset of a policy without state."""


class SimClock:
    """Lockstep clock: the plant's own time; never waits."""

    realtime = False

    def __init__(self, period: float):
        self.period = period
        self.overruns = 0
        self.missed_periods = 0
        self.jitter = LatencyHistogram()

    def start(self) -> None:
        pass

    def wait(self) -> bool:
        """Return whether the last tick overran its period (never, in lockstep)."""
        return False


class WallClock:
    """Absolute-deadline clock for real time.

    Each tick has the deadline ``t0 + k * period``. A tick that ends after its deadline counts as an
    overrun; the missed periods are skipped (the next deadline is the next one in the future), never
    run back to back. Jitter is the lateness of each wake-up against its deadline, in ns.
    """

    realtime = True

    def __init__(self, period: float):
        self.period_ns = int(round(period * 1e9))
        self.period = period
        self.overruns = 0
        self.missed_periods = 0
        self.jitter = LatencyHistogram()
        self._next = 0

    def start(self) -> None:
        self._next = time.perf_counter_ns() + self.period_ns

    def wait(self) -> bool:
        now = time.perf_counter_ns()
        overrun = now > self._next
        if overrun:
            self.overruns += 1
            missed = (now - self._next) // self.period_ns
            self.missed_periods += int(missed)
            self._next += (missed + 1) * self.period_ns
        remaining = self._next - time.perf_counter_ns()
        if remaining > 200_000:
            time.sleep((remaining - 150_000) / 1e9)
        while time.perf_counter_ns() < self._next:  # spin the last ~150 us
            pass
        self.jitter.add(0, time.perf_counter_ns() - self._next)
        self._next += self.period_ns
        return overrun


@dataclass
class RuntimeCounters:
    """Counters of one run, arrays shaped (envs,).

    Attributes:
        non_finite_actions: Ticks with a non-finite policy output (the last valid one held).
        safe_stops: Safe stops begun.
        resyncs: Position mode: the command re-anchored at the measured state (the arm was
            pushed or blocked beyond ``TRACKING_TOLERANCE``); the command stream restarts there.
        anchors: Velocity mode: ticks on which the smoother's integrated position was pulled to
            within ``VELOCITY_TRACKING_TOLERANCE`` of the measured pose; the velocity command
            itself stays continuous.
        faults: Safe stops by cause (``FAULT_CAUSES``).
    """

    non_finite_actions: np.ndarray
    safe_stops: np.ndarray
    resyncs: np.ndarray
    anchors: np.ndarray
    faults: dict[str, np.ndarray] = field(default_factory=dict)


class Runtime:
    """The control loop for ``envs`` robots behind one backend.

    Args:
        robot: Robot description.
        policy: Callable ``(envs, obs_dim) float32 -> (envs, act_dim) float32`` with a ``spec``
            attribute (:class:`~deploy.policy.OnnxPolicy`); its ``reset(envs)`` (boolean mask
            (envs,)), if it has one, is called where the policy's state must start afresh.
        backend: A :class:`~deploy.backends.base.Backend` (``read``, ``write``, ``advance``,
            ``drive_errors``), opened: :class:`~deploy.backends.sim.SimBackend` or a servo bus.
        clock: :class:`SimClock` (default) or :class:`WallClock`.
        injector: Optional :class:`~deploy.faults.FaultInjector` (simulation only).
        telemetry: Optional :class:`~deploy.telemetry.Telemetry` recorder.
        overrun_rate_limit: Fraction of overrun ticks over the last ``OVERRUN_WINDOW`` that makes
            a safe stop with the wall clock (default ``OVERRUN_RATE_LIMIT``, 5 %, our choice).

    Raises:
        ValueError: a policy of another control mode than the backend's, or an
            ``overrun_rate_limit`` outside (0, 1].
    """

    def __init__(
        self,
        robot: Robot,
        policy,
        backend,
        clock=None,
        injector=None,
        telemetry=None,
        overrun_rate_limit: float = OVERRUN_RATE_LIMIT,
    ):
        if not 0.0 < overrun_rate_limit <= 1.0:
            raise ValueError(f"overrun_rate_limit: expected in (0, 1], got {overrun_rate_limit}")
        self.overrun_rate_limit = overrun_rate_limit
        self.robot, self.policy, self.backend = robot, policy, backend
        self._reset_policy = getattr(policy, "reset", None) or _no_reset
        self.spec: PolicySpec = policy.spec
        self.spec.check_robot(robot)
        if self.spec.action.mode != backend.mode:
            raise ValueError(
                f"policy action mode '{self.spec.action.mode}' differs from the backend's control "
                f"mode '{backend.mode}'"
            )
        envs, n = backend.envs, robot.n_joints
        self.envs, self.n = envs, n
        self.mode_name = backend.mode
        self.dt = robot.control_period
        self.clock = clock or SimClock(self.dt)
        self.injector = injector
        self.telemetry = telemetry
        self.estimator = JointStateEstimator(robot, envs)
        self.kinematics = Kinematics(robot)
        self.guard = SafetyGuard(robot, envs, self.mode_name)
        self.smoother = CommandSmoother(robot, envs, self.mode_name)
        self.state = RobotState.zeros(envs, n, robot.config.sensors.ambient_temperature)
        self.goal = np.zeros((envs, 3))
        self.mode = np.full(envs, Mode.IDLE, dtype=np.int8)
        self.cause = np.full(envs, -1, dtype=np.int8)  # index into FAULT_CAUSES
        #: (envs, n) int64, OR of the hardware error bits each drive reported (cause servo_error)
        self.drive_errors = np.zeros((envs, n), dtype=np.int64)
        self.counters = RuntimeCounters(
            non_finite_actions=np.zeros(envs, dtype=np.int64),
            safe_stops=np.zeros(envs, dtype=np.int64),
            resyncs=np.zeros(envs, dtype=np.int64),
            anchors=np.zeros(envs, dtype=np.int64),
            faults={c: np.zeros(envs, dtype=np.int64) for c in FAULT_CAUSES},
        )
        self.latency = LatencyHistogram(len(STAGES))
        self.tick_cost = LatencyHistogram()
        self.ticks = 0
        self.time = 0.0
        self._obs = np.zeros((envs, self.spec.obs_dim), dtype=np.float32)
        self._action = np.zeros((envs, n), dtype=np.float32)
        self._last_valid_action = np.zeros((envs, n), dtype=np.float32)
        self._nan_streak = np.zeros(envs, dtype=np.int64)
        self._target = np.zeros((envs, n))
        self._cmd = np.zeros((envs, n))
        self._overrun_ring = np.zeros(OVERRUN_WINDOW, dtype=bool)
        self._stamps = np.zeros(len(STAGES) + 1, dtype=np.int64)
        self._home = np.asarray(robot.home)
        self._stop_damping = STOP_DAMPING * robot.effort_limit
        self._tracking = np.zeros(envs)
        self._anchored = np.zeros(envs, dtype=np.int64)
        # velocity mode: the position the commands integrate to (Ruckig's state), else None
        self._commanded = self.smoother.position if self.mode_name == "velocity" else None
        #: the estimator's control input: the acceleration commanded over the last period (the
        #: smoother's trajectory); torque mode commands no motion, the filter runs without one
        self._input = None if self.mode_name == "torque" else self.smoother.mean_acceleration
        # the thermal band of the derating law the guard and the drives share
        self._temp_start = self.guard.derating.start
        self._temp_max = self.guard.derating.maximum

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Anchor every stage at the measured state and enter RAMP_IN.

        Waits (``backend.advance()``, the drives holding their initial command) up to
        ``START_TIMEOUT`` s for a reading of every joint: with encoder latency the first readings
        arrive a few ticks late.

        Raises:
            RuntimeError: some joint sent no reading within ``START_TIMEOUT``.
        """
        if self.clock.realtime:  # wall clock: the policy's first call (slow) before the anchor
            self.policy(self._obs)
        frame = self.backend.read()
        for _ in range(int(np.ceil(START_TIMEOUT / self.dt))):
            if not np.isnan(frame.position).any():
                break
            self.backend.advance()
            if self.clock.realtime:  # hardware: advance returns at once, the clock paces
                time.sleep(self.dt)
            frame = self.backend.read()
        missing = np.isnan(frame.position)
        if missing.any():
            raise RuntimeError(
                f"Runtime.start: no encoder reading for joints {np.argwhere(missing).tolist()} "
                f"(env, joint) within {START_TIMEOUT} s; cannot anchor the estimator at a "
                "measured pose"
            )
        q = frame.position.copy()
        self.estimator.reset(q, frame.position_stamp)
        self.state.q[:] = q
        self.state.dq[:] = 0.0
        self.guard.reset(q)
        self.smoother.reset(q, self.state.dq)
        self.mode[:] = RAMP_IN
        self._reset_policy(np.ones(self.envs, dtype=bool))
        self.clock.start()

    def reset_faults(self, envs: np.ndarray | None = None) -> None:
        """Clear latched faults (an operator's reset): FAULTED envs start again with RAMP_IN.

        Args:
            envs: Optional boolean mask (envs,) of the envs to reset; default all. Other envs are
                untouched (sessions batched in one runtime stay independent).
        """
        faulted = self.mode == Mode.FAULTED
        if envs is not None:
            faulted &= np.asarray(envs, dtype=bool)
        self.mode[faulted] = Mode.RAMP_IN
        self.cause[faulted] = -1
        self.guard.reset(self.state.q, envs=faulted)
        self.smoother.sync(self.state.q, self.state.dq, envs=faulted)
        self._reset_policy(faulted)

    # ------------------------------------------------------------------ the tick
    def tick(self) -> None:
        """One control period for every env (see the module docstring)."""
        st, clock_ns = self._stamps, time.perf_counter_ns
        st[0] = clock_ns()
        if self.injector is not None:
            self.injector.before_read(self.time)
        frame = self.backend.read()
        if self.injector is not None:
            frame = self.injector.filter_frame(self.time, frame)
        drive_errors = self.backend.drive_errors()  # None: drives without error reports
        st[1] = clock_ns()
        state = self.estimator.update(frame, self.state, self._input)
        self.kinematics.update(state)
        self.guard.update_thermal(state.winding_temperature)
        self._supervise(state, drive_errors)
        st[2] = clock_ns()
        obs = self.spec.observation(state, self.goal, out=self._obs)
        st[3] = clock_ns()
        action = self._screen(self.policy(obs))
        st[4] = clock_ns()
        target = self.spec.action_to_target(action, state, out=self._target)
        target = self._override(target, state)
        target = self.guard.filter(target, state, out=target, commanded_position=self._commanded)
        self._on_violation()
        st[5] = clock_ns()
        cmd = self.smoother.step(target, out=self._cmd)
        st[6] = clock_ns()
        self.backend.write(cmd)
        st[7] = clock_ns()
        self.backend.advance()
        st[8] = clock_ns()
        state.last_action[:] = action
        self.ticks += 1
        self.time += self.dt
        self.latency.add_stages(st)
        self.tick_cost.add(0, st[8] - st[0] - (st[8] - st[7]))  # runtime cost without physics
        if self.telemetry is not None:
            self.telemetry.record(self)
        overrun = self.clock.wait()
        self._overrun_ring[self.ticks % OVERRUN_WINDOW] = overrun

    # ------------------------------------------------------------------ stages' helpers
    def _screen(self, action: np.ndarray) -> np.ndarray:
        """Non-finite output: hold the last valid action and count; too many in a row: safe stop."""
        if self.injector is not None:
            action = self.injector.filter_action(self.time, action)
        if np.isfinite(action).all():  # the common case
            self._action[:] = action
            self._last_valid_action[:] = action
            self._nan_streak[:] = 0
            return self._action
        bad = ~np.isfinite(action).all(axis=1)
        self.counters.non_finite_actions += bad
        self._nan_streak[bad] += 1
        self._action[:] = np.where(bad[:, None], self._last_valid_action, action)
        self._safe_stop(self._nan_streak >= NAN_ACTION_LIMIT, "non_finite_action")
        self._nan_streak[~bad] = 0
        self._last_valid_action[~bad] = action[~bad]
        return self._action

    def _supervise(self, state: RobotState, drive_errors: np.ndarray | None) -> None:
        """Stale sensors, over-temperature, drive errors, overruns; end of RAMP_IN and of safe
        stops."""
        stale = (self.estimator.time_since_fresh > self.robot.config.safety.stale_limit).any(axis=1)
        self._safe_stop(stale, "stale_sensor")
        hot = (state.winding_temperature > self._temp_max).any(axis=1)
        self._safe_stop(hot, "over_temperature")
        if drive_errors is not None and drive_errors.any():
            self.drive_errors |= drive_errors
            self._safe_stop(drive_errors.any(axis=1), "servo_error")
        if self.clock.realtime and self._overrun_ring.mean() > self.overrun_rate_limit:
            self._safe_stop(np.ones(self.envs, dtype=bool), "overrun")

        mode = self.mode
        if not (mode == RUNNING).all():  # else nothing to end (the common case)
            at_rest = (np.abs(state.dq) < REST_SPEED).all(axis=1)
            home = (np.abs(state.q - self._home) < HOME_TOLERANCE).all(axis=1)
            took_over = (mode == RAMP_IN) & at_rest & home
            if took_over.any():
                mode[took_over] = RUNNING
                self._reset_policy(took_over)  # the policy starts from its initial state
            stopped = (mode == SAFE_STOP) & at_rest
            if stopped.any():
                thermal = self.cause == FAULT_CAUSES.index("over_temperature")
                cool = (state.winding_temperature < self._temp_start).all(axis=1)
                resume = stopped & thermal & cool
                mode[stopped & ~thermal] = FAULTED
                if resume.any():
                    mode[resume] = RAMP_IN
                    self.cause[resume] = -1
                    self.smoother.sync(state.q, state.dq, envs=resume)
                    self._reset_policy(resume)
        moved = reanchor(self.smoother, state, self._tracking, self._anchored, self.mode)
        if moved is not None:
            counter = (
                self.counters.anchors if self.mode_name == "velocity" else self.counters.resyncs
            )
            counter += moved

    def _safe_stop(self, which: np.ndarray, cause: str) -> None:
        if not which.any():
            return
        new = which & (self.mode != SAFE_STOP) & (self.mode != FAULTED)
        if new.any():
            self.mode[new] = SAFE_STOP
            self.cause[new] = FAULT_CAUSES.index(cause)
            self.counters.safe_stops += new
            self.counters.faults[cause] += new
            self.smoother.safe_stop(new)

    def _on_violation(self) -> None:
        self._safe_stop(self.guard.hard_violation, "hard_limit")

    def _override(self, target: np.ndarray, state: RobotState) -> np.ndarray:
        """Targets of the envs not RUNNING: ramp to home, or stop and hold."""
        mode = self.mode
        if (mode == RUNNING).all():
            return target
        ramp = mode == RAMP_IN
        hold = (mode == SAFE_STOP) | (mode == FAULTED) | (mode == IDLE)
        q, dq = state.q, state.dq
        if self.mode_name == "position":
            # stop: where the joint comes to rest at the acceleration limit
            stop = q + dq * np.abs(dq) / (2.0 * self.robot.acceleration_limit)
            target[ramp] = self._home
            target[hold] = np.clip(stop[hold], self.robot.soft_lower, self.robot.soft_upper)
        elif self.mode_name == "velocity":
            target[ramp] = RAMP_GAIN * (self._home - q[ramp])
            target[hold] = 0.0
        else:
            for e in np.nonzero(ramp | hold)[0]:
                g = self.guard.gravity(q[e])
                if ramp[e]:
                    target[e] = g + self._stop_damping * (RAMP_GAIN * (self._home - q[e]) - dq[e])
                else:
                    target[e] = g - self._stop_damping * dq[e]
        return target

    # ------------------------------------------------------------------ running
    def run(self, ticks: int, on_tick=None) -> None:
        """Run ``ticks`` control periods with the garbage collector frozen and disabled.

        ``on_tick(runtime)``, if given, runs after each tick (goal scheduling, evaluation); when
        it returns True the run ends early (e.g. a latched fault on real hardware).
        """
        gc.collect()
        gc.freeze()
        was_enabled = gc.isenabled()
        gc.disable()
        try:
            for _ in range(ticks):
                self.tick()
                if on_tick is not None and on_tick(self):
                    break
        finally:
            if was_enabled:
                gc.enable()
            gc.unfreeze()

    def mode_names(self) -> list[str]:
        return [Mode(int(m)).name for m in self.mode]

    def cause_names(self) -> list[str | None]:
        return [FAULT_CAUSES[c] if c >= 0 else None for c in self.cause]

    # ------------------------------------------------------------------ read-only views
    @property
    def action(self) -> np.ndarray:
        """(envs, n) float32: the last tick's screened policy action in [-1, 1] (a view)."""
        return self._action

    @property
    def target(self) -> np.ndarray:
        """(envs, n): the last tick's guarded target, in the units of the control mode (position
        rad, velocity rad/s, torque N m; a view)."""
        return self._target

    @property
    def command(self) -> np.ndarray:
        """(envs, n): the command the last tick wrote to the backend, in the units of the
        control mode (position rad, velocity rad/s, torque N m; a view)."""
        return self._cmd
