"""Ruckig inside the :class:`~deploy.smoothing.CommandSmoother`: the call and its errors, the
per-DoF control interfaces, the extrema of its trajectories, and the smoother's state dict.

Ruckig keeps the trajectory it calculated inside the ``Ruckig`` object, which its Python binding
can neither read nor set: the state dict holds Ruckig's input (``RUCKIG_INPUT_FIELDS``) beside the
smoother's arrays, and taking or loading it makes the next step recalculate from that input
(:meth:`RuckigState.recalculate`), so that a smoother loaded from a state continues bit for bit
as the one it was taken from.

:class:`RuckigState` is a base class of :class:`~deploy.smoothing.CommandSmoother`; its methods
work on the smoother's attributes (set in ``CommandSmoother.__init__``).
"""

from __future__ import annotations

import numpy as np
from ruckig import ControlInterface, Result, RuckigError

from deploy.errors import Sim2RealError
from deploy.stateful import env_index, put, scalar, take

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


class SmoothingError(Sim2RealError, RuntimeError):
    """Ruckig could not compute a trajectory; the message has Ruckig's result and the input."""


class RuckigState:
    """Ruckig's call, control interfaces and trajectory extrema, and the state dict, of a
    :class:`~deploy.smoothing.CommandSmoother` (module docstring)."""

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
        bit for bit (:mod:`deploy.smoothing`); a recalculation depends on the input alone: the
        same numbers whatever the other envs of the batch, and after :meth:`load_state_dict`."""
        if self.mode != "torque":
            self._ruckig.reset()

    def state_dict(self, env: int | None = None) -> dict:
        """The smoother's state (copies; conventions of :mod:`deploy.stateful`).

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
        except RuckigError as exc:
            raise SmoothingError(f"Ruckig rejected the input: {exc}") from exc
        if result != Result.Working and result != Result.Finished:
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
