"""Ruckig inside the :class:`~sim2real.deploy.smoothing.CommandSmoother`: the call and its errors, the
per-DoF control interfaces, the extrema of its trajectories, the anchor of its integrated
position (velocity mode), the brake, and the smoother's state dict.

Ruckig keeps the trajectory it calculated inside the ``Ruckig`` object, which its Python binding
can neither read nor set: the state dict holds Ruckig's input (``RUCKIG_INPUT_FIELDS``) beside the
smoother's arrays, and taking or loading it makes the next step recalculate from that input
(:meth:`RuckigState.recalculate`), so that a smoother loaded from a state continues bit for bit
as the one it was taken from.

:class:`RuckigState` is a base class of :class:`~sim2real.deploy.smoothing.CommandSmoother`; its methods
work on the smoother's attributes (set in ``CommandSmoother.__init__``).
"""

from __future__ import annotations

import ctypes
import re

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    RuckigError,
    Synchronization,
)

from sim2real.deploy.core.stateful import env_index, put, scalar, take
from sim2real.robots.errors import Sim2RealError

#: Ruckig's per-DoF input fields a smoother's state holds (``InputParameter`` attributes).
RUCKIG_INPUT_FIELDS = (
    "current_position",
    "current_velocity",
    "current_acceleration",
    "target_position",
    "target_velocity",
    "target_acceleration",
)

#: Rad. Ruckig's extrema of a trajectory that ends exactly at a limit come out up to ~1e-13 rad
#: beyond it (rounding); the check ignores excursions below this (the finest encoder of our robots
#: resolves 2 pi / 2^20 = 6e-6 rad).
EXTREMA_TOLERANCE = 1e-9
#: What Ruckig's binding raises on a bad input or a failed calculation: ``RuckigError``, or a
#: ``ValueError`` when its C++ result has no member in the Python ``Result`` enum (e.g. -101).
RUCKIG_ERRORS = (RuckigError, ValueError)
# Ruckig's results of a good update (module constants: an enum member's lookup costs per tick)
_WORKING, _FINISHED = Result.Working, Result.Finished


def doubles(w: np.ndarray, row: int):
    """Row ``row`` of the C-contiguous float64 block ``w`` as a ctypes array of doubles over
    the same memory (which it keeps alive through ``w``)."""
    view = (ctypes.c_double * w.shape[1]).from_address(w[row].ctypes.data)
    view._keep = w  # the block must outlive the view
    return view


class SmoothingError(Sim2RealError, RuntimeError):
    """Ruckig could not compute a trajectory; the message has Ruckig's result and the input."""


