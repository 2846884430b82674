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
latched until :meth:`Runtime.reset_faults`. A safe stop ends when every joint is at rest
(``REST_SPEED``) or, at the latest, ``SAFE_STOP_TIMEOUT`` after it began (a joint still moving:
pushed, dragged, or an estimate that drifts), counted in ``counters.safe_stop_timeouts``: FAULTED,
or for over-temperature, RAMP_IN as soon as it is cool, at rest or not (FAULTED if a drive has
latched an error). Only an over-temperature stop stays in SAFE_STOP longer: until cool.

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

Clocks (:mod:`deploy.clock`, importable from here too): :class:`SimClock` runs in lockstep with a
simulated plant as fast as the CPU allows; :class:`WallClock` waits for absolute deadlines (sleep,
hybrid or spin), skips missed periods instead of bursting, and counts overruns and jitter.

The garbage collector is frozen and disabled while :meth:`Runtime.run` loops.
"""

from __future__ import annotations

import gc
import time
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from deploy.clock import SimClock, WallClock  # noqa: F401 (the runtime's clocks)
from deploy.estimation import JointStateEstimator
from deploy.kernels import latency as lk
from deploy.kernels import supervision as sv
from deploy.safety import SafetyGuard
from deploy.smoothing import CommandSmoother
from deploy.spec import PolicySpec
from deploy.state import Kinematics, RobotState
from deploy.stateful import check, load_part, prefixed, put, scalar, take
from deploy.telemetry import BIN_NS, BINS, LatencyHistogram
from robots import Robot

#: Consecutive non-finite policy outputs before a safe stop (0.05 s at 200 Hz).
NAN_ACTION_LIMIT = 10
#: Fraction of overrun ticks over the last ``OVERRUN_WINDOW`` ticks that makes a safe stop.
OVERRUN_RATE_LIMIT = 0.05
OVERRUN_WINDOW = 200
#: A joint is at rest below this speed, rad/s (ends a safe stop, ends RAMP_IN).
REST_SPEED = 0.05
#: A safe stop whose joints are not all at rest this long after it began ends FAULTED anyway
#: (latched), counted in ``RuntimeCounters.safe_stop_timeouts``, s. Our choice: the smoother
#: brakes any joint from its velocity limit within ``v / a + a / j`` s (the acceleration ramp,
#: then full deceleration); the longest of the shipped robots is go2's 0.65 s (ur5 0.54, arm6
#: 0.36, so101 0.21, arm3 0.21 s), so 2 s is three times the slowest brake. A stop still moving
#: then is not braking (an estimate that drifts, a joint pushed or dragged): waiting longer
#: would leave the robot in SAFE_STOP for good. Counted in ticks, ``ceil(timeout / period)``.
SAFE_STOP_TIMEOUT = 2.0
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
    "fall",
)
# the kernels (deploy.kernels.supervision) know the causes and modes by number
_CAUSE_CODES = {
    "hard_limit": sv.HARD_LIMIT,
    "non_finite_action": sv.NON_FINITE_ACTION,
    "stale_sensor": sv.STALE_SENSOR,
    "overrun": sv.OVERRUN,
    "over_temperature": sv.OVER_TEMPERATURE,
    "servo_error": sv.SERVO_ERROR,
    "fall": sv.FALL,
}
if [_CAUSE_CODES[c] for c in FAULT_CAUSES] != list(range(len(FAULT_CAUSES))) or [
    sv.IDLE,
    sv.RAMP_IN,
    sv.RUNNING,
    sv.SAFE_STOP,
    sv.FAULTED,
] != [int(m) for m in Mode]:
    raise RuntimeError("deploy.kernels.supervision: causes or modes differ from deploy.runtime")


def reanchor(
    smoother: CommandSmoother,
    state: RobotState,
    tracking: np.ndarray,
    anchored: np.ndarray,
    mode: np.ndarray | None = None,
    tolerance: float | None = None,
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
        tolerance: The mode's tolerance, rad (default ``TRACKING_TOLERANCE`` or
            ``VELOCITY_TRACKING_TOLERANCE``); ``inf`` turns the re-anchoring off.

    Returns:
        None when nothing moved, else an (envs,) mask (int64 or bool) of the counted envs.
    """
    if smoother.mode == "velocity":
        tol = VELOCITY_TRACKING_TOLERANCE if tolerance is None else tolerance
        moved = smoother.anchor(state.q, tol, out=anchored)
    elif smoother.mode == "position":
        tol = TRACKING_TOLERANCE if tolerance is None else tolerance
        moved = smoother.tracking_error(state.q, out=tracking) > tol
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


