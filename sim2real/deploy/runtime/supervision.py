"""The state machine (:class:`Supervision`): its arrays (modes, causes, counters, the screened
action) and its transitions in numpy.

:meth:`~Supervision.safe_stop`, :meth:`~Supervision.ramp_in_at_rest`, :meth:`~Supervision.override`
(the targets of the envs not RUNNING; the torque-mode ones need Pinocchio's gravity) and
:meth:`~Supervision.damp` (a legged robot's stops) serve both paths of the tick. The screen of
the policy's output and the supervision proper run in the kernels of
:mod:`sim2real.deploy.runtime.supervision_kernel` (bound by :mod:`sim2real.deploy.runtime.compiled`); their
numpy references are :class:`sim2real.deploy.runtime.reference.ReferenceSupervision`'s, which give the same
numbers bit for bit (``tests/test_compiled_tick.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sim2real.deploy.core.modes import (
    FAULT_CAUSES,
    FAULTED,
    IDLE,
    OVERRUN_WINDOW_S,
    RAMP_GAIN,
    RAMP_IN,
    RUNNING,
    SAFE_STOP,
    SAFE_STOP_TIMEOUT,
    STOP_DAMPING,
    Mode,
    RuntimeCounters,
)
from sim2real.deploy.core.state import RobotState
from sim2real.deploy.estimation.rest import rest_speed
from sim2real.deploy.kernels import any_true
from sim2real.deploy.kernels.calls import bind
from sim2real.robots import Robot


class Supervision:
    """The state machine of the envs of a :class:`~sim2real.deploy.runtime.Runtime` (one per env): its
    arrays (the runtime's too, the same arrays) and its transitions in numpy.

    Args:
        robot: Robot description.
        envs: Number of envs.
        mode_name: The control mode (``position``, ``velocity`` or ``torque``).
        estimator: The joint estimator (its ``time_since_fresh``).
        guard: The safety guard (its thermal derating band and ``gravity``).
        smoother: The command smoother (its ``safe_stop`` and ``sync``).
        clock: The runtime's clock (``realtime``: whether overruns count).
        overrun_rate_limit: Fraction of the control periods of the last ``OVERRUN_WINDOW_S``
            seconds the loop may miss before a safe stop with the wall clock (``overrun``).
        reset_policy: The policy's ``reset(envs)`` (bool mask (envs,)).
    """

    def __init__(
        self,
        robot: Robot,
        envs: int,
        mode_name: str,
        estimator,
        guard,
        smoother,
        clock,
        overrun_rate_limit: float,
        reset_policy: Callable[[np.ndarray], None],
    ):
        n = robot.n_joints
        self.robot, self.envs, self.mode_name = robot, envs, mode_name
        self.estimator, self.guard, self.smoother, self.clock = estimator, guard, smoother, clock
        self.overrun_rate_limit, self.reset_policy = overrun_rate_limit, reset_policy
        #: (envs, n) zeros: the velocity the smoother restarts from after a stop (a stopped arm;
        #: the estimate's speed under encoder noise is not: started from 2 rad/s of noise, the
        #: first trajectory after a reset drove so101 onto its hard limits, stop after stop)
        self.at_rest = np.zeros((envs, n))
        self.mode = np.full(envs, Mode.IDLE, dtype=np.int8)
        any_true(self.mode == RUNNING)  # compiled (or loaded from its cache) before the first tick
        # any_true of the guard's hard violations (the tick's safe_stop), bound to that array
        self._hard, self._any_hard = guard.hard_violation, bind(any_true, guard.hard_violation)
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
        #: Ruckig's messages of the steps it could not plan (the first few; cause ``smoother``)
        self.smoothing_errors: list[str] = []
        #: ``SAFE_STOP_TIMEOUT`` in ticks
        self.stop_timeout = max(1, int(np.ceil(SAFE_STOP_TIMEOUT / robot.control_period - 1e-9)))
        self.faults = np.zeros((len(FAULT_CAUSES), envs), dtype=np.int64)  # rows: views below
        self.counters.faults.update({c: self.faults[i] for i, c in enumerate(FAULT_CAUSES)})
        #: (envs, n) float32: the screened policy action, and the last finite one of each env
        self.action = np.zeros((envs, n), dtype=np.float32)
        self.last_valid_action = np.zeros((envs, n), dtype=np.float32)
        #: (envs,) int64: consecutive non-finite actions
        self.nan_streak = np.zeros(envs, dtype=np.int64)
        #: (window,) int64: the last ``OVERRUN_WINDOW_S`` seconds of control periods on the wall
        #: clock, 1 where the loop missed the period (:meth:`note_periods`), 0 where a tick
        #: finished in it
        window = max(1, int(np.ceil(OVERRUN_WINDOW_S / robot.control_period - 1e-9)))
        self.overrun_ring = np.zeros(window, dtype=np.int64)
        self._ring_at = 0
        self.home = np.asarray(robot.home)
        #: rad/s, every joint's estimated speed below it is at rest (ends RAMP_IN and safe
        #: stops): ``REST_SPEED`` or ``REST_SIGMAS`` of the joint filter's steady-state
        #: velocity standard deviation, whichever is larger
        #: (:func:`sim2real.deploy.estimation.rest.rest_speed`); a constant of the robot
        self.rest_speed = rest_speed(robot)
        #: RAMP_IN ends on the smoother's commanded position at home (not the estimate's): a
        #: robot with PD targets (the kind's drive targets, a legged one) in position mode,
        #: whose drives' soft PD (the gains it was trained with) holds its weight short of the
        #: home pose, which its estimate would never reach
        self.home_from_command = guard.targets.home_from_command(mode_name)
        #: the velocity-driven joints (wheels) of the smoother's command, or None
        self.wheels = getattr(smoother, "wheels", None)
        #: (n,) bool: the joints whose pose RAMP_IN's end judges against home: all but those
        #: wheels, whose command is a speed (0 in the ramp) and whose angle is any
        self.homed = np.ones(robot.n_joints, dtype=bool)
        if self.wheels is not None:
            self.homed[self.wheels.columns] = False
        self.stop_damping = STOP_DAMPING * robot.effort_limit
        # the thermal band of the derating law the guard and the drives share
        self.temp_start = self.guard.derating.start
        self.temp_max = self.guard.derating.maximum
        #: ``(envs) -> None``, told the envs ((envs,) bool) of each new ``stale_sensor`` stop
        #: (the runtime's :class:`~sim2real.deploy.runtime.stale.StaleStops`); None: nobody
        self.on_stale_stop: Callable[[np.ndarray], None] | None = None

    def mode_names(self) -> list[str]:
        """Each env's mode by name (:class:`~sim2real.deploy.core.modes.Mode`)."""
        return [Mode(int(m)).name for m in self.mode]

    def cause_names(self) -> list[str | None]:
        """Each env's fault cause by name (``FAULT_CAUSES``; None: none)."""
        return [FAULT_CAUSES[c] if c >= 0 else None for c in self.cause]

    def missed_in_last(self, periods: int) -> int:
        """Control periods the loop missed among the last ``periods`` of :attr:`overrun_ring`
        (at most its window; 0 in lockstep)."""
        ring, w = self.overrun_ring, self.overrun_ring.shape[0]
        k = min(max(int(periods), 0), w)
        return int(sum(int(ring[(self._ring_at - 1 - i) % w]) for i in range(k)))

    def note_periods(self, missed: int) -> None:
        """Write the last tick's periods into :attr:`overrun_ring`: one 0 for a tick on time,
        else ``missed`` 1s (its own period and those it skipped; ``WallClock.wait``'s return)."""
        ring, at = self.overrun_ring, self._ring_at
        w = ring.shape[0]
        if not missed:
            ring[at] = 0
            self._ring_at = (at + 1) % w
            return
        for _ in range(min(int(missed), w)):
            ring[at] = 1
            at = (at + 1) % w
        self._ring_at = at

    def ramp_in_at_rest(self, envs: np.ndarray, q: np.ndarray) -> None:
        """RAMP_IN for the envs of ``envs`` (bool mask) from the estimated pose ``q``, at rest:
        faults cleared, the guard and the smoother (no speed: a stopped robot) anchored there,
        the policy's state reset."""
        self.mode[envs] = RAMP_IN
        self.cause[envs] = -1
        self.guard.reset(q, envs=envs, drives=False)  # the drives ran on through the stop
        self.smoother.sync(q, self.at_rest, envs=envs)
        self.reset_policy(envs)

    def safe_stop(self, which: np.ndarray, cause: str) -> None:
        """SAFE_STOP, for ``cause`` (one of ``FAULT_CAUSES``), of the envs of ``which`` (bool
        mask) not already in SAFE_STOP or FAULTED: counted, and the smoother brakes them."""
        if not (self._any_hard() if which is self._hard else any_true(which)):
            return
        new = which & (self.mode != SAFE_STOP) & (self.mode != FAULTED)
        if new.any():
            self.mode[new] = SAFE_STOP
            self.cause[new] = FAULT_CAUSES.index(cause)
            self.counters.safe_stops += new
            self.counters.faults[cause] += new
            self.smoother.safe_stop(new)
            if cause == "stale_sensor" and self.on_stale_stop is not None:
                self.on_stale_stop(new)

    def smoothing_failed(self, error: BaseException, state: RobotState, every: bool) -> None:
        """A step Ruckig could not plan (``error``, a ``SmoothingError``): SAFE_STOP
        (``smoother``) of the envs it names (:meth:`~sim2real.deploy.smoothing.CommandSmoother.failed_envs`),
        or of every env with ``every``, each anchored at its estimate and braking
        (:meth:`~sim2real.deploy.smoothing.CommandSmoother.recover`). The message is kept in
        ``smoothing_errors`` (the first few)."""
        which = np.ones(self.envs, dtype=bool) if every else self.smoother.failed_envs(error)
        if len(self.smoothing_errors) < 8:
            self.smoothing_errors.append(str(error))
        self.smoother.recover(state.q, state.dq, which)
        self.safe_stop(which, "smoother")

    def override(self, target: np.ndarray, state: RobotState) -> np.ndarray:
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
            target[ramp] = self.home
            target[hold] = np.clip(stop[hold], self.robot.soft_lower, self.robot.soft_upper)
        elif self.mode_name == "velocity":
            target[ramp] = RAMP_GAIN * (self.home - q[ramp])
            target[hold] = 0.0
        else:
            for e in np.nonzero(ramp | hold)[0]:
                g = self.guard.gravity(q[e])
                if ramp[e]:
                    target[e] = g + self.stop_damping * (RAMP_GAIN * (self.home - q[e]) - dq[e])
                else:
                    target[e] = g - self.stop_damping * dq[e]
        return target

    def damp(self, cmd: np.ndarray, state: RobotState, damp: np.ndarray) -> None:
        """The command of the envs of ``damp`` (bool mask): position mode, the measured pose
        (the servo's PD then only damps, ``-kd dq``); velocity mode, zero speed; torque mode,
        ``-STOP_DAMPING * effort_limit * dq``."""
        if self.mode_name == "position":
            cmd[damp] = state.q[damp]
            if self.wheels is not None:  # a wheel's damped stop: speed 0, its kd brakes it
                self.wheels.damp(cmd, damp)
        elif self.mode_name == "velocity":
            cmd[damp] = 0.0
        else:
            cmd[damp] = -self.stop_damping * state.dq[damp]
