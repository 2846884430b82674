""":class:`ReferenceSmoother`, the numpy reference of :meth:`sim2real.deploy.smoothing.CommandSmoother.step`
around the Ruckig call: per mode, the targets clamped to the limits and the
clamps counted, the velocity-mode stopping guards near the soft limits (``|v| <=``
:func:`~sim2real.deploy.smoothing.stopping_speed` of the room left, and the exact brake trigger), the
screen of the trajectories whose extrema could leave the hard limits, and the torque-mode rate
limit.

The compiled kernels of :mod:`sim2real.deploy.smoothing.kernel` do the same, bit for bit
(``tests/test_compiled_tick.py``). :class:`ReferenceSmoother` is a
:class:`~sim2real.deploy.smoothing.CommandSmoother` (same constructor) whose step runs in numpy; it
compiles nothing.
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.smoothing import kernel as sk
from sim2real.deploy.smoothing.smoother import CommandSmoother


class ReferenceSmoother(CommandSmoother):
    """A :class:`~sim2real.deploy.smoothing.CommandSmoother` whose :meth:`step` runs the numpy reference
    around Ruckig (module docstring); the same arguments, attributes and errors."""

    def _warm_up(self) -> None:
        """Nothing to compile."""

    def _step(self, target: np.ndarray | None, out: np.ndarray | None) -> np.ndarray:
        """:meth:`step` after its checks, in numpy."""
        np.copyto(self._before, self._w[sk.POS : sk.ACC + 1])
        raw, mask = self._raw, self._mask
        if target is not None:
            np.copyto(self._raw2d, target)
            np.isfinite(raw, out=self._finite)
            if np.count_nonzero(self._finite) != self.dofs:
                np.logical_not(self._finite, out=mask)
                np.logical_and(mask, ~self._stop_dof, out=mask)
                self._increment(self.non_finite_per_joint, mask)
                np.copyto(raw, self._held, where=~self._finite)
            np.copyto(self._held, raw)
        else:
            np.copyto(raw, self._held)
        if self.mode == "torque":
            self._step_torque()
        else:
            np.copyto(self._mean_acc, self._vel)  # Ruckig's velocity before the step
            if self.mode == "position":
                self._step_position()
            else:
                self._step_velocity()
            np.subtract(self._vel, self._mean_acc, out=self._mean_acc)
            self._mean_acc *= self._inv_dt
        if out is None:
            return self.command
        np.copyto(out, self.command)
        return out

    def _increment(self, counter: np.ndarray, mask: np.ndarray) -> None:
        flat = counter.reshape(-1)
        np.add(flat, self._one_int, out=self._count)
        np.copyto(flat, self._count, where=mask)

    def _count_changed(self, counter: np.ndarray, before: np.ndarray, after: np.ndarray) -> None:
        np.not_equal(before, after, out=self._mask2)
        if np.count_nonzero(self._mask2):
            np.logical_and(self._mask2, ~self._stop_dof, out=self._mask2)
            self._increment(counter, self._mask2)

    def _step_position(self) -> None:
        raw, goal, out, cmd = self._raw, self._goal, self._out, self._cmd
        np.minimum(np.maximum(raw, self._lo, out=goal), self._hi, out=goal)
        self._count_changed(self.target_clamps_per_joint, raw, goal)
        self._inp.target_position = goal
        self._update()
        cmd[:] = out.new_position
        self._pos[:] = cmd
        self._vel[:] = out.new_velocity
        self._acc[:] = out.new_acceleration
        if out.new_calculation:
            self._check_extrema()
        np.minimum(np.maximum(cmd, self._lo, out=cmd), self._hi, out=cmd)
        np.copyto(self._cmd_position, cmd)
        out.pass_to_input(self._inp)

    def _near_limits(self) -> bool:
        """``_mask`` = DoFs within ``EXTREMA_SCREEN_FACTOR`` worst-case stopping distances of a
        hard limit, or faster than the velocity limit (possible right after a sync): only these
        can reach a limit within one trajectory. Returns whether any."""
        near, tmp = self._mask, self._mask2
        np.greater(self._pos, self._screen_hi, out=near)
        np.less(self._pos, self._screen_lo, out=tmp)
        np.logical_or(near, tmp, out=near)
        np.abs(self._vel, out=self._tmp)
        np.greater(self._tmp, self._vmax, out=tmp)
        np.logical_or(near, tmp, out=near)
        return bool(np.count_nonzero(near))

    def _check_extrema(self) -> None:
        """Count the DoFs whose new trajectory leaves the hard limits (screened by
        :meth:`_near_limits`: far from the limits the extrema are not even computed)."""
        if self._near_limits():
            self._count_extrema()

    def _step_velocity(self) -> None:
        raw, goal, out, tmp = self._raw, self._goal, self._out, self._tmp
        np.minimum(np.maximum(raw, self._neg_vmax, out=goal), self._vmax, out=goal)
        self._count_changed(self.target_clamps_per_joint, raw, goal)
        np.copyto(goal, 0.0, where=self._stop_dof)
        np.copyto(raw, goal)
        if self._near_limits():
            # stopping guard 1 (smooth): |v_target| <= stopping_speed(distance to the limit ahead)
            np.subtract(self._hi, self._pos, out=tmp)
            self._stopping_speed(tmp)
            np.minimum(goal, tmp, out=goal)
            np.subtract(self._pos, self._lo, out=tmp)
            self._stopping_speed(tmp)
            np.negative(tmp, out=tmp)
            np.maximum(goal, tmp, out=goal)
            # stopping guard 2 (exact): brake now where the next state could not stop in time
            if self._brake_needed():
                unsafe = self._unsafe
                np.minimum(goal, 0.0, out=tmp)
                np.copyto(goal, tmp, where=unsafe[0])
                np.maximum(goal, 0.0, out=tmp)
                np.copyto(goal, tmp, where=unsafe[1])
        self._count_changed(self.stopping_distance_clamps_per_joint, raw, goal)
        self._inp.target_velocity = goal
        self._update()
        self._cmd[:] = out.new_velocity
        self._pos[:] = out.new_position
        self._vel[:] = self._cmd
        self._acc[:] = out.new_acceleration
        np.copyto(self._cmd_position, self._pos)
        out.pass_to_input(self._inp)

    def _brake_needed(self) -> bool:
        """Fill ``_unsafe`` (2, dofs): rows toward the upper / lower limit, True where, after one
        more period of the worst acceleration the jerk limit allows, the joint could no longer
        stop before the limit. Ruckig's brake to velocity 0 is time-optimal, hence the shortest;
        its distance from velocity u and acceleration b toward the limit is at most
        ``u1 b1 / j + b1^3 / (3 j^2) + stopping_distance(u1 + b1^2 / (2 j))`` (ramp the
        acceleration to 0, then brake; ``u1, b1`` the worst next state). Returns whether any."""
        w, dt = self._guard, self.control_period
        u, b, room, t1, t2, t3 = w["u"], w["b"], w["room"], w["t1"], w["t2"], w["t3"]
        np.multiply(self._sign, self._vel, out=u)
        np.multiply(self._sign, self._acc, out=b)
        np.subtract(self._limits, self._pos, out=room)
        np.multiply(room, self._sign, out=room)
        # worst next displacement u dt + b dt^2 / 2 + j dt^3 / 6 uses up room
        np.multiply(u, dt, out=t1)
        np.multiply(b, 0.5 * dt * dt, out=t2)
        np.add(t1, t2, out=t1)
        np.add(t1, self._jdt3_6, out=t1)
        np.subtract(room, t1, out=room)
        # worst next speed u1 = max(u + b dt + j dt^2 / 2, 0), acceleration b1 = clip(b + j dt)
        np.multiply(b, dt, out=t2)
        np.add(t2, u, out=t2)
        np.add(t2, self._jdt2_2, out=t2)
        np.maximum(t2, 0.0, out=t2)
        np.add(b, self._jdt, out=t3)
        np.minimum(np.maximum(t3, 0.0, out=t3), self._amax, out=t3)
        # braking distance from (u1, b1)
        np.multiply(t3, self._inv_j, out=t1)  # b1 / j
        np.multiply(t2, t1, out=b)  # u1 b1 / j
        np.multiply(t1, t1, out=t1)
        np.multiply(t1, t3, out=t1)
        np.multiply(t1, 1.0 / 3.0, out=t1)  # b1^3 / (3 j^2)
        np.add(b, t1, out=b)
        np.multiply(t3, t3, out=t1)
        np.multiply(t1, self._inv_2j, out=t1)
        np.add(t1, t2, out=t1)  # u2 = u1 + b1^2 / (2 j)
        np.multiply(t1, self._inv_2a, out=t2)
        np.add(t2, self._a_2j, out=t2)
        np.multiply(t2, t1, out=t2)  # stopping_distance(u2)
        np.add(b, t2, out=b)
        np.greater(b, room, out=self._unsafe)
        return bool(np.count_nonzero(self._unsafe))

    def _stopping_speed(self, distance: np.ndarray) -> None:
        """In place: ``distance`` (rad) -> :func:`~sim2real.deploy.smoothing.stopping_speed` (rad/s), no
        allocation."""
        np.maximum(distance, 0.0, out=distance)
        np.multiply(distance, self._8a, out=distance)
        np.add(distance, self._c2, out=distance)
        np.sqrt(distance, out=distance)
        np.subtract(distance, self._c, out=distance)
        np.multiply(distance, 0.5, out=distance)

    def _step_torque(self) -> None:
        raw, goal, tmp, cmd = self._raw, self._goal, self._tmp, self._cmd
        np.clip(raw, self._neg_emax, self._emax, out=goal)
        self._count_changed(self.target_clamps_per_joint, raw, goal)
        np.subtract(goal, cmd, out=tmp)
        np.clip(tmp, self._neg_rate, self._rate, out=tmp)
        np.add(cmd, tmp, out=cmd)