def _same(a: np.ndarray) -> np.ndarray:
    return a


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
        safe_stop_timeouts: Safe stops whose joints were not all at rest ``SAFE_STOP_TIMEOUT``
            after they began (they end FAULTED; an over-temperature one resumes once cool).
        faults: Safe stops by cause (``FAULT_CAUSES``).
    """

    non_finite_actions: np.ndarray
    safe_stops: np.ndarray
    resyncs: np.ndarray
    anchors: np.ndarray
    safe_stop_timeouts: np.ndarray
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
        reference: Run the numpy references of the tick's numeric logic (supervision, action
            screen, observation, guard, smoother) instead of the compiled kernels of
            :mod:`deploy.kernels` (the default); both give the same numbers bit for bit
            (``tests/test_compiled_tick.py``). The estimator is the compiled one either way.

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
        reference: bool = False,
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
        self.reference = reference
        self.guard = SafetyGuard(robot, envs, self.mode_name, reference=reference)
        self.smoother = CommandSmoother(robot, envs, self.mode_name, reference=reference)
        ambient = robot.config.sensors.ambient_temperature
        self.state = RobotState.zeros(envs, n, ambient)
        self.goal = np.zeros((envs, 3))
        #: floating-base robots: the base estimate (IMU, leg kinematics) and the fall check
        self.base_estimator = self.fall_detector = None
        if robot.floating_base:
            from deploy.base_estimation import BaseStateEstimator
            from deploy.fall import FallDetector

            self.state = RobotState.legged(envs, n, robot.n_feet, ambient)
            self.base_estimator = BaseStateEstimator(robot, envs)
            self.fall_detector = FallDetector(robot, envs)
        #: (envs, 3) the velocity command of a legged robot (vx, vy m/s, yaw rate rad/s, base
        #: frame): the operator's (deploy-run --command) or the soak's schedule; write into it
        self.velocity_command = (
            self.state.command if self.state.command is not None else np.zeros((envs, 3))
        )
        #: rad: the re-anchoring's tolerance (:func:`reanchor`). A legged robot's low-gain PD
        #: lags its targets by design (they act as torques through kp), so it has none (inf).
        self.tracking_tolerance = (
            np.inf
            if robot.floating_base
            else VELOCITY_TRACKING_TOLERANCE
            if self.mode_name == "velocity"
            else TRACKING_TOLERANCE
        )
        #: (envs, n) zeros: the velocity the smoother restarts from after a stop (a stopped arm;
        #: the estimate's speed under encoder noise is not: started from 2 rad/s of noise, the
        #: first trajectory after a reset drove so101 onto its hard limits, stop after stop)
        self._at_rest = np.zeros((envs, n))
        self.mode = np.full(envs, Mode.IDLE, dtype=np.int8)
        self.cause = np.full(envs, -1, dtype=np.int8)  # index into FAULT_CAUSES
        #: (envs, n) int64, OR of the hardware error bits each drive reported (cause servo_error)
        self.drive_errors = np.zeros((envs, n), dtype=np.int64)
        self.counters = RuntimeCounters(
            non_finite_actions=np.zeros(envs, dtype=np.int64),
            safe_stops=np.zeros(envs, dtype=np.int64),
            resyncs=np.zeros(envs, dtype=np.int64),
            anchors=np.zeros(envs, dtype=np.int64),
            safe_stop_timeouts=np.zeros(envs, dtype=np.int64),
        )
        #: (envs,) int64, supervised ticks since each env's safe stop began (0 outside SAFE_STOP)
        self.stop_ticks = np.zeros(envs, dtype=np.int64)
        self._stop_timeout = max(1, int(np.ceil(SAFE_STOP_TIMEOUT / self.dt - 1e-9)))
        self._faults = np.zeros((len(FAULT_CAUSES), envs), dtype=np.int64)  # rows: views below
        self.counters.faults.update({c: self._faults[i] for i, c in enumerate(FAULT_CAUSES)})
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
        self._init_kernels()

    def _init_kernels(self) -> None:
        """Constants and work arrays of the compiled tick (:mod:`deploy.kernels.supervision`),
        and one call of each kernel on copies: compiled (or loaded from numba's cache) now, not
        in the first tick."""
        robot, envs, n, d = self.robot, self.envs, self.n, self.guard.derating
        self._control = {"position": sv.POSITION, "velocity": sv.VELOCITY}.get(
            self.mode_name, sv.TORQUE
        )
        self._derating = np.ascontiguousarray(
            np.stack([d.start, d.maximum, np.broadcast_to(d.floor, (n,))]), dtype=np.float64
        )
        tolerance = self.tracking_tolerance
        self._params = np.array(
            [
                robot.config.safety.stale_limit,
                self.overrun_rate_limit,
                REST_SPEED,
                HOME_TOLERANCE,
                tolerance,
                self._stop_timeout,
            ]
        )
        self._bind_action()
        self._limit_rows = np.ascontiguousarray(
            np.stack([robot.acceleration_limit, robot.soft_lower, robot.soft_upper]),
            dtype=np.float64,
        )
        # the smoother's commanded position, which the re-anchoring screen compares with q
        sm = self.smoother
        self._screen_commanded = sm.position if self.mode_name == "velocity" else sm.commanded
        self._flags = np.zeros((4, envs), dtype=bool)
        self._drive_any = np.zeros(envs, dtype=bool)
        # latency histograms' bins (deploy.telemetry)
        self._bins = np.array([BIN_NS, BINS], dtype=np.int64)
        if self.reference:
            return
        # the kernels' arguments for self.state, made once (the arrays are updated in place)
        self._supervise_cached = self._supervise_args(self.state)
        self._screen_cached = self._screen_args(None, self.state)[2:]
        self.spec.observation(self.state, self.goal, out=self._obs)  # builds and warms its plan
        sv.supervise(*self._supervise_args(self.state, copy=True))
        sv.screen_action(*self._screen_args(self._action, self.state, copy=True))
        lat, cost, c = self.latency, self.tick_cost, np.copy
        lk.add_stages(
            self._stamps, self._bins, c(lat.counts), c(lat.max_ns), c(cost.counts), c(cost.max_ns)
        )

    def _bind_action(self) -> None:
        """The kernel's rows of ``self.spec.action`` (clip, scale, offset) and its reference;
        again whenever ``spec`` is replaced."""
        a, n = self.spec.action, self.n
        self._act_spec = self.spec
        self._act_rows = np.ascontiguousarray(
            np.stack(
                [
                    np.full(n, float(a.clip)),
                    np.broadcast_to(np.asarray(a.scale, dtype=np.float64), (n,)),
                    np.broadcast_to(np.asarray(a.offset, dtype=np.float64), (n,)),
                ]
            )
        )
        self._current = a.reference == "current"

    def _supervise_args(self, state: RobotState, copy: bool = False) -> tuple:
        """Arguments of :func:`deploy.kernels.supervision.supervise` (the written arrays copied
        with ``copy``, for the warm-up call)."""
        w = np.copy if copy else _same
        return (
            self._control,
            state.winding_temperature,
            self._derating,
            w(self.guard.effort_scale),
            self.estimator.time_since_fresh,
            self._drive_any,
            self.drive_errors,
            self._overrun_ring,
            bool(self.clock.realtime),
            self._params,
            state.q,
            state.dq,
            self._home,
            self._screen_commanded,
            w(self.mode),
            w(self.cause),
            w(self.counters.safe_stops),
            w(self._faults),
            w(self.stop_ticks),
            w(self.counters.safe_stop_timeouts),
            w(self._flags),
        )

    def _screen_args(self, action: np.ndarray, state: RobotState, copy: bool = False) -> tuple:
        """Arguments of :func:`deploy.kernels.supervision.screen_action` (see
        :meth:`_supervise_args`)."""
        w = np.copy if copy else _same
        return (
            self._control,
            action,
            w(self._action),
            w(self._last_valid_action),
            w(self._nan_streak),
            w(self.counters.non_finite_actions),
            NAN_ACTION_LIMIT,
            w(self.mode),
            w(self.cause),
            w(self.counters.safe_stops),
            w(self._faults),
            w(self._flags),
            self._act_rows,
            self._current,
            state.q,
            state.dq,
            self._home,
            self._limit_rows,
            RAMP_GAIN,
            w(self._target),
        )

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
        if self.base_estimator is not None:  # upright as the accelerometer says, yaw 0
            acc = frame.imu_acceleration
            finite = np.isfinite(acc).all() and (np.linalg.norm(acc, axis=1) > 0).all()
            self.base_estimator.reset(frame.time, acceleration=acc if finite else None)
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
        self._ramp_in_at_rest(faulted)

    def _ramp_in_at_rest(self, envs: np.ndarray) -> None:
        """RAMP_IN for the envs of ``envs`` (bool mask) from the estimated pose, at rest: faults
        cleared, the guard and the smoother (no speed: a stopped robot) anchored there, the
        policy's state reset."""
        self.mode[envs] = RAMP_IN
        self.cause[envs] = -1
        self.guard.reset(self.state.q, envs=envs)
        self.smoother.sync(self.state.q, self._at_rest, envs=envs)
        self._reset_policy(envs)

    def restart(self, envs: np.ndarray, q: np.ndarray, t) -> None:
        """An operator's restart of the envs of ``envs`` (bool mask (envs,)) after the robot was
        moved by hand (stood back up, carried): the joint estimate re-anchored at the pose ``q``
        ((n,) or (envs, n) rad) at rest at time ``t`` (s; float or (envs,)), and the base
        estimator upright, as :meth:`start` anchors them (the estimators' counters of those envs
        are kept: a session's tallies survive its restarts); the guard and smoother at ``q``;
        latched faults cleared; RAMP_IN. Other envs are untouched.

        A filter that tracked the jump instead would hand the smoother a joint speed of tens of
        rad/s."""
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
        if self.base_estimator is not None:
            self.base_estimator.reset(t, envs=envs)
        self.state.q[envs] = q[envs]
        self.state.dq[envs] = 0.0
        self._ramp_in_at_rest(envs)

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
        if self.base_estimator is not None:
            self._update_base(frame, state)  # IMU, contacts, the gait clock; falls
        self._supervise(state, drive_errors)  # with the thermal derating of the effort limits
        st[2] = clock_ns()
        obs = self.spec.observation(state, self.goal, out=self._obs, reference=self.reference)
        st[3] = clock_ns()
        policy_output = self.policy(obs)
        st[4] = clock_ns()
        action, target = self._act(policy_output, state)  # screen, action_to_target, override
        target = self.guard.filter(target, state, out=target, commanded_position=self._commanded)
        self._on_violation()
        st[5] = clock_ns()
        cmd = self.smoother.step(target, out=self._cmd)
        if self.base_estimator is not None:  # a legged robot's every stop lies it down, damped
            damp = self.damping
            if damp.any():
                self._damp(cmd, state, damp)
        st[6] = clock_ns()
        self.backend.write(cmd)
        st[7] = clock_ns()
        self.backend.advance()
        st[8] = clock_ns()
        state.last_action[:] = action
        self.ticks += 1
        self.time += self.dt
        if self.reference:
            self.latency.add_stages(st)
            self.tick_cost.add(0, st[8] - st[0] - (st[8] - st[7]))  # runtime cost w/o physics
        else:
            lat, cost = self.latency, self.tick_cost
            lk.add_stages(st, self._bins, lat.counts, lat.max_ns, cost.counts, cost.max_ns)
        if self.telemetry is not None:
            self.telemetry.record(self)
        overrun = self.clock.wait()
        self._overrun_ring[self.ticks % OVERRUN_WINDOW] = overrun

    # ------------------------------------------------------------------ stages' helpers
    def _act(self, action: np.ndarray, state: RobotState) -> tuple[np.ndarray, np.ndarray]:
        """The policy's output to a target: the fault injector's filter, :meth:`_screen`,
        ``spec.action_to_target``, :meth:`_override`; returns ``(action, target)``, the
        screened action (float32) and the target (units of the mode), (envs, n) each.

        Compiled: one kernel (:func:`deploy.kernels.supervision.screen_action`); Python starts
        the smoother's safe stop of a new non-finite-action stop and, in torque mode, the
        overrides (Pinocchio's gravity)."""
        if self.injector is not None:
            action = self.injector.filter_action(self.time, action)
        if self.reference:
            action = self._screen(action)
            target = self.spec.action_to_target(action, state, out=self._target)
            return action, self._override(target, state)
        if self.spec is not self._act_spec:
            self._bind_action()
            self._screen_cached = self._screen_args(None, self.state)[2:]
        if state is self.state:
            code = sv.screen_action(self._control, action, *self._screen_cached)
        else:
            code = sv.screen_action(*self._screen_args(action, state))
        if code:
            if code & sv.SCREEN_STOP:
                self.smoother.safe_stop(self._flags[sv.NEW_STOP].copy())
            if code & sv.SCREEN_OVERRIDE:
                self._override(self._target, state)
        return self._action, self._target

    def _screen(self, action: np.ndarray) -> np.ndarray:
        """Non-finite output: hold the last valid action and count; too many in a row: safe stop
        (the reference of the compiled screen)."""
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
        """The thermal derating of the guard's effort limits; stale sensors, over-temperature,
        drive errors, overruns; end of RAMP_IN and of safe stops; re-anchoring.

        Compiled: one kernel (:func:`deploy.kernels.supervision.supervise`); Python acts where
        it says (the smoother's safe stops and re-syncs, policy resets, re-anchoring)."""
        if self.reference:
            self.guard.update_thermal(state.winding_temperature)
            self._supervise_reference(state, drive_errors)
            return
        if drive_errors is not None:
            if drive_errors.any():
                self.drive_errors |= drive_errors
                np.any(drive_errors, axis=1, out=self._drive_any)
            else:
                self._drive_any.fill(False)
        if state is self.state:
            code = sv.supervise(*self._supervise_cached)
        else:
            code = sv.supervise(*self._supervise_args(state))
        if code:
            flags = self._flags
            if code & sv.SUPERVISE_STOP:
                self.smoother.safe_stop(flags[sv.NEW_STOP].copy())
            if code & sv.SUPERVISE_TOOK_OVER:
                self._reset_policy(flags[sv.TOOK_OVER].copy())
            if code & sv.SUPERVISE_RESUME:
                resume = flags[sv.RESUMED].copy()
                self.smoother.sync(state.q, self._at_rest, envs=resume)
                self._reset_policy(resume)
            if code & (sv.SUPERVISE_RESUME | sv.SUPERVISE_ANCHOR):
                self._reanchor(state)

    def _supervise_reference(self, state: RobotState, drive_errors: np.ndarray | None) -> None:
        """The reference of the compiled supervision."""
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
            stopping = mode == SAFE_STOP
            ticks = self.stop_ticks
            ticks += stopping
            # at rest, or SAFE_STOP_TIMEOUT after the stop began (counted once, when reached)
            timed_out = stopping & (ticks >= self._stop_timeout)
            stopped = (stopping & at_rest) | timed_out
            if stopped.any():
                self.counters.safe_stop_timeouts += (
                    timed_out & ~at_rest & (ticks == self._stop_timeout)
                )
                thermal = self.cause == FAULT_CAUSES.index("over_temperature")
                cool = (state.winding_temperature < self._temp_start).all(axis=1)
                # a servo whose own protection tripped meanwhile has cut its torque: no resume
                latched = self.drive_errors.any(axis=1)
                resume = stopped & thermal & cool & ~latched
                faulted = stopped & (~thermal | latched)
                mode[faulted] = FAULTED
                ticks[faulted | resume] = 0
                if resume.any():
                    mode[resume] = RAMP_IN
                    self.cause[resume] = -1
                    self.smoother.sync(state.q, self._at_rest, envs=resume)
                    self._reset_policy(resume)
        self._reanchor(state)

    def _update_base(self, frame, state: RobotState) -> None:
        """A floating-base robot's tick: the base estimate from the IMU and leg kinematics, the
        feet's contact, the gait clock; an IMU silent past ``safety.stale_limit`` makes a safe
        stop (stale_sensor), a fall (:class:`deploy.fall.FallDetector`) a damped one (fall)."""
        self.base_estimator.update(frame, state.q, state.dq, out=state.base)
        state.foot_contact[:] = frame.foot_contact
        state.clock[:] = self.time
        stale = self.base_estimator.time_since_fresh > self.robot.config.safety.stale_limit
        self._safe_stop(stale, "stale_sensor")
        fallen = self.fall_detector.check(state) & ((self.mode == RUNNING) | (self.mode == RAMP_IN))
        self._safe_stop(fallen, "fall")

    @property
    def damping(self) -> np.ndarray:
        """(envs,) bool: the envs whose command damps the joints instead of holding a pose: a
        legged robot's envs in SAFE_STOP or FAULTED (holding its stance against gravity with a
        low-gain PD heated the thighs past 200 degC in simulation: it lies down instead); all
        False for an arm."""
        if self.base_estimator is None:
            return np.zeros(self.envs, dtype=bool)
        return (self.mode == SAFE_STOP) | (self.mode == FAULTED)

    def _damp(self, cmd: np.ndarray, state: RobotState, damp: np.ndarray) -> None:
        """The command of the envs of ``damp`` (bool mask): position mode, the measured pose
        (the servo's PD then only damps, ``-kd dq``); velocity mode, zero speed; torque mode,
        ``-STOP_DAMPING * effort_limit * dq``."""
        if self.mode_name == "position":
            cmd[damp] = state.q[damp]
        elif self.mode_name == "velocity":
            cmd[damp] = 0.0
        else:
            cmd[damp] = -self._stop_damping * state.dq[damp]

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
        if getattr(self.clock, "fresh", False):  # a wall clock not yet waited on: the collection
            self.clock.start()  # (tens of ms) is set-up, not the first tick's overrun
        try:
            for _ in range(ticks):
                self.tick()
                if on_tick is not None and on_tick(self):
                    break
        finally:
            if was_enabled:
                gc.enable()
            gc.unfreeze()

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        """The runtime's own per-env arrays (leading env axis)."""
        c, st = self.counters, self.state
        fields = {
            "mode": self.mode,
            "cause": self.cause,
            "goal": self.goal,
            "drive_errors": self.drive_errors,
            "action": self._action,
            "last_valid_action": self._last_valid_action,
            "nan_streak": self._nan_streak,
            "stop_ticks": self.stop_ticks,
            "target": self._target,
            "command": self._cmd,
            "counters/non_finite_actions": c.non_finite_actions,
            "counters/safe_stops": c.safe_stops,
            "counters/resyncs": c.resyncs,
            "counters/anchors": c.anchors,
            "counters/safe_stop_timeouts": c.safe_stop_timeouts,
        }
        fields.update({f"counters/faults/{k}": v for k, v in c.faults.items()})
        for name in ("q", "dq", "ee_position", "ee_rotation", "winding_temperature", "last_action"):
            fields[f"state/{name}"] = getattr(st, name)
        if st.base is not None:  # a floating base: its estimate, contacts, command, clock
            for name in ("foot_contact", "command", "clock"):
                fields[f"state/{name}"] = getattr(st, name)
            for name, value in vars(st.base).items():
                fields[f"state/base/{name}"] = value
        return fields

    def _shared_fields(self) -> dict[str, np.ndarray]:
        """Arrays the envs share: the overrun window, the wall-clock histograms."""
        fields = {
            "overrun_ring": self._overrun_ring,
            "latency/counts": self.latency.counts,
            "latency/max_ns": self.latency.max_ns,
            "tick_cost/counts": self.tick_cost.counts,
            "tick_cost/max_ns": self.tick_cost.max_ns,
        }
        jitter = getattr(self.clock, "jitter", None)
        if jitter is not None:
            fields["clock/jitter/counts"] = jitter.counts
            fields["clock/jitter/max_ns"] = jitter.max_ns
        return fields

    def _parts(self) -> dict:
        """The stages whose state is part of the runtime's: the estimator, guard and smoother,
        and the policy, backend and fault injector where they have a ``state_dict``."""
        parts = {"estimator": self.estimator, "guard": self.guard, "smoother": self.smoother}
        if self.base_estimator is not None:
            parts["base_estimator"] = self.base_estimator
        for name, part in (
            ("policy", self.policy),
            ("backend", self.backend),
            ("injector", self.injector),
        ):
            if part is not None and hasattr(part, "state_dict"):
                parts[name] = part
        return parts

    def state_dict(self, env: int | None = None) -> dict:
        """The state of the loop and of its stages (copies; conventions of
        :mod:`deploy.stateful`).

        The runtime's own fields, (envs, ...) (length 1 for one env ``env``): ``mode``,
        ``cause`` (int8), ``goal`` (envs, 3) m, ``drive_errors``, the screened ``action`` and
        ``last_valid_action`` (float32), ``nan_streak``, ``stop_ticks`` (int64, ticks since the
        safe stop began), the last ``target`` and ``command`` (the
        units of the mode), ``counters/<name>`` and ``counters/faults/<cause>`` (int64) and the
        estimated ``state/<field>`` (:class:`~deploy.state.RobotState`). Shared by the batch:
        ``ticks`` (int), ``time`` (float, s), ``overrun_ring`` (``OVERRUN_WINDOW``,) bool, the
        wall-clock histograms ``latency/*``, ``tick_cost/*`` and ``clock/*`` (measurements, not
        seeded; a wall clock's next deadline is not state: a resumed loop starts its own).
        Then each stage's ``state_dict(env)`` under its name: ``estimator/``, ``guard/``,
        ``smoother/``, and ``policy/``, ``backend/``, ``injector/`` where the policy (a
        recurrent one), the backend (:class:`~deploy.backends.sim.SimBackend`) or the fault
        injector has one.
        """
        out: dict = take(self._state_fields(), env)
        out.update({k: np.array(v, copy=True) for k, v in self._shared_fields().items()})
        out["ticks"], out["time"] = int(self.ticks), float(self.time)
        clock = self.clock
        out["clock/overruns"] = int(clock.overruns)
        out["clock/missed_periods"] = int(clock.missed_periods)
        for name, part in self._parts().items():
            out.update(prefixed(name, part.state_dict(env)))
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``; the shared fields
        either way), into a runtime built with the same robot, policy, backend kind and clock.
        A started runtime is not needed: the state replaces what :meth:`start` sets (a wall
        clock's deadlines start anew here).

        Raises:
            StateDictError: a missing field or a shape that differs, named with its stage's
                prefix (e.g. ``estimator/covariance``). The runtime's own fields are checked
                before anything is written; a stage's error leaves the stages before it loaded.
        """
        ticks, now = scalar(state, "ticks", int), scalar(state, "time", float)
        overruns = scalar(state, "clock/overruns", int)
        missed = scalar(state, "clock/missed_periods", int)
        shared = self._shared_fields()
        check(shared, state, None)
        put(self._state_fields(), state, env)
        put(shared, state, None)
        self.ticks, self.time = ticks, now
        self.clock.overruns, self.clock.missed_periods = overruns, missed
        for name, part in self._parts().items():
            load_part(name, part, state, env)
        self.clock.start()

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
