"""The table calls of :class:`sim2real.deploy.runtime.compiled.CompiledSupervision`
(:class:`TableCalls`, its base): the fused estimate and observe stages of a fixed-base robot
(:meth:`TableCalls.estimate_observe`), and the building of the tables of addresses the kernels of
:mod:`sim2real.deploy.runtime.fused_kernel` take (the fused call's, the supervision's, the action
screen's), each array checked by :func:`~sim2real.deploy.kernels.calls.put`.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import Kinematics
from sim2real.deploy.kernels.calls import bind, put
from sim2real.deploy.runtime import fused_kernel as fk
from sim2real.deploy.spec.policy_spec import PolicySpec


class TableCalls:
    """The table calls of :class:`~sim2real.deploy.runtime.compiled.CompiledSupervision`, which
    sets the attributes they use (its state, estimator, supervision arrays and cached kernel
    arguments) and the tables' initial values."""

    def _bind_screen(self, action: np.ndarray) -> None:
        """Build the screen's table over ``action`` (the policy's output buffer) and the
        runtime's arrays, if every one has the kernel's dtype, shape and layout."""
        table, arrays = np.zeros(fk.SCREEN_SIZE, dtype=np.int64), []
        c, state, envs, n = self._screen_cached, self.state, self.envs, self.n
        f4, f8, i8, e = np.float32, np.float64, np.int64, (self.envs, self.n)
        checks = [
            put(table, arrays, fk.S_ACTION, action, f4, e),
            *(
                put(table, arrays, index, array, dtype, shape)
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
            self._screen_call = bind(fk.screen, table)  # no dispatch per call
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
        if not est.initialized:
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
        if self._copy_input:  # an input the kernel cannot read in place: into the estimator's
            np.copyto(self._estimator_input, acceleration)
        if drive_errors is not None:
            self._note_drive_errors(drive_errors)
        code = self._estimate_call(0)  # estimate_observe(table, 0), bound to the table
        if code & fk.RECOVER:  # a degenerate joint filter: re-initialized, then the rest
            est.recover(code >> fk.STATUS_SHIFT, frame, self.state, acceleration)
            code = self._estimate_call(1)
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
        ea = est.kernel_arrays(frame, state, acceleration)  # checks the frame; binds the estimator
        self._copy_input = acceleration is not None and ea.u is not acceleration
        self._estimator_input = ea.u
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
        kin, plan = self._kinematics, spec.plan
        self._fused = False
        if state.base is not None or not plan.compiled or not (kin.compiled or kin.frame_id < 0):
            return
        if plan.history is not None:  # its frames stack after the observation kernel: separate
            return
        if est.velocity_variance is not None and frame.velocity is not None:
            return  # the drives' velocity is absorbed after the Kalman tick (the estimator's)
        envs, n = self.envs, self.n
        observe = plan.kernel_args(state, goal, out, envs)  # grows the plan's buffers first
        table, arrays = np.zeros(fk.SIZE, dtype=np.int64), []
        f8, i8, b1 = np.float64, np.int64, np.bool_

        def at(index: int, array, dtype, shape: tuple, rows: bool = False) -> bool:
            return put(table, arrays, index, array, dtype, shape, rows)

        layout, clocks, raw, blocks = (
            plan.layout,
            plan.clocks.params,
            observe[-2],
            len(plan.layout),
        )
        e = (envs, n)
        checks = [
            at(fk.Z, frame.position, f8, e),
            at(fk.TS, frame.position_stamp, f8, e),
            at(fk.NOW, frame.time, f8, (envs,)),
            at(fk.TEMP_IN, frame.winding_temperature, f8, e),
            at(fk.U, ea.u, f8, e),
            at(fk.CONSTS, ea.consts, f8, (5, n)),
            at(fk.COUNTS, ea.counts, i8, (3, envs, n)),
            at(fk.EST_FLAGS, ea.flags, b1, (2, envs, n)),
            self._put_supervision(table, arrays),
            at(fk.EE_POSITION, state.ee_position, f8, (envs, 3)),
            at(fk.EE_ROTATION, state.ee_rotation, f8, (envs, 3, 3)),
            at(fk.LAST_ACTION, state.last_action, f8, e),
            at(fk.LAYOUT, layout, i8, layout.shape),
            at(fk.CLOCKS, clocks, f8, clocks.shape),
            at(fk.STARTS, plan.clocks.kernel, f8, (raw.shape[0], blocks)),
            at(fk.GOAL, goal, f8, (envs, 3)),
            observe[10] is observe[11] is observe[12] is observe[13],
            at(fk.VECTOR, observe[10], f8, (envs, 3), rows=True),
            at(fk.ORIENTATION, observe[14], f8, (envs, 4), rows=True),
            at(fk.CLOCK, observe[15], f8, (envs,), rows=True),
            at(fk.CONTACT, observe[16], f8, (envs, 0), rows=True),
            at(fk.NORM, plan.norm, f8, (3, plan.dim)),
            at(fk.RAW, raw, f8, (envs, plan.dim), rows=True),
            at(fk.OUT, out, np.float32, (envs, plan.dim)),
        ]
        if kin.compiled:
            chain, placements, work = kin.chain
            joints = len(chain) - 1
            checks += [
                at(fk.CHAIN, chain, i8, (joints + 1, 3)),
                at(fk.PLACEMENTS, placements, f8, (joints + 1, 3, 4)),
                at(fk.WORK, work, f8, (joints + 1, 3, 4)),
            ]
        else:
            joints = 0
        if not all(checks):
            return
        table[[fk.JOINTS, fk.BLOCKS, fk.WIDTH, fk.DIM, fk.RAW_ROWS, fk.FEET, fk.EXTRAPOLATES]] = (
            joints, blocks, layout.shape[1], plan.dim, raw.shape[0], 0, bool(ea.input_extrapolates)
        )  # fmt: skip
        self._table, self._table_arrays, self._fused = table, arrays, True
        self._estimate_call = bind(fk.estimate_observe, table, rest=(0,))

    def _put_supervision(self, table: np.ndarray, arrays: list) -> bool:
        """Put the supervision's arrays (and the state's and estimator's it reads) into an
        :func:`~sim2real.deploy.runtime.fused_kernel.estimate_observe` table, with their sizes and
        flags; whether every one fits (:func:`~sim2real.deploy.kernels.calls.put`)."""
        sup, state, est, envs, n = (
            self._supervise_cached,
            self.state,
            self.estimator,
            self.envs,
            self.n,
        )
        f8, i8, b1, e = np.float64, np.int64, np.bool_, (envs, n)
        filt = getattr(est, "filter_state", None)  # a JointStateEstimator's
        checks = [
            put(table, arrays, fk.FILT, filt, f8, (8, envs, n)),
            filt is not None
            and sup[4] is est.time_since_fresh
            and np.shares_memory(sup[4], filt[7]),
            sup[1] is state.winding_temperature and sup[10] is state.q and sup[11] is state.dq,
        ]
        for index, array, dtype, shape in (
            (fk.Q, state.q, f8, e),
            (fk.DQ, state.dq, f8, e),
            (fk.TEMP, state.winding_temperature, f8, e),
            (fk.DERATING, sup[2], f8, (3, n)),
            (fk.EFFORT_SCALE, sup[3], f8, e),
            (fk.DRIVE_ANY, sup[5], b1, (envs,)),
            (fk.DRIVE_ERRORS, sup[6], i8, e),
            (fk.OVERRUN_RING, sup[7], i8, sup[7].shape),
            (fk.PARAMS, sup[9], f8, (7,)),
            (fk.HOME, sup[12], f8, (n,)),
            (fk.COMMANDED, sup[13], f8, e),
            (fk.MODE, sup[14], np.int8, (envs,)),
            (fk.CAUSE, sup[15], np.int8, (envs,)),
            (fk.SAFE_STOPS, sup[16], i8, (envs,)),
            (fk.FAULTS, sup[17], i8, sup[17].shape),
            (fk.STOP_TICKS, sup[18], i8, (envs,)),
            (fk.STOP_TIMEOUTS, sup[19], i8, (envs,)),
            (fk.FLAGS, sup[20], b1, (4, envs)),
            (fk.HOMED, sup[21], b1, (n,)),
        ):
            checks.append(put(table, arrays, index, array, dtype, shape))
        table[[fk.ENVS, fk.N, fk.WINDOW, fk.CAUSES, fk.CONTROL, fk.REALTIME]] = (
            envs, n, len(sup[7]), len(sup[17]), sup[0], bool(sup[8])
        )  # fmt: skip
        return all(checks)
