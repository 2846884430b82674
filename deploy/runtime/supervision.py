"""The state machine (:class:`Supervision`): its arrays (modes, causes, counters, the screened
action) and its transitions in numpy.

:meth:`~Supervision.safe_stop`, :meth:`~Supervision.ramp_in_at_rest`, :meth:`~Supervision.override`
(the targets of the envs not RUNNING; the torque-mode ones need Pinocchio's gravity) and
:meth:`~Supervision.damp` (a legged robot's stops) serve both paths of the tick;
:meth:`~Supervision.screen` and :meth:`~Supervision.supervise` are the numpy references of the
kernels of :mod:`deploy.runtime.supervision_kernel` (bound by :mod:`deploy.runtime.compiled`),
which give the same numbers bit for bit (``tests/test_compiled_tick.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from deploy.kernels import any_true
from deploy.runtime.modes import (
    FAULT_CAUSES,
    FAULTED,
    HOME_TOLERANCE,
    IDLE,
    NAN_ACTION_LIMIT,
    OVERRUN_WINDOW,
    RAMP_GAIN,
    RAMP_IN,
    REST_SPEED,
    RUNNING,
    SAFE_STOP,
    SAFE_STOP_TIMEOUT,
    STOP_DAMPING,
    Mode,
    RuntimeCounters,
)
from deploy.state import RobotState
from robots import Robot


class Supervision:
    """The state machine of the envs of a :class:`~deploy.runtime.Runtime` (one per env): its
    arrays (the runtime's too, the same arrays) and its transitions in numpy.

    Args:
        robot: Robot description.
        envs: Number of envs.
        mode_name: The control mode (``position``, ``velocity`` or ``torque``).
        estimator: The joint estimator (its ``time_since_fresh``).
        guard: The safety guard (its thermal derating band and ``gravity``).
        smoother: The command smoother (its ``safe_stop`` and ``sync``).
        clock: The runtime's clock (``realtime``: whether overruns count).
        overrun_rate_limit: Fraction of overrun ticks over the last ``OVERRUN_WINDOW`` that makes
            a safe stop with the wall clock.
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
        #: ``SAFE_STOP_TIMEOUT`` in ticks
        self.stop_timeout = max(1, int(np.ceil(SAFE_STOP_TIMEOUT / robot.control_period - 1e-9)))
        self.faults = np.zeros((len(FAULT_CAUSES), envs), dtype=np.int64)  # rows: views below
        self.counters.faults.update({c: self.faults[i] for i, c in enumerate(FAULT_CAUSES)})
        #: (envs, n) float32: the screened policy action, and the last finite one of each env
        self.action = np.zeros((envs, n), dtype=np.float32)
        self.last_valid_action = np.zeros((envs, n), dtype=np.float32)
        #: (envs,) int64: consecutive non-finite actions
        self.nan_streak = np.zeros(envs, dtype=np.int64)
        #: (OVERRUN_WINDOW,) bool: the last ticks' wall-clock overruns (the runtime writes it)
        self.overrun_ring = np.zeros(OVERRUN_WINDOW, dtype=bool)
        self.home = np.asarray(robot.home)
        #: RAMP_IN ends on the smoother's commanded position at home (not the estimate's): a
        #: legged robot in position mode, whose drives' soft PD (the gains it was trained with)
        #: holds its weight short of the home pose, which its estimate would never reach
        self.home_from_command = robot.floating_base and mode_name == "position"
        self.stop_damping = STOP_DAMPING * robot.effort_limit
        # the thermal band of the derating law the guard and the drives share
        self.temp_start = self.guard.derating.start
        self.temp_max = self.guard.derating.maximum

    def ramp_in_at_rest(self, envs: np.ndarray, q: np.ndarray) -> None:
        """RAMP_IN for the envs of ``envs`` (bool mask) from the estimated pose ``q``, at rest:
        faults cleared, the guard and the smoother (no speed: a stopped robot) anchored there,
        the policy's state reset."""
        self.mode[envs] = RAMP_IN
        self.cause[envs] = -1
        self.guard.reset(q, envs=envs)
        self.smoother.sync(q, self.at_rest, envs=envs)
        self.reset_policy(envs)

    def safe_stop(self, which: np.ndarray, cause: str) -> None:
        """SAFE_STOP, for ``cause`` (one of ``FAULT_CAUSES``), of the envs of ``which`` (bool
        mask) not already in SAFE_STOP or FAULTED: counted, and the smoother brakes them."""
        if not any_true(which):
            return
        new = which & (self.mode != SAFE_STOP) & (self.mode != FAULTED)
        if new.any():
            self.mode[new] = SAFE_STOP
            self.cause[new] = FAULT_CAUSES.index(cause)
            self.counters.safe_stops += new
            self.counters.faults[cause] += new
            self.smoother.safe_stop(new)

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
        elif self.mode_name == "velocity":
            cmd[damp] = 0.0
        else:
            cmd[damp] = -self.stop_damping * state.dq[damp]

    def screen(self, action: np.ndarray) -> np.ndarray:
        """Non-finite output: hold the last valid action and count; too many in a row: safe stop
        (the reference of the compiled screen)."""
        if np.isfinite(action).all():  # the common case
            self.action[:] = action
            self.last_valid_action[:] = action
            self.nan_streak[:] = 0
            return self.action
        bad = ~np.isfinite(action).all(axis=1)
        self.counters.non_finite_actions += bad
        self.nan_streak[bad] += 1
        self.action[:] = np.where(bad[:, None], self.last_valid_action, action)
        self.safe_stop(self.nan_streak >= NAN_ACTION_LIMIT, "non_finite_action")
        self.nan_streak[~bad] = 0
        self.last_valid_action[~bad] = action[~bad]
        return self.action

    def supervise(self, state: RobotState, drive_errors: np.ndarray | None) -> None:
        """The reference of the compiled supervision (the thermal derating and the re-anchoring
        after it are the runtime's): stale sensors, over-temperature, drive errors, overruns; end
        of RAMP_IN and of safe stops."""
        stale = (self.estimator.time_since_fresh > self.robot.config.safety.stale_limit).any(axis=1)
        self.safe_stop(stale, "stale_sensor")
        hot = (state.winding_temperature > self.temp_max).any(axis=1)
        self.safe_stop(hot, "over_temperature")
        if drive_errors is not None and drive_errors.any():
            self.drive_errors |= drive_errors
            self.safe_stop(drive_errors.any(axis=1), "servo_error")
        if self.clock.realtime and self.overrun_ring.mean() > self.overrun_rate_limit:
            self.safe_stop(np.ones(self.envs, dtype=bool), "overrun")

        mode = self.mode
        if not (mode == RUNNING).all():  # else nothing to end (the common case)
            at_rest = (np.abs(state.dq) < REST_SPEED).all(axis=1)
            pose = self.smoother.commanded if self.home_from_command else state.q
            home = (np.abs(pose - self.home) < HOME_TOLERANCE).all(axis=1)
            took_over = (mode == RAMP_IN) & at_rest & home
            if took_over.any():
                mode[took_over] = RUNNING
                self.reset_policy(took_over)  # the policy starts from its initial state
            stopping = mode == SAFE_STOP
            ticks = self.stop_ticks
            ticks += stopping
            # at rest, or SAFE_STOP_TIMEOUT after the stop began (counted once, when reached)
            timed_out = stopping & (ticks >= self.stop_timeout)
            stopped = (stopping & at_rest) | timed_out
            if stopped.any():
                self.counters.safe_stop_timeouts += (
                    timed_out & ~at_rest & (ticks == self.stop_timeout)
                )
                thermal = self.cause == FAULT_CAUSES.index("over_temperature")
                cool = (state.winding_temperature < self.temp_start).all(axis=1)
                # a servo whose own protection tripped meanwhile has cut its torque: no resume
                latched = self.drive_errors.any(axis=1)
                resume = stopped & thermal & cool & ~latched
                faulted = stopped & (~thermal | latched)
                mode[faulted] = FAULTED
                ticks[faulted | resume] = 0
                if resume.any():
                    mode[resume] = RAMP_IN
                    self.cause[resume] = -1
                    self.smoother.sync(state.q, self.at_rest, envs=resume)
                    self.reset_policy(resume)
