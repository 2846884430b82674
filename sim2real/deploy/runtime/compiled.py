"""The compiled supervision and action screen of the runtime (:class:`CompiledSupervision`): the
constants and work arrays of the kernels of :mod:`sim2real.deploy.runtime.supervision_kernel`, their
arguments over the runtime's arrays, and what Python does where a kernel says (the smoother's safe
stops and re-syncs, policy resets, re-anchoring, the torque-mode overrides).

Each kernel is called once on copies when :class:`CompiledSupervision` is built: compiled (or
loaded from numba's cache) then, not in the first tick. The numpy reference is
:class:`sim2real.deploy.runtime.supervision.Supervision`; both give the same numbers bit for bit
(``tests/test_compiled_tick.py``). The supervision, the screen (once the policy's output buffer
repeats) and :meth:`CompiledSupervision.estimate_observe` (a fixed-base robot's estimate and
observe stages: estimator, kinematics, supervision, observation) run over tables of addresses
(:mod:`sim2real.deploy.runtime.fused`, ``tests/test_fused_estimate.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sim2real.deploy.core.modes import (
    FAULT_CAUSES,
    HOME_TOLERANCE,
    NAN_ACTION_LIMIT,
    RAMP_GAIN,
    Mode,
)
from sim2real.deploy.core.state import Kinematics, RobotState
from sim2real.deploy.kernels.calls import bind, fits
from sim2real.deploy.runtime import fused_kernel as fk
from sim2real.deploy.runtime import supervision_kernel as sv
from sim2real.deploy.runtime.fused import TableCalls
from sim2real.deploy.runtime.supervision import Supervision
from sim2real.deploy.spec.policy_spec import PolicySpec

# the kernels (sim2real.deploy.runtime.supervision_kernel) know the causes and modes by number
_CAUSE_CODES = {
    "hard_limit": sv.HARD_LIMIT,
    "non_finite_action": sv.NON_FINITE_ACTION,
    "stale_sensor": sv.STALE_SENSOR,
    "overrun": sv.OVERRUN,
    "over_temperature": sv.OVER_TEMPERATURE,
    "servo_error": sv.SERVO_ERROR,
    "fall": sv.FALL,
    "operator": sv.OPERATOR,
    "smoother": sv.SMOOTHER,
}
if [_CAUSE_CODES[c] for c in FAULT_CAUSES] != list(range(len(FAULT_CAUSES))) or [
    sv.IDLE,
    sv.RAMP_IN,
    sv.RUNNING,
    sv.SAFE_STOP,
    sv.FAULTED,
] != [int(m) for m in Mode]:
    raise RuntimeError(
        "sim2real.deploy.runtime.supervision_kernel: causes or modes differ from sim2real.deploy.runtime"
    )


def _same(a: np.ndarray) -> np.ndarray:
    return a


class CompiledSupervision(TableCalls):
    """The compiled path of a :class:`~sim2real.deploy.runtime.Runtime`'s supervision and action screen,
    over the arrays of its state machine (:class:`~sim2real.deploy.runtime.supervision.Supervision`),
    which the kernels update in place.

    Args:
        supervision: The runtime's state machine (its arrays, stages and ``override``).
        spec: The policy's spec (its action rows; bound again when the runtime's is replaced).
        state: The runtime's estimated state (the kernels' arguments for it are made once).
        target: (envs, n), the target the screen writes (units of the control mode).
        tracking_tolerance: The re-anchoring's tolerance, rad.
        reanchor: The runtime's re-anchoring, ``reanchor(state)``.
    """

    def __init__(
        self,
        supervision: Supervision,
        spec: PolicySpec,
        state: RobotState,
        target: np.ndarray,
        tracking_tolerance: float,
        reanchor: Callable[[RobotState], None],
    ):
        s = self._supervision = supervision
        self.robot, self.mode_name = s.robot, s.mode_name
        self.envs, self.n = s.envs, s.robot.n_joints
        self.estimator, self.guard, self.smoother = s.estimator, s.guard, s.smoother
        self.clock, self.overrun_rate_limit = s.clock, s.overrun_rate_limit
        self.mode, self.cause, self.counters, self._faults = s.mode, s.cause, s.counters, s.faults
        self.drive_errors, self.stop_ticks = s.drive_errors, s.stop_ticks
        self._action, self._last_valid_action = s.action, s.last_valid_action
        self._nan_streak, self._overrun_ring = s.nan_streak, s.overrun_ring
        self._home, self._at_rest, self._stop_timeout = s.home, s.at_rest, s.stop_timeout
        self._homed = s.homed
        # Python's part: policy resets, the torque-mode overrides (Pinocchio), re-anchoring
        self._reset_policy, self._override, self._reanchor = s.reset_policy, s.override, reanchor
        self.state, self._target, self.tracking_tolerance = state, target, tracking_tolerance

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
                robot.stale_limit,
                self.overrun_rate_limit,
                s.rest_speed,
                HOME_TOLERANCE,
                tolerance,
                self._stop_timeout,
                float(s.home_from_command),
            ]
        )
        self._bind_action(spec)
        self._limit_rows = np.ascontiguousarray(
            np.stack([robot.acceleration_limit, robot.soft_lower, robot.soft_upper]),
            dtype=np.float64,
        )
        # the smoother's commanded position, which the re-anchoring screen compares with q
        sm = self.smoother
        self._screen_commanded = sm.position if self.mode_name == "velocity" else sm.commanded
        self.flags = np.zeros((4, envs), dtype=bool)
        self.drive_any = np.zeros(envs, dtype=bool)
        # the kernels' arguments for the runtime's state, made once (the arrays are updated in
        # place), and one call of each kernel on copies
        self._supervise_cached = self._supervise_args(self.state)
        #: :meth:`supervise`'s packed table (one argument for the kernel's 22), or None where
        #: some array does not fit (then the kernel is called with its arguments)
        values = self._supervision_values()
        self._supervise_table = None if values is None else fk.SUPERVISE.pack_or_none(**values)
        if self._supervise_table is not None:  # its kernel bound to it (compiled, or loaded)
            self._supervise_call = bind(fk.supervise_only, self._supervise_table)
        self._screen_cached = self._screen_args(None, self.state)[2:]
        sv.supervise(*self._supervise_args(self.state, copy=True))
        sv.screen_action(*self._screen_args(self._action, self.state, copy=True))
        #: :meth:`estimate_observe`'s end-effector kinematics (a fixed base's; None: built on
        #: its first call) and the arrays its table was built over (compared by identity)
        self._kinematics: Kinematics | None = None
        self._table_key: tuple = ()
        #: :meth:`estimate_observe` runs the separate stages (no fused call for this robot,
        #: policy or estimator input), or the fused call after checking its arrays
        self._fused = self._copy_input = False
        #: the estimator's control input array the fused call reads, where it copies the input
        self._estimator_input: np.ndarray | None = None
        bind(fk.screen, fk.SCREEN.empty())  # compiled (or loaded from numba's cache) now
        bind(fk.supervise_only, fk.SUPERVISE.empty())
        e, m = self.envs, self.n  # action_ran's call on copies (the arrays it binds to later)
        bind(sv.action_ran, np.zeros((e, m)), np.zeros((e, m), np.float32), self.mode.copy(),
             np.zeros(e, bool), int(Mode.RUNNING))  # fmt: skip
        if state.base is None:  # a fixed base: the fused call too, and its kinematics
            bind(fk.estimate_observe, fk.FUSED.empty(), rest=(0,))
            self._kinematics = Kinematics(self.robot)

    def _bind_action(self, spec: PolicySpec) -> None:
        """The kernel's rows of ``spec.action`` (clip, scale, offset) and its reference; again
        whenever the runtime's ``spec`` is replaced."""
        a, n = spec.action, self.n
        self._act_spec = spec
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
        #: the action array the screen's table was built over (:meth:`_bind_screen`; None: no
        #: table, the kernel is called with its arguments) and the last action array seen
        self._screen_action = self._screen_seen = None
        #: ``(last_action, action, idle, call)``: :meth:`action_ran`'s call bound to those arrays
        self._ran: tuple | None = None

    def _supervise_args(self, state: RobotState, copy: bool = False) -> tuple:
        """Arguments of :func:`sim2real.deploy.runtime.supervision_kernel.supervise` (the written arrays
        copied
        with ``copy``, for the warm-up call)."""
        w = np.copy if copy else _same
        return (
            self._control,
            state.winding_temperature,
            self._derating,
            w(self.guard.effort_scale),
            self.estimator.time_since_fresh,
            self.drive_any,
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
            w(self.flags),
            self._homed,
        )

    def _screen_args(self, action: np.ndarray, state: RobotState, copy: bool = False) -> tuple:
        """Arguments of :func:`sim2real.deploy.runtime.supervision_kernel.screen_action` (see
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
            w(self.flags),
            self._act_rows,
            self._current,
            state.q,
            state.dq,
            self._home,
            self._limit_rows,
            RAMP_GAIN,
            w(self._target),
        )

    def supervise(self, state: RobotState, drive_errors: np.ndarray | None) -> None:
        """The thermal derating of the guard's effort limits; stale sensors, over-temperature,
        drive errors, overruns; end of RAMP_IN and of safe stops: one kernel
        (:func:`sim2real.deploy.runtime.supervision_kernel.supervise`); Python acts where it says (the
        smoother's safe stops and re-syncs, policy resets, re-anchoring)."""
        if drive_errors is not None:
            self._note_drive_errors(drive_errors)
        if state is self.state and self._supervise_table is not None:
            code = self._supervise_call()  # fk.supervise_only(self._supervise_table)
        elif state is self.state:
            code = sv.supervise(*self._supervise_cached)
        else:
            code = sv.supervise(*self._supervise_args(state))
        if code:
            self._act_on(code, state)

    def _note_drive_errors(self, drive_errors: np.ndarray) -> None:
        """Latch the drives' error bits ((envs, n) int64) and mark the envs reporting any."""
        if drive_errors.any():
            self.drive_errors |= drive_errors
            np.any(drive_errors, axis=1, out=self.drive_any)
        else:
            self.drive_any.fill(False)

    def _act_on(self, code: int, state: RobotState) -> None:
        """What Python does where :func:`~sim2real.deploy.runtime.supervision_kernel.supervise`
        returned ``code``: the smoother's safe stops and re-syncs, policy resets, re-anchoring."""
        flags = self.flags
        if code & sv.SUPERVISE_STOP:
            new = flags[sv.NEW_STOP].copy()
            self.smoother.safe_stop(new)
            stale = new & (self.cause == sv.STALE_SENSOR)
            if stale.any() and self._supervision.on_stale_stop is not None:
                self._supervision.on_stale_stop(stale)  # what went stale (runtime.stale)
        if code & sv.SUPERVISE_TOOK_OVER:
            self._reset_policy(flags[sv.TOOK_OVER].copy())
        if code & sv.SUPERVISE_RESUME:
            resume = flags[sv.RESUMED].copy()
            self.smoother.sync(state.q, self._at_rest, envs=resume)
            self._reset_policy(resume)
        if code & (sv.SUPERVISE_RESUME | sv.SUPERVISE_ANCHOR):
            self._reanchor(state)

    def screen(self, action: np.ndarray, state: RobotState, spec: PolicySpec) -> None:
        """The screen of the policy's output (non-finite: hold the last valid action and count;
        too many in a row: safe stop), ``spec.action_to_target`` and the overrides of the envs
        not RUNNING, into the runtime's screened action and target: one kernel
        (:func:`sim2real.deploy.runtime.supervision_kernel.screen_action`); Python starts the smoother's safe
        stop of a new non-finite-action stop and, in torque mode, the overrides (Pinocchio's
        gravity)."""
        if spec is not self._act_spec:
            self._bind_action(spec)
            self._screen_cached = self._screen_args(None, self.state)[2:]
        if state is not self.state:
            code = sv.screen_action(*self._screen_args(action, state))
        elif action is self._screen_action:  # its table is built
            code = self._screen_call()  # fk.screen of its packed table
        else:
            code = sv.screen_action(self._control, action, *self._screen_cached)
            if action is self._screen_seen:  # the second call in a row with this array
                self._bind_screen(action)
            self._screen_seen = action
        if code:
            if code & sv.SCREEN_STOP:
                self.smoother.safe_stop(self.flags[sv.NEW_STOP].copy())
            if code & sv.SCREEN_OVERRIDE:
                self._override(self._target, state)

    def action_ran(self, state: RobotState, action: np.ndarray, idle: np.ndarray) -> bool:
        """``state.last_action`` = the action the drives ran: ``action`` (envs, n) float32 for
        the RUNNING envs, 0 for the others, which ``idle`` (envs,) bool marks; one kernel
        (:func:`sim2real.deploy.runtime.supervision_kernel.action_ran`) bound to these arrays
        (made again when one is another array). Returns False, having done nothing, where one
        does not fit the kernel (the caller's numpy path)."""
        last, bound = state.last_action, self._ran
        if bound is None or bound[0] is not last or bound[1] is not action or bound[2] is not idle:
            call = None
            envs, n = self.envs, self.n
            if (
                fits(last, np.float64, (envs, n))
                and fits(action, np.float32, (envs, n))
                and fits(idle, np.bool_, (envs,))
                and fits(self.mode, np.int8, (envs,))
                and last.flags.writeable
                and idle.flags.writeable
            ):
                call = bind(sv.action_ran, last, action, self.mode, idle, int(Mode.RUNNING))
            bound = self._ran = (last, action, idle, call)
        if bound[3] is None:
            return False
        bound[3]()
        return True
