"""The table calls of :class:`sim2real.deploy.runtime.compiled.CompiledSupervision`
(:class:`TableCalls`, its base): the fused estimate and observe stages of a fixed-base robot
(:meth:`TableCalls.estimate_observe`), and the packing of the declared tables the kernels of
:mod:`sim2real.deploy.runtime.fused_kernel` take (the fused call's, the supervision's, the action
screen's), each array by the name of the kernel's argument it is.
"""

from __future__ import annotations

from inspect import signature

import numpy as np

from sim2real.deploy.core.backend import SensorFrame
from sim2real.deploy.core.state import Kinematics
from sim2real.deploy.kernels.calls import bind
from sim2real.deploy.runtime import fused_kernel as fk
from sim2real.deploy.runtime import supervision_kernel as sv
from sim2real.deploy.spec.kernel import observation
from sim2real.deploy.spec.policy_spec import PolicySpec


class TableCalls:
    """The table calls of :class:`~sim2real.deploy.runtime.compiled.CompiledSupervision`, which
    sets the attributes they use (its state, estimator, supervision arrays and cached kernel
    arguments) and the tables' initial values."""

    def _bind_screen(self, action: np.ndarray) -> None:
        """Build the screen's table over ``action`` (the policy's output buffer) and the
        runtime's arrays, if every one has the kernel's dtype, shape and layout."""
        names = signature(sv.screen_action.py_func).parameters
        values = dict(zip(names, (self._control, action, *self._screen_cached), strict=True))
        if values["q"] is not self.state.q or values["dq"] is not self.state.dq:
            return
        table = fk.SCREEN.pack_or_none(**values)
        if table is not None:
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
        if getattr(self, "cameras", None) is not None:  # the image stage runs between them
            return
        if state.base is not None or not plan.compiled or not (kin.compiled or kin.frame_id < 0):
            return
        if plan.history is not None:  # its frames stack after the observation kernel: separate
            return
        if est.velocity_variance is not None and frame.velocity is not None:
            return  # the drives' velocity is absorbed after the Kalman tick (the estimator's)
        observe = plan.kernel_args(state, goal, out, self.envs)  # grows the plan's buffers first
        names = signature(observation.py_func).parameters
        obs = dict(zip(names, observe, strict=True))
        sup = self._supervision_values()
        base = (obs["linear_velocity"], obs["angular_velocity"], obs["gravity"], obs["command"])
        if sup is None or not all(a is base[0] for a in base):  # no base: one zeros array
            return
        if obs["raw"].shape[0] < self.envs:
            return
        if kin.compiled:
            chain, placements, work = kin.chain
            joints = len(chain) - 1
        else:  # no end effector's kinematics: the kernel skips them
            chain, joints = np.zeros((1, 3), dtype=np.int64), 0
            placements, work = np.zeros((1, 3, 4)), np.zeros((1, 3, 4))
        table = fk.FUSED.pack_or_none(
            **sup, extrapolates=bool(ea.input_extrapolates), joints=joints, z=frame.position,
            ts=frame.position_stamp, now=frame.time, temperature_in=frame.winding_temperature,
            u=ea.u, filt=est.filter_state, consts=ea.consts, counts=ea.counts,
            est_flags=ea.flags, ee_position=state.ee_position, ee_rotation=state.ee_rotation,
            last_action=state.last_action, chain=chain, placements=placements, work=work,
            layout=obs["layout"], clocks=obs["clocks"], clock_starts=obs["clock_starts"],
            goal=goal, vector=base[0], orientation=obs["orientation"], clock=obs["clock"],
            contact=obs["contact"], norm=obs["norm"], raw=obs["raw"], out=out,
        )  # fmt: skip
        if table is None:
            return
        self._fused = True
        self._estimate_call = bind(fk.estimate_observe, table, rest=(0,))

    def _supervision_values(self) -> dict | None:
        """:func:`~sim2real.deploy.runtime.supervision_kernel.supervise`'s arguments by name
        (the table :data:`~sim2real.deploy.runtime.fused_kernel.SUPERVISE` packs, and the fused
        call's), or None where they are not the state's and the joint estimator's arrays."""
        state, est = self.state, self.estimator
        names = signature(sv.supervise.py_func).parameters
        values = dict(zip(names, self._supervise_cached, strict=True))
        filt = getattr(est, "filter_state", None)  # a JointStateEstimator's
        fresh = values["time_since_fresh"]
        if (
            filt is None
            or fresh is not est.time_since_fresh
            or not np.shares_memory(fresh, filt[7])
        ):
            return None
        if values["temperature"] is not state.winding_temperature:
            return None
        if values["q"] is not state.q or values["dq"] is not state.dq:
            return None
        return values
