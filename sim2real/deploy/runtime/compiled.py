"""The compiled supervision and action screen of the runtime (:class:`CompiledSupervision`): the
constants and work arrays of the kernels of :mod:`sim2real.deploy.runtime.supervision_kernel`, their
arguments over the runtime's arrays, and what Python does where a kernel says (the smoother's safe
stops and re-syncs, policy resets, re-anchoring, the torque-mode overrides).

Each kernel is called once on copies when :class:`CompiledSupervision` is built: compiled (or
loaded from numba's cache) then, not in the first tick. The numpy reference is
:class:`sim2real.deploy.runtime.supervision.Supervision`; both give the same numbers bit for bit
(``tests/test_compiled_tick.py``). :meth:`CompiledSupervision.estimate_observe` runs a fixed-base
robot's estimate and observe stages (estimator, kinematics, supervision, observation) in one
call (:mod:`sim2real.deploy.runtime.fused_kernel`) over a table of addresses
(``tests/test_fused_estimate.py``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.modes import (
    FAULT_CAUSES,
    HOME_TOLERANCE,
    NAN_ACTION_LIMIT,
    RAMP_GAIN,
    REST_SPEED,
    Mode,
)
from sim2real.deploy.core.state import Kinematics, RobotState
from sim2real.deploy.runtime import fused_kernel as fk
from sim2real.deploy.runtime import supervision_kernel as sv
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


class CompiledSupervision:
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
        s = supervision
        self.robot, self.mode_name = s.robot, s.mode_name
        self.envs, self.n = s.envs, s.robot.n_joints
        self.estimator, self.guard, self.smoother = s.estimator, s.guard, s.smoother
        self.clock, self.overrun_rate_limit = s.clock, s.overrun_rate_limit
        self.mode, self.cause, self.counters, self._faults = s.mode, s.cause, s.counters, s.faults
        self.drive_errors, self.stop_ticks = s.drive_errors, s.stop_ticks
        self._action, self._last_valid_action = s.action, s.last_valid_action
        self._nan_streak, self._overrun_ring = s.nan_streak, s.overrun_ring
        self._home, self._at_rest, self._stop_timeout = s.home, s.at_rest, s.stop_timeout
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
                robot.config.safety.stale_limit,
                self.overrun_rate_limit,
                REST_SPEED,
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
        self._screen_cached = self._screen_args(None, self.state)[2:]
        sv.supervise(*self._supervise_args(self.state, copy=True))
        sv.screen_action(*self._screen_args(self._action, self.state, copy=True))
        #: :meth:`estimate_observe`'s end-effector kinematics (built on its first call), its
        #: table of addresses, the arrays it was built over (compared by identity each call)
        #: and every array it points to (kept alive with it)
        self._kinematics: Kinematics | None = None
        self._table = np.zeros(fk.SIZE, dtype=np.int64)
        self._table_key: tuple = ()
        self._table_arrays: list[np.ndarray] = []
        #: :meth:`estimate_observe` runs the separate stages (no fused call for this robot,
        #: policy or estimator input), or the fused call after checking its arrays
        self._fused = False
        fk.screen.compile(fk.SCREEN_SIGNATURE)  # compiled (or loaded from numba's cache) now
        if state.base is None:  # a fixed base: the fused call too
            fk.estimate_observe.compile(fk.SIGNATURE)

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
        #: table, the kernel is called with its arguments), the table, the arrays it points to
        #: (kept alive with it) and the last action array seen
        self._screen_action = self._screen_seen = None
        self._screen_table = np.zeros(fk.SCREEN_SIZE, dtype=np.int64)
        self._screen_arrays: list[np.ndarray] = []

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
        if state is self.state:
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
            self.smoother.safe_stop(flags[sv.NEW_STOP].copy())
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
            code = fk.screen(self._screen_table)
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

    def _bind_screen(self, action: np.ndarray) -> None:
        """Build the screen's table over ``action`` (the policy's output buffer) and the
        runtime's arrays, if every one has the kernel's dtype, shape and layout."""
        table, arrays = np.zeros(fk.SCREEN_SIZE, dtype=np.int64), []
        c, state, envs, n = self._screen_cached, self.state, self.envs, self.n
        f4, f8, i8, e = np.float32, np.float64, np.int64, (self.envs, self.n)
        checks = [
            fk.put(table, arrays, fk.S_ACTION, action, f4, e),
            *(
                fk.put(table, arrays, index, array, dtype, shape)
                for index, array, dtype, shape in (
                    (fk.S_SCREENED, c[0], f4, e),
                    (fk.S_LAST_VALID, c[1], f4, e),
                    (fk.S_NAN_STREAK, c[2], i8, (envs,)),
                    (fk.S_NON_FINITE, c[3], i8, (envs,)),
                    (fk.S_MODE, c[5], np.int8, (envs,)),
                    (fk.S_CAUSE, c[6], np.int8, (envs,)),
                    (fk.S_SAFE_STOPS, c[7], i8, (envs,)),
                    (fk.S_FAULTS, c[8], i8, (len(c[8]), envs)),
                    (fk.S_FLAGS, c[9], np.bool_, (4, envs)),
                    (fk.S_ACT, c[10], f8, (3, n)),
                    (fk.S_Q, state.q, f8, e),
                    (fk.S_DQ, state.dq, f8, e),
                    (fk.S_HOME, c[14], f8, (n,)),
                    (fk.S_LIMITS, c[15], f8, (3, n)),
                    (fk.S_RAMP_GAIN, np.array([c[16]], dtype=f8), f8, (1,)),
                    (fk.S_TARGET, c[17], f8, e),
                )
            ),
            c[12] is state.q and c[13] is state.dq,
        ]
        if all(checks):
            table[: fk.S_CAUSES + 1] = (envs, n, self._control, c[4], bool(c[11]), len(c[8]))
            self._screen_table, self._screen_arrays = table, arrays
            self._screen_action = action

    # ------------------------------------------------------------------ the fused call
    def estimate_observe(
        self,
        frame: SensorFrame,
        drive_errors: np.ndarray | None,
        acceleration: np.ndarray | None,
        spec: PolicySpec,
        goal: np.ndarray,
        out: np.ndarray,
    ) -> np.ndarray:
        """A fixed-base robot's estimate and observe stages in one compiled call
        (:func:`sim2real.deploy.runtime.fused_kernel.estimate_observe`), the same numbers as
        ``estimator.update(frame, state, acceleration)``, ``Kinematics.update(state)``,
        :meth:`supervise` and ``spec.observation(state, goal, out=out)`` in that order, on the
        runtime's state; Python then acts where the supervision says, as :meth:`supervise`.

        Args:
            frame: The backend's sensor frame (position, stamps, time, winding temperatures).
            drive_errors: (envs, n) int64 error bits the drives reported, or None.
            acceleration: (envs, n) rad/s^2, the estimator's control input, or None.
            spec: The policy's spec. goal: (envs, 3) m. out: float32 (envs, obs_dim).

        Returns:
            ``out``, the observation.

        The call's table is built again when one of these arrays (or the state's ``q``) is
        another than at the last call. A floating-base state, a plan that runs the numpy
        reference, an end effector the compiled chain cannot compute, or arrays of other dtypes
        or layouts run the four stages one by one instead.

        Raises:
            RuntimeError: the estimator was not reset. ValueError: a frame of the wrong shape.
            SpecError: a floating-base observation block and a state without a base.
        """
        est = self.estimator
        if not est._all_initialized:
            raise RuntimeError("JointStateEstimator.update before reset(q, t) of every env")
        k = self._table_key
        if not (
            k
            and frame.position is k[0]
            and frame.position_stamp is k[1]
            and frame.time is k[2]
            and frame.winding_temperature is k[3]
            and acceleration is k[4]
            and spec is k[5]
            and goal is k[6]
            and out is k[7]
            and self.state.q is k[8]
        ):
            self._bind_table(frame, acceleration, spec, goal, out)
        if not self._fused:
            return self._separate(frame, drive_errors, acceleration, spec, goal, out)
        if est._copy_input:
            np.copyto(est._u, acceleration)
        if drive_errors is not None:
            self._note_drive_errors(drive_errors)
        code = fk.estimate_observe(self._table, 0)
        if code & fk.RECOVER:  # a degenerate joint filter: re-initialized, then the rest
            est._recover(code >> fk.STATUS_SHIFT, frame)
            code = fk.estimate_observe(self._table, 1)
        if code:
            self._act_on(code, self.state)
        return out

    def _separate(self, frame, drive_errors, acceleration, spec, goal, out) -> np.ndarray:
        """:meth:`estimate_observe` as four calls (its fallback)."""
        state = self.estimator.update(frame, self.state, acceleration)
        self._kinematics.update(state)
        self.supervise(state, drive_errors)
        return spec.observation(state, goal, out=out)

    def _bind_table(self, frame, acceleration, spec, goal, out) -> None:
        """Check the arrays of :meth:`estimate_observe`'s call and build its table (or decide
        for the separate stages)."""
        state, est = self.state, self.estimator
        est._bind(frame, state, acceleration)  # checks the frame; the estimator's own arguments
        self._table_key = (
            frame.position,
            frame.position_stamp,
            frame.time,
            frame.winding_temperature,
            acceleration,
            spec,
            goal,
            out,
            state.q,
        )
        if self._kinematics is None:
            self._kinematics = Kinematics(self.robot)
        kin, plan = self._kinematics, spec._plan
        self._fused = False
        if state.base is not None or not plan.compiled or not (kin.compiled or kin.frame_id < 0):
            return
        envs, n = self.envs, self.n
        observe = plan._kernel_args(state, goal, out, envs)  # grows the plan's buffers first
        table, arrays = np.zeros(fk.SIZE, dtype=np.int64), []
        f8, i8, b1 = np.float64, np.int64, np.bool_

        def put(index: int, array, dtype, shape: tuple, rows: bool = False) -> bool:
            return fk.put(table, arrays, index, array, dtype, shape, rows)

        sup = self._supervise_cached
        layout, periods, raw, blocks = (
            plan.layout,
            plan.block_periods,
            observe[-2],
            len(plan.layout),
        )
        e, ea = (envs, n), est._args
        checks = [
            put(fk.Z, frame.position, f8, e),
            put(fk.TS, frame.position_stamp, f8, e),
            put(fk.NOW, frame.time, f8, (envs,)),
            put(fk.TEMP_IN, frame.winding_temperature, f8, e),
            put(fk.U, ea[4], f8, e),
            put(fk.FILT, est._filt, f8, (8, envs, n)),
            put(fk.CONSTS, est._consts, f8, (4, n)),
            put(fk.COUNTS, est._counts, i8, (3, envs, n)),
            put(fk.EST_FLAGS, est._flags, b1, (2, envs, n)),
            est.time_since_fresh is sup[4] and np.shares_memory(sup[4], est._filt[7]),
            put(fk.Q, state.q, f8, e),
            put(fk.DQ, state.dq, f8, e),
            put(fk.TEMP, state.winding_temperature, f8, e),
            sup[1] is state.winding_temperature and sup[10] is state.q and sup[11] is state.dq,
            put(fk.EE_POSITION, state.ee_position, f8, (envs, 3)),
            put(fk.EE_ROTATION, state.ee_rotation, f8, (envs, 3, 3)),
            put(fk.LAST_ACTION, state.last_action, f8, e),
            put(fk.DERATING, sup[2], f8, (3, n)),
            put(fk.EFFORT_SCALE, sup[3], f8, e),
            put(fk.DRIVE_ANY, sup[5], b1, (envs,)),
            put(fk.DRIVE_ERRORS, sup[6], i8, e),
            put(fk.OVERRUN_RING, sup[7], i8, sup[7].shape),
            put(fk.PARAMS, sup[9], f8, (7,)),
            put(fk.HOME, sup[12], f8, (n,)),
            put(fk.COMMANDED, sup[13], f8, e),
            put(fk.MODE, sup[14], np.int8, (envs,)),
            put(fk.CAUSE, sup[15], np.int8, (envs,)),
            put(fk.SAFE_STOPS, sup[16], i8, (envs,)),
            put(fk.FAULTS, sup[17], i8, sup[17].shape),
            put(fk.STOP_TICKS, sup[18], i8, (envs,)),
            put(fk.STOP_TIMEOUTS, sup[19], i8, (envs,)),
            put(fk.FLAGS, sup[20], b1, (4, envs)),
            put(fk.LAYOUT, layout, i8, layout.shape),
            put(fk.PERIODS, periods, f8, (blocks,)),
            put(fk.GOAL, goal, f8, (envs, 3)),
            observe[9] is observe[10] is observe[11] is observe[12],
            put(fk.VECTOR, observe[9], f8, (envs, 3), rows=True),
            put(fk.ORIENTATION, observe[13], f8, (envs, 4), rows=True),
            put(fk.CLOCK, observe[14], f8, (envs,), rows=True),
            put(fk.CONTACT, observe[15], f8, (envs, 0), rows=True),
            put(fk.NORM, plan.norm, f8, (3, plan.dim)),
            put(fk.RAW, raw, f8, (envs, plan.dim), rows=True),
            put(fk.OUT, out, np.float32, (envs, plan.dim)),
        ]
        if kin.compiled:
            chain, placements, work = kin.chain
            joints = len(chain) - 1
            checks += [
                put(fk.CHAIN, chain, i8, (joints + 1, 3)),
                put(fk.PLACEMENTS, placements, f8, (joints + 1, 3, 4)),
                put(fk.WORK, work, f8, (joints + 1, 3, 4)),
            ]
        else:
            joints = 0
        if not all(checks):
            return
        table[: fk.EXTRAPOLATES + 1] = (
            envs, n, joints, blocks, layout.shape[1], plan.dim, raw.shape[0], len(sup[7]),
            len(sup[17]), 0, sup[0], bool(sup[8]), bool(ea[-1]),
        )  # fmt: skip
        self._table, self._table_arrays, self._fused = table, arrays, True
