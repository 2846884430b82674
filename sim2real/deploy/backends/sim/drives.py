"""The simulated drives of the plant: torque limits derated from the winding temperature, and the
velocity loop's anti-windup.

Each drive's actuator torque is limited to its joint's effort limit, which the drive derates from
its own (true) winding temperature with :class:`sim2real.robots.thermal.EffortDerating` (peak torque below
the derating start, continuous torque, or the arm's gravity load where that is more, at the
maximum winding temperature), applied before every control period's physics steps.

:class:`SimDrives` is a base class of :class:`~sim2real.deploy.backends.sim.plant.SimBackend`; its methods
work on the backend's attributes (set in ``SimBackend.__init__``).
"""

from __future__ import annotations

import numpy as np

from sim2real.deploy.backends.sim.drives_kernel import derating_due, windup_exceeded


class SimDrives:
    """The drive model of a :class:`~sim2real.deploy.backends.sim.plant.SimBackend` (module docstring)."""

    def derate_drives(self) -> None:
        """Each drive's torque limit from its winding temperature (module docstring): the
        plant's ``effort_limit`` (envs, n) N m, MuJoCo's ``jnt_actfrcrange`` and, in velocity mode,
        the anti-windup bound (rad) follow it. Only envs with a winding above its derating start,
        or derated before, are touched. The step of the Python path before the plant's compiled
        one (:func:`sim2real.deploy.backends.sim.reference.reference_advance`, the pybullet
        plant). Raises nothing."""
        if derating_due(
            self.thermal.winding_temperature, self.derating.start, self._derated, self._hot
        ):
            self._set_derated_limits()

    def _set_derated_limits(self) -> None:
        """The action of :meth:`derate_drives` once its screen (``_hot`` (envs,) bool: a winding
        above its derating start) found work: the limits of the hot envs and of those derated
        before follow their windings' temperature."""
        hot = self._hot
        for e in np.flatnonzero(hot | self._derated):
            limit = self.effort_limit[e]
            np.multiply(
                self.derating.factor(self.thermal.winding_temperature[e], out=self._derate[e]),
                self.derating.peak,
                out=limit,
            )
            m = self.models[e]
            joints = slice(self._jnt_offset, self._jnt_offset + self.n_joints)
            m.jnt_actfrcrange[joints, 0] = -limit
            m.jnt_actfrcrange[joints, 1] = limit
            if self.mode == "velocity":
                np.divide(limit, m.actuator_gainprm[: self.n_joints, 0], out=self._windup_bound[e])
        self._derated[:] = hot

    def anti_windup(self) -> None:
        """Velocity mode: keep each drive's setpoint (``MjData.act``, rad) within
        ``effort_limit / kp`` of its joint angle gathered at the end of the period (the drive's
        present, derated, limit). A step of the Python path, as :meth:`derate_drives`; raises
        nothing.

        The integral term of the PI velocity loop, ``kp (s - q)``, then never asks for more than
        the drive's peak torque: when the torque saturates (a command accelerating faster than the
        motor can under load) the setpoint stops running ahead, and the joint does not overshoot
        the commanded speed to catch up afterwards (clamping anti-windup, K. J. Astrom and T.
        Hagglund, *Advanced PID Control*, ISA 2006, sec. 3.5). Applied once per control period.
        """
        lag, bound, acts = self._lag, self._windup_bound, self._acts
        for e, act in enumerate(acts):
            lag[e] = act
        if windup_exceeded(lag, self._qpos, bound):
            wound = np.abs(lag) > bound
            for e in np.flatnonzero(wound.any(axis=1)):
                q = self._qpos[e]
                np.clip(acts[e], q - bound[e], q + bound[e], out=acts[e])