class RuckigState:
    """Ruckig's call, control interfaces and trajectory extrema, and the state dict, of a
    :class:`~sim2real.deploy.smoothing.CommandSmoother` (module docstring)."""

    # ------------------------------------------------------------------ state
    def _state_fields(self) -> dict[str, np.ndarray]:
        shape = (self.envs, self.n_joints)
        return {
            "command": self.command,
            "position": self.position,
            "velocity": self.velocity,
            "acceleration": self.acceleration,
            "mean_acceleration": self.mean_acceleration,
            "commanded_position": self._cmd_position2d,
            "held": self._held.reshape(shape),
            "stopping": self.stopping,
            "non_finite_per_joint": self.non_finite_per_joint,
            "target_clamps_per_joint": self.target_clamps_per_joint,
            "extrema_violations_per_joint": self.extrema_violations_per_joint,
            "stopping_distance_clamps_per_joint": self.stopping_distance_clamps_per_joint,
        }

    def _ruckig_input(self) -> dict[str, np.ndarray]:
        """Copies of Ruckig's per-DoF input, (envs, n) (the binding returns lists)."""
        if self.mode == "torque":
            return {}
        shape = (self.envs, self.n_joints)
        return {
            f"ruckig/{name}": np.asarray(getattr(self._inp, name), dtype=np.float64).reshape(shape)
            for name in RUCKIG_INPUT_FIELDS
        }

    def recalculate(self) -> None:
        """Make the next :meth:`step` calculate every trajectory afresh from Ruckig's input
        (``Ruckig.reset()``) instead of sampling the one it keeps. The two agree to ~1e-16, not
        bit for bit (:mod:`sim2real.deploy.smoothing`); a recalculation depends on the input alone: the
        same numbers whatever the other envs of the batch, and after :meth:`load_state_dict`."""
        if self.mode != "torque":
            self._ruckig.reset()

    def state_dict(self, env: int | None = None) -> dict:
        """The smoother's state (copies; conventions of :mod:`sim2real.deploy.core.stateful`).

        Fields, (envs, n) unless stated (length 1 for one env ``env``): ``command`` (the units of
        the mode), Ruckig's state ``position``, ``velocity``, ``acceleration`` (rad, rad/s,
        rad/s^2) and ``mean_acceleration``, ``commanded_position`` (rad), ``held`` (the last
        finite target), ``stopping`` (envs,) bool, the per-joint counters (int64); Ruckig's input
        ``ruckig/<field>`` (``RUCKIG_INPUT_FIELDS``; not in torque mode) and ``synced`` (bool,
        shared).

        Ruckig keeps the trajectory it calculated inside the ``Ruckig`` object, which its Python
        binding can neither read nor set. Taking the state therefore calls :meth:`recalculate`:
        this smoother's next step calculates from the input, as a smoother loaded from this
        state does, and both continue bit for bit alike.
        """
        out: dict = take(self._state_fields(), env)
        index = env_index(env)
        out.update({k: v[index].copy() for k, v in self._ruckig_input().items()})
        out["synced"] = bool(self._synced)
        self.recalculate()
        return out

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict` (of every env, or of env ``env``): Ruckig's input is
        re-seeded (current and target position, velocity, acceleration), the per-DoF control
        interfaces follow the ``stopping`` flags, and the next step recalculates
        (:meth:`recalculate`).

        Raises:
            StateDictError: a missing field or a shape that differs; nothing is changed.
        """
        synced = scalar(state, "synced", bool)
        ruckig = self._ruckig_input()
        put({**self._state_fields(), **ruckig}, state, env)
        for key, values in ruckig.items():
            setattr(self._inp, key.split("/", 1)[1], values.reshape(-1))
        self._stop_dof[:] = np.repeat(self.stopping, self.n_joints)
        self._synced = synced
        if self.mode != "torque":
            self._set_interfaces()
        self.recalculate()

    # ------------------------------------------------------------------ the anchor
    def anchor(self, q: np.ndarray, tolerance: float, out: np.ndarray | None = None) -> np.ndarray:
        """Velocity mode: keep Ruckig's integrated position within ``tolerance`` of ``q``.

        Ruckig integrates its own velocity commands. A drive that cannot follow them (its torque
        saturates, an obstacle or a push holds the joint; its anti-windup then holds its own
        integrator back) leaves the joint behind that integral for good, and without an anchor
        the gap only grows over hours of operation: the soft-limit brake and the guard's
        stopping bounds, which read this position, then stop the joint in parts of its range
        it is nowhere near. Each joint's position is clamped into ``[q - tolerance,
        q + tolerance]``; velocity and acceleration are untouched, so the velocity command stays
        continuous. A no-op in position and torque mode (position mode re-syncs through
        :meth:`tracking_error`).

        Args:
            q: (envs, n) measured (estimated) joint positions, rad.
            tolerance: rad, the largest lag of the drive behind its command accepted as
                tracking (:data:`sim2real.deploy.runtime.VELOCITY_TRACKING_TOLERANCE` in the runtime).
            out: Optional (envs,) int64 array; 1 where an env's position was moved, else 0.

        Returns:
            (envs,) int64, 1 for the envs whose position was moved.
        """
        out = np.zeros(self.envs, dtype=np.int64) if out is None else out
        out.fill(0)
        if self.mode != "velocity":
            return out
        pos, tmp = self.position, self._tmp2d
        np.subtract(pos, q, out=tmp)
        np.abs(tmp, out=tmp)
        if tmp.max() <= tolerance:  # the common case
            return out
        np.greater(tmp, tolerance, out=self._mask.reshape(pos.shape))
        out += self._mask.reshape(pos.shape).any(axis=1)
        np.minimum(np.maximum(pos, q - tolerance, out=pos), q + tolerance, out=pos)
        self._inp.current_position = self._pos
        np.copyto(self._cmd_position, self._pos)
        return out

    # ------------------------------------------------------------------ the brake
    def brake(self, envs: np.ndarray, joints: np.ndarray | None = None) -> None:
        """Replace the last step of the selected envs by a brake: one control period of Ruckig's
        jerk-limited stop (velocity interface, target velocity and acceleration 0, the smoother's
        limits) from the state before that step. The command, Ruckig's state and input, the
        commanded position and the mean acceleration of those envs follow; the envs stay in
        normal operation (the next step plans toward their target again). The guard's motion
        envelope (:mod:`sim2real.deploy.safety.envelope`) calls it and counts it.

        Args:
            envs: (envs,) bool, the envs to brake.
            joints: Optional (envs, n) bool, only these joints of those envs (default all).

        Raises:
            ValueError: torque mode (no trajectory to brake).
            SmoothingError: Ruckig rejected the brake's input.
        """
        if self.mode == "torque":
            raise ValueError("CommandSmoother.brake: torque mode has no trajectory to brake")
        dof = np.repeat(np.asarray(envs, dtype=bool), self.n_joints)
        if joints is not None:
            dof &= np.asarray(joints, dtype=bool).reshape(-1)
        b, inp, out = self._before, self._brake_inp, self._brake_out
        inp.current_position = np.where(dof, b[0], 0.0)
        inp.current_velocity = np.where(dof, b[1], 0.0)
        inp.current_acceleration = np.where(dof, b[2], 0.0)
        # calculate afresh from this input: Ruckig would otherwise go on sampling the trajectory
        # of its last call whenever the whole batch's input repeats, so that an env's brake would
        # depend on what the other envs did (RuckigState.recalculate)
        self._braker.reset()
        try:
            result = self._braker.update(inp, out)
        except RUCKIG_ERRORS as exc:
            raise SmoothingError(f"Ruckig rejected the brake's input: {exc}") from exc
        if result != Result.Working and result != Result.Finished:
            raise SmoothingError(f"Ruckig returned {result!r} for the brake")
        pos = np.asarray(out.new_position)
        vel = np.asarray(out.new_velocity)
        acc = np.asarray(out.new_acceleration)
        self._pos[dof], self._vel[dof], self._acc[dof] = pos[dof], vel[dof], acc[dof]
        self._mean_acc[dof] = (vel[dof] - b[1][dof]) * self._inv_dt
        if self.mode == "position":
            self._cmd_position[dof] = np.clip(pos[dof], self._lo[dof], self._hi[dof])
            self._cmd[dof] = self._cmd_position[dof]
        else:
            self._cmd_position[dof] = pos[dof]
            self._cmd[dof] = vel[dof]
        main = self._inp
        for name, values in (
            ("current_position", self._pos),
            ("current_velocity", self._vel),
            ("current_acceleration", self._acc),
        ):
            current = np.array(getattr(main, name))
            current[dof] = values[dof]
            setattr(main, name, current)

    # ------------------------------------------------------------------ a failed plan
    def failed_envs(self, error: BaseException) -> np.ndarray:
        """The envs whose input made Ruckig fail (a :class:`SmoothingError` from a step, the
        brake or a safe stop).

        Ruckig names the DoF of an invalid input (``... of DoF 13 ...``): its env. A failed
        calculation names none: the envs whose current state is not finite or is past the
        smoother's velocity or acceleration limits (the states Ruckig cannot plan from), else
        every env.

        Returns:
            (envs,) bool.
        """
        which = np.zeros(self.envs, dtype=bool)
        named = re.search(r"\bdof:?\s*(\d+)", str(error), flags=re.IGNORECASE)
        if named is not None and int(named.group(1)) < self.dofs:
            which[int(named.group(1)) // self.n_joints] = True
            return which
        vel, acc = (
            np.asarray(self._inp.current_velocity),
            np.asarray(self._inp.current_acceleration),
        )
        bad = ~np.isfinite(np.asarray(self._inp.current_position)) | ~np.isfinite(vel)
        bad |= ~np.isfinite(acc) | (np.abs(vel) > self._vmax * (1.0 + 1e-6))
        bad |= np.abs(acc) > self._amax * (1.0 + 1e-6)
        which[:] = bad.reshape(self.envs, -1).any(axis=1)
        if not which.any():
            which[:] = True
        return which

    def recover(self, q: np.ndarray, dq: np.ndarray, envs: np.ndarray) -> None:
        """After a failed plan: anchor the envs of ``envs`` at the estimate and brake them.

        Ruckig's state of those envs becomes ``q`` (its own position where ``q`` is not finite)
        and ``dq`` within the velocity limits, acceleration 0, and they stop as in
        :meth:`~sim2real.deploy.smoothing.CommandSmoother.safe_stop`; should Ruckig refuse that
        too, they are anchored at rest (speed 0) and stop from there. The other envs keep their
        trajectories.

        Args:
            q: (envs, n) rad, the estimated joint positions.
            dq: (envs, n) rad/s, the estimated joint velocities.
            envs: (envs,) bool, the envs to recover.

        Raises:
            SmoothingError: Ruckig refuses even an env at rest (a limit of the robot's that is
                not finite or is zero).
        """
        shape = (self.envs, self.n_joints)
        q = np.where(np.isfinite(q), q, np.asarray(self._inp.current_position).reshape(shape))
        vmax = self._vmax.reshape(shape)
        speed = np.clip(np.nan_to_num(dq), -vmax, vmax)
        self.sync(q, speed, envs=envs)
        try:
            self.safe_stop(envs)
        except SmoothingError:
            self.sync(q, np.zeros(shape), envs=envs)
            self.safe_stop(envs)

    def follow(self, target: np.ndarray, envs: np.ndarray, out: np.ndarray) -> None:
        """A PD-target robot's envs of ``envs`` command ``target`` itself (position mode), as
        its policy was trained (``action.smoothing`` 'none').

        Its drives run a PD law on the target: a target is a torque request, and the policy
        was trained to step it from one period to the next. Ruckig's plan toward it, within
        limits a target may exceed, changed the torque asked for (a humanoid's ankle targets
        by up to 2 rad in the period after a push). The command of those envs' position-driven
        joints becomes the target, and Ruckig's state there the target at rest (velocity and
        acceleration 0), from where it plans should the env leave RUNNING (a ramp-in; a
        legged robot's stops damp the joints and take no plan). Velocity-driven joints (wheels)
        command their speed targets as emitted too (the step leaves the envs of
        :attr:`follow_envs` unclamped there), Ruckig's state there untouched.

        Args:
            target: (envs, n) rad, the guard's targets.
            envs: (envs,) bool, the envs that follow (the runtime's RUNNING envs).
            out: (envs, n) rad, the command to overwrite (this step's).

        Raises nothing; the caller passes finite targets (the guard's).
        """
        mask = self._follow_mask
        if not envs.any():
            return
        np.copyto(out, target, where=envs[:, None])
        np.logical_and(envs[:, None], self._follow_joints, out=mask)
        flat, t = self._follow_flat, target.reshape(-1)
        for row in (self._pos, self._cmd, self._cmd_position, self._held):
            np.copyto(row, t, where=flat)
        for row in (self._vel, self._acc, self._mean_acc):
            np.copyto(row, 0.0, where=flat)
        inp = self._inp
        inp.current_position = self._pos.tolist()
        inp.current_velocity = self._vel.tolist()
        inp.current_acceleration = self._acc.tolist()

    # ------------------------------------------------------------------ construction
    def _build_ruckig(self) -> None:
        """Ruckig's online generator (one control period per step) and its input and output, its
        offline planner (safe-stop durations) and the brake's generator, over the smoother's
        limits (``_vmax``, ``_amax``, ``_jmax``, flat (envs * n,)); position or velocity mode."""
        dofs, dt, mode = self.dofs, self.control_period, self.mode
        self._ruckig = Ruckig(dofs, dt)
        self._planner = Ruckig(dofs)  # offline: predicts safe-stop durations
        self._inp = inp = InputParameter(dofs)
        self._out = OutputParameter(dofs)
        inp.synchronization = Synchronization.No
        inp.max_velocity = self._vmax
        inp.max_acceleration = self._amax
        inp.max_jerk = self._jmax
        zeros = np.zeros(dofs)
        inp.current_position = zeros
        inp.current_velocity = zeros
        inp.current_acceleration = zeros
        inp.target_position = zeros
        inp.target_velocity = zeros
        inp.target_acceleration = zeros
        self._interface = (
            ControlInterface.Position if mode == "position" else ControlInterface.Velocity
        )
        inp.control_interface = self._interface
        # the brake (brake): to rest under the same limits, one control period per call
        self._braker = Ruckig(dofs, dt)
        self._brake_inp = b = InputParameter(dofs)
        self._brake_out = OutputParameter(dofs)
        b.synchronization = Synchronization.No
        b.control_interface = ControlInterface.Velocity
        b.max_velocity, b.max_acceleration, b.max_jerk = self._vmax, self._amax, self._jmax
        b.current_position = b.current_velocity = b.current_acceleration = zeros
        b.target_position = b.target_velocity = b.target_acceleration = zeros

    # ------------------------------------------------------------------ Ruckig
    def _set_interfaces(self) -> None:
        """Per-DoF control interface: velocity (target 0) for stopping envs."""
        inp = self._inp
        if not self.stopping.any():
            inp.per_dof_control_interface = None
            inp.control_interface = self._interface
        elif self.stopping.all():
            inp.per_dof_control_interface = None
            inp.control_interface = ControlInterface.Velocity
        else:
            inp.per_dof_control_interface = [
                ControlInterface.Velocity if s else self._interface for s in self._stop_dof
            ]

    def _update(self) -> None:
        try:
            result = self._ruckig.update(self._inp, self._out)
        except RUCKIG_ERRORS as exc:
            raise SmoothingError(f"Ruckig rejected the input: {exc}") from exc
        if result is not _WORKING and result is not _FINISHED:  # enum members: singletons
            raise SmoothingError(
                f"Ruckig returned {result!r}: current position {self._pos.tolist()}, velocity "
                f"{self._vel.tolist()}, acceleration {self._acc.tolist()}, targets "
                f"{self._goal.tolist()}"
            )

    def _count_extrema(self) -> None:
        """Count the DoFs marked in ``_mask`` whose new trajectory leaves the hard limits."""
        near = self._mask
        extrema = self._out.trajectory.position_extrema
        for i in np.flatnonzero(near):
            bound = extrema[i]
            if (
                bound.min < self._lo[i] - EXTREMA_TOLERANCE
                or bound.max > self._hi[i] + EXTREMA_TOLERANCE
            ):
                self.extrema_violations_per_joint.reshape(-1)[i] += 1
